// The TypeScript MCAP reader (@mcap/core, CRCs on), Foxglove's ROS 2 CDR decoder
// (@foxglove/rosmsg + @foxglove/rosmsg2-serialization) and the official Foxglove JSON Schemas
// (@foxglove/schemas, with ajv and fzstd) on an archive: node tests/mcap_ts_reader.js FILE.mcap -> JSON.
// Run by tests/benchmark/test_archive.py when node finds those packages (NODE_PATH).
const fs = require("fs");
const { McapIndexedReader } = require("@mcap/core");
const fzstd = require("fzstd");
const Ajv = require("ajv");
const schemas = require("@foxglove/schemas/jsonschema");
const { parse } = require("@foxglove/rosmsg");
const { MessageReader } = require("@foxglove/rosmsg2-serialization");
const decompressHandlers = { zstd: (buf, size) => fzstd.decompress(buf, new Uint8Array(Number(size))) };

// ROS 2 times are {sec, nanosec}; Foxglove's JSON Schemas spell them {sec, nsec}.
function foxgloveJson(v) {
  if (Array.isArray(v)) return v.map(foxgloveJson);
  if (v && typeof v === "object" && !ArrayBuffer.isView(v)) {
    const keys = Object.keys(v);
    if (keys.length === 2 && "sec" in v && "nanosec" in v) return { sec: v.sec, nsec: v.nanosec };
    const out = {};
    for (const k of keys) out[k] = foxgloveJson(v[k]);
    return out;
  }
  if (ArrayBuffer.isView(v)) return Array.from(v);
  return v;
}

async function main() {
  const path = process.argv[2];
  const fd = fs.openSync(path, "r");
  const size = fs.fstatSync(fd).size;
  const readable = {
    size: async () => BigInt(size),
    read: async (offset, length) => {
      const buf = Buffer.alloc(Number(length));
      fs.readSync(fd, buf, 0, Number(length), Number(offset));
      return new Uint8Array(buf.buffer, buf.byteOffset, buf.byteLength);
    },
  };
  const ajv = new Ajv({ allErrors: true, strict: false });
  const official = { "foxglove_msgs/msg/SceneUpdate": ajv.compile(schemas.SceneUpdate),
                     "foxglove_msgs/msg/FrameTransforms": ajv.compile(schemas.FrameTransforms) };
  const counts = {}, invalid = {}, last = {}, stateX = {};
  let order = true;
  const dec = new TextDecoder();
  const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });
  const decoders = new Map();
  for (const [id, ch] of reader.channelsById) {
    const schema = reader.schemasById.get(ch.schemaId);
    if (schema.encoding === "ros2msg") {
      const r = new MessageReader(parse(dec.decode(schema.data), { ros2: true }));
      decoders.set(id, { topic: ch.topic, decode: (d) => r.readMessage(d), check: official[schema.name] });
    } else {
      const v = ajv.compile(JSON.parse(dec.decode(schema.data)));
      decoders.set(id, { topic: ch.topic, decode: (d) => JSON.parse(dec.decode(d)), check: v, json: true });
    }
  }
  for await (const msg of reader.readMessages({ validateCrcs: true })) {
    const d = decoders.get(msg.channelId);
    const topic = d.topic;
    counts[topic] = (counts[topic] || 0) + 1;
    if (last[topic] !== undefined && msg.logTime < last[topic]) order = false;
    last[topic] = msg.logTime;
    const data = d.decode(msg.data);
    if (topic === "/state") (stateX[data.episode] = stateX[data.episode] || []).push(data.x);
    if (d.check && !d.check(d.json ? data : foxgloveJson(data))) {
      invalid[topic] = (invalid[topic] || 0) + 1;
      if (invalid[topic] === 1) console.error(topic, JSON.stringify(d.check.errors).slice(0, 400));
    }
  }
  const meta = [];
  for await (const m of reader.readMetadata({ name: "episode" })) meta.push(m.metadata.get("episode"));
  console.log(JSON.stringify({ counts, invalid, time_order: order, episodes: meta.length,
                               chunks: reader.chunkIndexes.length, state_x: stateX }));
}
main().catch((e) => { console.error("ERROR", e.message); process.exit(1); });
