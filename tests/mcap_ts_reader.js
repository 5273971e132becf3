// The TypeScript MCAP reader (@mcap/core, CRCs on) and the official Foxglove JSON Schemas (@foxglove/schemas,
// with ajv and fzstd) on an archive: node tests/mcap_ts_reader.js FILE.mcap -> JSON counts. Run by
// tests/test_archive.py when node finds those packages (NODE_PATH).
const fs = require("fs");
const { McapIndexedReader, McapStreamReader } = require("@mcap/core");
const fzstd = require("fzstd");
const Ajv = require("ajv");
const schemas = require("@foxglove/schemas/jsonschema");
const decompressHandlers = { zstd: (buf, size) => fzstd.decompress(buf, new Uint8Array(Number(size))) };

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
  const validate = { "/scene": ajv.compile(schemas.SceneUpdate), "/tf": ajv.compile(schemas.FrameTransform) };
  const counts = {}, invalid = {};
  let last = -1n, order = true;
  const dec = new TextDecoder();
  const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });
  for await (const msg of reader.readMessages({ validateCrcs: true })) {
    const topic = reader.channelsById.get(msg.channelId).topic;
    counts[topic] = (counts[topic] || 0) + 1;
    if (msg.logTime < last) order = false;
    last = msg.logTime;
    const v = validate[topic];
    if (v) {
      const data = JSON.parse(dec.decode(msg.data));
      if (!v(data)) { invalid[topic] = (invalid[topic] || 0) + 1; if (invalid[topic] === 1) console.error(topic, JSON.stringify(v.errors).slice(0, 400)); }
    }
  }
  const meta = [];
  for await (const m of reader.readMetadata({ name: "episode" })) meta.push(m.metadata.get("episode"));
  console.log(JSON.stringify({ counts, invalid, time_order: order, episodes: meta.length, chunks: reader.chunkIndexes.length }));
}
main().catch((e) => { console.error("ERROR", e.message); process.exit(1); });
