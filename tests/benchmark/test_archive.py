"""MCAP archives: a small run recorded through the runner, read back exactly; replay; bad input."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys

import jsonschema
import numpy as np
import pytest
from mcap.reader import make_reader
from test_benchmark_cli import one_line_error

from conftest import suite_file
from overtakezoo.benchmark.archive.format import EPISODE_GAP_NS
from overtakezoo.benchmark.archive.reader import list_episodes, read_archive, read_episode, read_index
from overtakezoo.benchmark.archive.recorder import ArchiveRecorder
from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.run.runner import run_suite
from overtakezoo.envs import MODE_NAMES, OUTCOME_NAMES
from overtakezoo.envs.suites import load_suite
from overtakezoo.zoo.base import Decider

SHARD = (3, 150)  # table1 has 3000 scenarios: the 4th of 150 slices is scenarios 60..79


class MixedDecider(Decider):
    """Deterministic mode changes (follow / overtake / abort) so every topic carries variety."""

    name = "test-mixed"

    def reset(self, mask=None):
        self.k = 0

    def act(self, obs):
        self.k += 1
        rows = np.arange(obs.shape[0])
        phase = (self.k // 40 + rows) % 4
        return np.select([phase == 0, phase == 3], [0, 2], 1).astype(np.int64)


class Tee:
    """Forwards to the archive recorder and keeps the run's own trajectory, per episode, for comparison."""

    def __init__(self, inner):
        self.inner, self.episodes = inner, {}

    def begin_chunk(self, core, index):
        self.index, self.log = np.asarray(index), {k: [] for k in ("ego", "npc_s", "npc_v", "done", "mode", "rew")}
        self.inner.begin_chunk(core, index)
        self._keep(core)

    def _keep(self, core):
        self.log["ego"].append(np.stack([core.x, core.y, core.psi, core.v, core.a, core.steer], 1).copy())
        self.log["npc_s"].append(core.npc_s.copy())
        self.log["npc_v"].append(core.npc_v.copy())
        self.log["done"].append(core.done.copy())

    def record_step(self, core, modes, result):
        self.inner.record_step(core, modes, result)
        self.log["mode"].append(core.mode.copy())
        self.log["rew"].append(result.reward.copy())
        self._keep(core)

    def end_chunk(self, core):
        self.inner.end_chunk(core)
        log = {k: np.stack(v) for k, v in self.log.items()}  # (T+1, N, ...) or (T, N)
        for r, ep in enumerate(self.index.tolist()):
            steps = int(np.argmax(log["done"][:, r]))  # the first step at which the row is finished
            self.episodes[ep] = {
                "steps": steps,
                "ego": log["ego"][: steps + 1, r],
                "npc_s": log["npc_s"][: steps + 1, r],
                "npc_v": log["npc_v"][: steps + 1, r],
                "mode": log["mode"][:steps, r],
                "rew": log["rew"][:steps, r],
            }


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    path = tmp_path_factory.mktemp("archive") / "run.mcap"
    suite = load_suite("table1")
    # The default scene (every step); chunks of about 100 kB (a few episodes each) so cuts fall between them.
    with ArchiveRecorder(path, chunk_size=100_000) as rec:
        tee = Tee(rec)
        results = run_suite(
            suite, MixedDecider(suite.config), shard=SHARD, chunk_size=8, progress=False, recorder=tee
        )  # 3 chunks: 8, 8, 4
    return path, results, tee


def test_archive_rebuilds_every_episode_exactly(run):
    path, results, tee = run
    episodes = read_archive(path)
    assert [e.index for e in episodes] == list(range(60, 80))
    for r, ep in enumerate(episodes):
        run_ep = tee.episodes[ep.index]
        assert ep.steps == run_ep["steps"]
        for j, key in enumerate(("x", "y", "psi", "v", "a", "steer")):
            assert np.array_equal(ep.ego[key], run_ep["ego"][:, j]), key
        assert np.array_equal(ep.npc_s, run_ep["npc_s"]) and np.array_equal(ep.npc_v, run_ep["npc_v"])
        assert np.array_equal(ep.mode, run_ep["mode"]) and np.array_equal(ep.reward, run_ep["rew"])
        assert ep.summary["episode_return"] == pytest.approx(run_ep["rew"].sum(), abs=1e-9)
        # Outcome and statistics equal the runner's results (which round floats to 4 decimals).
        per = results.per
        assert ep.outcome == OUTCOME_NAMES[per["outcome"][r]]
        for key, src in (("crash_npc", "crash_npc"), ("aborts", "aborts"), ("switches", "switches")):
            assert ep.summary[src] == per[key][r]
        for key, src in (
            ("episode_time", "t"),
            ("completion_time", "completion_time"),
            ("opposite_time", "opposite_time"),
            ("min_ttc", "min_ttc"),
            ("peak_jerk", "peak_jerk"),
        ):
            np.testing.assert_equal(np.round(ep.summary[src], 4), per[key][r])


def test_index_and_single_episode(run):
    path, results, _ = run
    entries = list_episodes(path)
    assert [e.index for e in entries] == list(range(60, 80))
    # A compact timeline: episodes back to back, EPISODE_GAP_NS apart, each as long as its steps.
    assert entries[0].start_ns == 0
    assert all(b.start_ns == a.end_ns + EPISODE_GAP_NS for a, b in zip(entries, entries[1:], strict=False))
    assert all(e.end_ns - e.start_ns == e.steps * 100_000_000 for e in entries)
    ep = read_episode(path, 71)
    full = {e.index: e for e in read_archive(path)}[71]
    assert ep.outcome == full.outcome and np.array_equal(ep.ego["x"], full.ego["x"])
    assert entries[11].outcome == ep.outcome and entries[11].steps == ep.steps
    with pytest.raises(UserError, match="episode 5 is not in"):
        read_episode(path, 5)


def _decoded(path, topics=None):
    """(topic, log_time, decoded message) of every message, in log-time order, through mcap's reader
    (CRCs checked) and mcap_ros2's CDR decoder (an independent implementation of ROS 2 CDR)."""
    from mcap_ros2.decoder import DecoderFactory

    class Json:
        def decoder_for(self, encoding, schema):
            return json.loads if encoding == "json" else None

    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory(), Json()])
        return [(ch.topic, msg.log_time, dec) for _, ch, msg, dec in reader.iter_decoded_messages(topics=topics)]


def test_messages_follow_their_schemas_and_times_are_monotonic(run):
    path, _, tee = run
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        assert all(c.compression == "zstd" for c in summary.chunk_indexes)
        schemas = {summary.channels[c].topic: summary.schemas[summary.channels[c].schema_id] for c in summary.channels}
        last: dict[str, int] = {}
        for schema, channel, msg in reader.iter_messages(log_time_order=False):  # file order
            assert msg.log_time >= last.get(channel.topic, -1)  # each topic in time order through the file
            last[channel.topic] = msg.log_time
            if schema.encoding == "jsonschema":
                jsonschema.validate(json.loads(msg.data), json.loads(schema.data))
    assert {t: (s.name, s.encoding) for t, s in schemas.items() if s.encoding == "ros2msg"} == {
        "/state": ("overtakezoo_msgs/msg/State", "ros2msg"),
        "/tf": ("foxglove_msgs/msg/FrameTransforms", "ros2msg"),
        **{
            t: ("foxglove_msgs/msg/SceneUpdate", "ros2msg")
            for t in ("/scene/road", "/scene/vehicles", "/scene/rollouts", "/scene/label", "/scene/outcome")
        },
    }
    ranges = {e.index: (e.start_ns, e.end_ns) for e in list_episodes(path)}
    by_topic: dict[str, list] = {}
    for topic, t, msg in _decoded(path):
        by_topic.setdefault(topic, []).append((t, msg))
    # /state, decoded by mcap_ros2, is the run's own trajectory, bit for bit.
    states = by_topic["/state"]
    for ep, run_ep in tee.episodes.items():
        rows = [m for t, m in states if m.episode == ep]
        lo, hi = ranges[ep]
        assert [m.step for m in rows] == list(range(run_ep["steps"] + 1))
        assert [t for t, m in states if m.episode == ep] == [
            lo + k * 100_000_000 for k in range(len(rows))
        ] and lo + run_ep["steps"] * 100_000_000 == hi
        got = np.array([[m.x, m.y, m.psi, m.v, m.a, m.steer] for m in rows])
        assert np.array_equal(got, run_ep["ego"])
        assert np.array_equal(np.array([m.npc_s for m in rows]), run_ep["npc_s"])
        assert np.array_equal(np.array([m.mode for m in rows[1:]]), run_ep["mode"])
        assert np.array_equal(np.array([m.reward for m in rows[1:]]), run_ep["rew"])
    steps = sum(r["steps"] + 1 for r in tee.episodes.values())
    assert len(by_topic["/tf"]) == steps and len(by_topic["/scene/road"]) == len(tee.episodes)
    frames = [tf.child_frame_id for tf in by_topic["/tf"][0][1].transforms]
    assert frames == ["ego", "npc1", "npc2"]


def test_cdr_templates_match_an_independent_encoder(run):
    """Every message kind re-encoded by mcap_ros2's serializer (from the decoded message and the
    file's own ros2msg definition) gives the bytes in the file: our templates lay out CDR exactly
    as ROS 2 does (alignment, strings, sequences)."""
    from mcap_ros2._dynamic import serialize_dynamic
    from mcap_ros2.decoder import DecoderFactory

    path, _, _ = run
    seen = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, msg, dec in reader.iter_decoded_messages(
            topics=[
                "/state",
                "/tf",
                "/scene/road",
                "/scene/vehicles",
                "/scene/rollouts",
                "/scene/label",
                "/scene/outcome",
            ]
        ):
            if schema.encoding != "ros2msg" or seen.get(channel.topic, 0) >= 20:
                continue
            seen[channel.topic] = seen.get(channel.topic, 0) + 1
            encode = serialize_dynamic(schema.name, schema.data.decode())[schema.name]
            assert bytes(encode(dec)) == msg.data, channel.topic
    assert set(seen) == {
        "/state",
        "/tf",
        "/scene/road",
        "/scene/vehicles",
        "/scene/rollouts",
        "/scene/label",
        "/scene/outcome",
    }


def test_archive_bytes_are_deterministic(tmp_path):
    suite = load_suite("table1")
    blobs = []
    for k in range(2):
        with ArchiveRecorder(tmp_path / f"{k}.mcap", scene_every=3) as rec:
            run_suite(suite, MixedDecider(suite.config), shard=(0, 600), progress=False, recorder=rec)
        blobs.append((tmp_path / f"{k}.mcap").read_bytes())
    assert blobs[0] == blobs[1]


def test_format_2_archives_are_refused_in_one_line(tmp_path):
    from mcap.writer import Writer

    path = tmp_path / "old.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        w.add_metadata("overtakezoo", {"format_version": "2"})
        w.finish()
    with pytest.raises(UserError, match="archive format 2 is not readable by this version"):
        read_index(path)


def test_corrupt_archive_is_one_clear_error(run, tmp_path, capsys):
    path, _, _ = run
    data = path.read_bytes()
    with open(path, "rb") as f:
        chunk = make_reader(f).get_summary().chunk_indexes[1]
    flipped = bytearray(data)
    flipped[chunk.chunk_start_offset + chunk.chunk_length // 2] ^= 0x5A  # inside a compressed chunk
    for name, blob in (("junk.mcap", b"x" * 50), ("flip.mcap", bytes(flipped)), ("head.mcap", data[:200])):
        bad = tmp_path / name
        bad.write_bytes(blob)
        with pytest.raises(UserError, match="truncated or corrupt|cut before its first whole episode"):
            read_archive(bad)
        if name == "flip.mcap":  # the index is intact: listing works, reading the damaged chunk does not
            episode = next(e.index for e in list_episodes(bad) if e.start_ns <= chunk.message_start_time <= e.end_ns)
            assert main(["replay", str(bad), "--episode", str(episode), "--out", str(tmp_path / "x.png")]) == 2
        else:
            assert main(["replay", str(bad), "--list"]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error:") and err.count("\n") == 1


def test_cut_archive_gives_its_whole_episodes(run, tmp_path, capsys):
    """A file cut anywhere reads back as the episodes closed before the cut, each exactly as in the
    whole file; `replay --list` lists them and says in one line what was lost."""
    path, _, _ = run
    data = path.read_bytes()
    full = {e.index: e for e in read_archive(path)}
    bad = tmp_path / "cut.mcap"
    counts = []
    for frac in (0.15, 0.4, 0.6, 0.8, 0.95, 0.9995):
        bad.write_bytes(data[: int(len(data) * frac)])
        index = read_index(bad)
        episodes = read_archive(bad)
        assert [e.index for e in episodes] == [e.index for e in index.entries] == list(range(60, 60 + len(episodes)))
        for ep in episodes:
            assert np.array_equal(ep.ego["x"], full[ep.index].ego["x"]) and ep.summary == full[ep.index].summary
        if len(episodes) < 20:  # else the cut fell in the summary section (the last case below)
            assert index.note == (
                f"archive cut after episode {episodes[-1].index}: {len(episodes)} whole episodes, the rest lost"
            )
        counts.append(len(episodes))
        assert read_episode(bad, episodes[-1].index).steps == full[episodes[-1].index].steps
    assert counts == sorted(counts) and counts[0] < counts[-1]
    bad.write_bytes(data[: len(data) // 2])
    assert main(["replay", str(bad), "--list"]) == 0
    out, err = capsys.readouterr()
    assert f"\n{len(list_episodes(bad))} episodes\n" in out
    assert err.startswith("warning: archive cut after episode") and err.count("\n") == 1
    # Only the summary section lost: every episode is whole, the note says the index was rebuilt.
    bad.write_bytes(data[:-100])
    index = read_index(bad)
    assert len(index.entries) == 20 and "none lost" in index.note


class _Stop:
    """Forwards to a recorder; after ``chunks`` chunks (or at ``step`` of the next one) it interrupts
    the run: ``how`` is "kill" (SIGKILL to this process), "term" (SIGTERM) or "raise" (KeyboardInterrupt)."""

    def __init__(self, inner, how, chunks, step=None):
        self.inner, self.how, self.chunks, self.step, self.k = inner, how, chunks, step, 0

    def begin_chunk(self, core, index):
        self.inner.begin_chunk(core, index)
        self.t = 0

    def record_step(self, core, modes, result):
        self.inner.record_step(core, modes, result)
        self.t += 1
        if self.k == self.chunks and self.t == self.step:
            self.stop()

    def end_chunk(self, core):
        self.inner.end_chunk(core)
        self.k += 1
        if self.k == self.chunks and self.step is None:
            self.stop()

    def stop(self):
        if self.how == "raise":
            raise KeyboardInterrupt
        os.kill(os.getpid(), signal.SIGKILL if self.how == "kill" else signal.SIGTERM)
        signal.pause() if self.how == "kill" else None


_WRITER = """
import sys
sys.path[:0] = [{tests!r}, {tests!r} + "/.."]  # this test file and the shared conftest
from test_archive import MixedDecider, _Stop
from overtakezoo.benchmark.archive.recorder import ArchiveRecorder
from overtakezoo.benchmark.run.runner import run_suite
from overtakezoo.envs.suites import load_suite
suite = load_suite("table1")
with ArchiveRecorder({path!r}) as rec:
    run_suite(suite, MixedDecider(suite.config), shard=(0, 300), chunk_size=4, progress=False,
              recorder=_Stop(rec, {how!r}, 2))
"""


@pytest.mark.parametrize("how", ["kill", "term"])
def test_killed_or_terminated_writer(tmp_path, capsys, how):
    """SIGKILL leaves the temp file (the target is never half-written), readable up to its last whole
    episode; SIGTERM finishes the file with its whole episodes and renames it into place."""
    target = tmp_path / "run.mcap"
    code = _WRITER.format(tests=os.path.dirname(__file__), path=str(target), how=how)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    temps = list(tmp_path.glob(".run.mcap.tmp-*"))
    if how == "kill":
        assert proc.returncode == -signal.SIGKILL and not target.exists() and len(temps) == 1
        assert main(["replay", str(temps[0]), "--list"]) == 0
        out, err = capsys.readouterr()
        assert "8 episodes" in out and err == "warning: archive cut after episode 7: 8 whole episodes, the rest lost\n"
        assert [e.index for e in read_archive(temps[0])] == list(range(8))
    else:
        assert proc.returncode != 0 and "KeyboardInterrupt" in proc.stderr
        assert target.exists() and not temps
        index = read_index(target)
        assert index.note is None and [e.index for e in index.entries] == list(range(8))


def test_interrupt_mid_chunk_keeps_finished_episodes(tmp_path):
    """Ctrl-C in the middle of a chunk: the file gets the whole chunks and the rows of the open chunk
    that had finished, each identical to the same episode of an uninterrupted run."""
    suite = load_suite("table1")
    full_path, cut_path = tmp_path / "full.mcap", tmp_path / "cut.mcap"
    with ArchiveRecorder(full_path) as rec:
        run_suite(suite, MixedDecider(suite.config), shard=(0, 300), chunk_size=5, progress=False, recorder=rec)
    with pytest.raises(KeyboardInterrupt):
        with ArchiveRecorder(cut_path) as rec:
            run_suite(
                suite,
                MixedDecider(suite.config),
                shard=(0, 300),
                chunk_size=5,
                progress=False,
                recorder=_Stop(rec, "raise", 1, step=200),
            )
    full = {e.index: e for e in read_archive(full_path)}
    cut = read_archive(cut_path)
    late = [e.index for e in cut if e.index >= 5]
    assert [e.index for e in cut][:5] == list(range(5)) and late  # chunk 0 whole, some rows of chunk 1
    assert all(full[i].steps <= 200 for i in late) and all(full[i].steps > 200 for i in set(range(5, 10)) - set(late))
    for ep in cut:
        assert ep.steps == full[ep.index].steps and np.array_equal(ep.ego["x"], full[ep.index].ego["x"])
    assert not list(tmp_path.glob(".*.tmp-*"))


def test_two_writers_on_one_archive_never_mix(tmp_path):
    suite = load_suite("table1")
    path = tmp_path / "run.mcap"
    a, b = ArchiveRecorder(path), ArchiveRecorder(path)
    assert a.tmp_path != b.tmp_path
    run_suite(suite, MixedDecider(suite.config), shard=(0, 600), progress=False, recorder=a)
    run_suite(suite, MixedDecider(suite.config), shard=(1, 600), progress=False, recorder=b)
    b.close()
    assert [e.index for e in list_episodes(path)] == list(range(5, 10))
    a.close()  # the last to finish wins, whole
    assert [e.index for e in list_episodes(path)] == list(range(5)) and read_index(path).note is None
    assert not list(tmp_path.glob(".*.tmp-*"))


def test_fifo_and_symlink_targets_are_written_like_every_other_file(tmp_path):
    """The archive goes through envs/io's atomic writes: a FIFO is streamed into (and stays a FIFO),
    a symlink is followed (the link stays, the file it points to is replaced)."""
    import stat
    import threading

    suite = load_suite("table1")
    fifo, got = tmp_path / "run.fifo", []
    os.mkfifo(fifo)
    reader = threading.Thread(target=lambda: got.append(fifo.open("rb").read()), daemon=True)
    reader.start()
    with ArchiveRecorder(fifo, scene_every=0) as rec:
        assert rec.tmp_path == fifo
        run_suite(suite, MixedDecider(suite.config), shard=(0, 600), progress=False, recorder=rec)
    reader.join(10)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    (tmp_path / "piped.mcap").write_bytes(got[0])
    assert [e.index for e in list_episodes(tmp_path / "piped.mcap")] == list(range(5))

    real, link = tmp_path / "real.mcap", tmp_path / "link.mcap"
    real.write_bytes(b"old")
    link.symlink_to(real)
    with ArchiveRecorder(link, scene_every=0) as rec:
        assert rec.tmp_path.parent == tmp_path and rec.tmp_path.name.startswith(".real.mcap.tmp-")
        run_suite(suite, MixedDecider(suite.config), shard=(0, 600), progress=False, recorder=rec)
    assert link.is_symlink() and real.read_bytes() == got[0]
    assert not list(tmp_path.glob(".*.tmp-*"))


def _scene_by_episode(path):
    """Each episode's decoded /tf and /scene/* messages by topic, as (log time, message)."""
    entries = list_episodes(path)
    out = {e.index: {} for e in entries}
    starts = [e.start_ns for e in entries]
    for topic, t, msg in _decoded(path):
        if topic == "/tf" or topic.startswith("/scene/"):
            ep = entries[int(np.searchsorted(starts, t, side="right")) - 1]
            assert ep.start_ns <= t <= ep.end_ns
            out[ep.index].setdefault(topic, []).append((t, msg))
    return entries, out


def test_scene_at_every_step_ends_with_the_outcome(run):
    """Default scene: the frames at every step 0..T, the road once, the vehicles, rollouts and label
    when they change; the last update shows the outcome; a crash highlights the vehicle hit; unseen
    vehicles are faded; the next episode clears the outcome."""
    path, results, _ = run
    entries, scenes = _scene_by_episode(path)
    crashes = faded = 0
    for e in entries:
        sc = scenes[e.index]
        ep = read_episode(path, e.index)
        tf = sc["/tf"]
        assert [t for t, _ in tf] == [e.start_ns + k * 100_000_000 for k in range(e.steps + 1)]
        for k in (0, e.steps // 2, e.steps):  # the frames follow the recorded state
            ego, *npcs = tf[k][1].transforms
            assert (ego.translation.x, ego.translation.y) == (ep.ego["x"][k], ep.ego["y"][k])
            assert ego.rotation.z == pytest.approx(np.sin(ep.ego["psi"][k] / 2))
            assert [n.translation.x for n in npcs] == ep.npc_s[k].tolist()
        assert [t for t, _ in sc["/scene/road"]] == [e.start_ns]
        for topic in ("/scene/vehicles", "/scene/rollouts", "/scene/label"):
            times = [t for t, _ in sc[topic]]
            assert times[0] == e.start_ns and times[-1] == e.end_ns and times == sorted(set(times))
        roll = sc["/scene/rollouts"]
        assert all(
            b - a <= 10 * 100_000_000 for a, b in zip([t for t, _ in roll], [t for t, _ in roll][1:], strict=False)
        )
        lines = roll[-1][1].entities[0].lines
        chosen = [j for j, line in enumerate(lines) if line.thickness == 0.25]
        assert chosen == [int(ep.rollout[-1])]
        t_end, shown = sc["/scene/outcome"][-1]
        assert sc["/scene/outcome"][0][1].deletions[0].type == 1 and t_end == e.end_ns
        words = shown.entities[0].texts[0].text.strip()
        assert words.startswith(e.outcome.upper())
        label = sc["/scene/label"][-1][1].entities[0].texts[0].text
        assert label.split() == ["episode", str(e.index), MODE_NAMES[int(ep.mode[-1])]]
        cubes = [ent.cubes[0].color for ent in sc["/scene/vehicles"][-1][1].entities[1:]]  # the ego is first
        hit = [c for c in cubes if (c.r, c.g, c.b) == (1, 0, 1)]
        if e.outcome == "crash":
            crashes += 1
            present = np.flatnonzero(ep.scenario["npc_present"]).tolist()
            assert len(hit) == 1 and cubes.index(hit[0]) == int(ep.summary["crash_npc"]) in present
            assert f"NPC{int(ep.summary['crash_npc']) + 1}" in words
        else:
            assert not hit
        faded += sum(ent.cubes[0].color.a < 1 for _, u in sc["/scene/vehicles"] for ent in u.entities)
    assert crashes >= 1 and faded > 0


def test_scene_every_k_keeps_the_final_step(tmp_path):
    suite = load_suite("table1")
    path = tmp_path / "thin.mcap"
    with ArchiveRecorder(path, scene_every=7) as rec:
        run_suite(suite, MixedDecider(suite.config), shard=(0, 600), progress=False, recorder=rec)
    entries, scenes = _scene_by_episode(path)
    for e in entries:
        steps = sorted({*range(0, e.steps + 1, 7), e.steps})
        assert [t for t, _ in scenes[e.index]["/tf"]] == [e.start_ns + k * 100_000_000 for k in steps]
        assert {t for topic in scenes[e.index] for t, _ in scenes[e.index][topic]} <= {
            e.start_ns + k * 100_000_000 for k in steps
        }


def test_replay_cli(run, tmp_path, capsys):
    path, _, _ = run
    assert main(["replay", str(path), "--list"]) == 0
    out = capsys.readouterr().out
    assert "20 episodes" in out and "60" in out
    assert main(["replay", str(path), "--episode", "999"]) == 2
    assert "episode 999 is not in" in capsys.readouterr().err
    png, gif = tmp_path / "ep.png", tmp_path / "ep.gif"
    assert main(["replay", str(path), "--episode", "61", "--out", str(png)]) == 0
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert main(["replay", str(path), "--episode", "61", "--out", str(gif), "--every", "25"]) == 0
    assert gif.read_bytes()[:3] == b"GIF"
    if shutil.which("ffmpeg") is None:
        assert main(["replay", str(path), "--episode", "61", "--out", str(tmp_path / "ep.mp4")]) == 2
        assert "ffmpeg" in capsys.readouterr().err


def test_replay_help_has_examples(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["replay", "--help"])
    assert exc.value.code == 0 and "examples:" in capsys.readouterr().out


def test_eval_archive_end_to_end(tmp_path, capsys):
    from overtakezoo.benchmark.archive.reader import read_archive_meta

    suite = suite_file(tmp_path / "tiny.toml", 8)
    out, mcap = tmp_path / "res.json", tmp_path / "run.mcap"
    assert (
        main(
            [
                "eval",
                "--suite",
                str(suite),
                "--decider",
                "always-overtake",
                "--out",
                str(out),
                "--archive",
                str(mcap),
                "--no-progress",
            ]
        )
        == 0
    )
    results = json.loads(out.read_text())
    plain = tmp_path / "plain.json"
    assert (
        main(["eval", "--suite", str(suite), "--decider", "always-overtake", "--out", str(plain), "--no-progress"]) == 0
    )

    def untimed(tree):  # the results without when the run started and how long it took
        if isinstance(tree, dict):
            return {k: untimed(v) for k, v in tree.items() if k not in ("started", "wall_time_s")}
        return [untimed(v) for v in tree] if isinstance(tree, list) else tree

    assert untimed(json.loads(plain.read_text())) == untimed(results)  # the archive changes no result
    outcomes = [OUTCOME_NAMES[o] for o in results["scenarios"]["outcome"]]
    assert [e.outcome for e in list_episodes(mcap)] == outcomes
    meta = read_archive_meta(mcap)
    assert meta["suite"] == "tiny" and meta["decider"] == "always-overtake"
    assert (
        main(
            [
                "eval",
                "--suite",
                str(suite),
                "--decider",
                "always-overtake",
                "--out",
                str(out),
                "--archive",
                str(tmp_path),
            ]
        )
        == 2
    )  # a directory: refused before the run
    assert "is a directory" in capsys.readouterr().err


def test_non_finite_values_round_trip(run):
    """Non-finite scenario values (an infinite reveal distance) are null in the JSON spec and read
    back as inf; the per-step floats are float64 in CDR (exact, non-finite included)."""
    from overtakezoo.benchmark.archive.recorder import _json_rows

    assert _json_rows(np.array([[1.0, np.inf], [np.nan, 2.0]])) == [[1.0, None], [None, 2.0]]
    path, _, _ = run
    suite = load_suite("table1")
    scen = suite.scenarios().take(np.arange(60, 80)).to_arrays()
    assert np.isinf(scen["npc_reveal"]).any()  # the suite has unrevealed-until-seen NPCs: the case is real
    for k, ep in enumerate(read_archive(path)):
        for name, arr in scen.items():
            np.testing.assert_array_equal(np.asarray(ep.scenario[name], dtype=arr.dtype), arr[k], err_msg=name)


def _node_packages() -> bool:
    if shutil.which("node") is None:
        return False
    probe = (
        "for (const p of ['@mcap/core', 'fzstd', 'ajv', '@foxglove/schemas/jsonschema', '@foxglove/rosmsg', "
        "'@foxglove/rosmsg2-serialization']) require(p)"
    )
    return subprocess.run(["node", "-e", probe], capture_output=True).returncode == 0


@pytest.mark.skipif(
    not _node_packages(),
    reason="needs node with @mcap/core, fzstd, ajv, @foxglove/schemas, "
    "@foxglove/rosmsg, @foxglove/rosmsg2-serialization (e.g. npm i "
    "them in a folder and set NODE_PATH to its node_modules)",
)
def test_typescript_reader_and_official_foxglove_schemas(run):
    path, _, _ = run
    script = os.path.join(os.path.dirname(os.path.dirname(__file__)), "mcap_ts_reader.js")
    proc = subprocess.run(["node", script, str(path)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    got = json.loads(proc.stdout)
    entries = list_episodes(path)
    steps = sum(e.steps for e in entries)
    assert got["invalid"] == {} and got["time_order"] and got["episodes"] == len(entries) == 20
    assert got["counts"]["/tf"] == got["counts"]["/state"] == steps + len(entries)
    assert got["counts"]["/scene/road"] == len(entries) and got["chunks"] >= 2
    for ep in read_archive(path):  # Foxglove's CDR decoder reads the same state
        assert got["state_x"][str(ep.index)] == ep.ego["x"].tolist()


@pytest.mark.slow  # about 8 s of CPU: run with -m slow
def test_gif_of_the_246_frame_episode(tmp_path):
    """rule-fsm, table1 episode 29 (245 steps): every frame rendered, the whole road in the overview."""
    from PIL import Image

    from overtakezoo import zoo
    from overtakezoo.benchmark.archive.replay import replay

    suite = load_suite("table1")
    path, gif = tmp_path / "rule.mcap", tmp_path / "ep29.gif"
    with ArchiveRecorder(path) as rec:
        run_suite(suite, zoo.load("rule-fsm", config=suite.config), shard=(29, 3000), progress=False, recorder=rec)
    (entry,) = list_episodes(path)
    assert (entry.index, entry.steps) == (29, 245)
    replay(path, 29, gif)
    with Image.open(gif) as im:
        assert im.n_frames == 246 and im.size[0] == 960


def test_foxglove_layout_ships_and_replay_says_how_to_open_it(capsys):
    from overtakezoo.benchmark.archive.format import ROS2_SCHEMAS, SCENE_TOPICS
    from overtakezoo.benchmark.archive.replay import FOXGLOVE_LAYOUT

    layout = json.loads(FOXGLOVE_LAYOUT.read_text())
    panels = layout["configById"]
    assert {p.split("!")[0] for p in panels} == {"3D", "Plot", "RawMessages"}
    scene = next(v for k, v in panels.items() if k.startswith("3D"))
    assert scene["followTf"] == "ego" and set(scene["topics"]) == set(SCENE_TOPICS)
    topics = {p["value"].split(".")[0] for k, v in panels.items() if k.startswith("Plot") for p in v["paths"]}
    assert topics == {"/state"} and topics <= set(ROS2_SCHEMAS)
    assert any(v.get("topicPath") == "/episode/summary" for v in panels.values())
    tree = json.dumps(layout["layout"])
    assert all(k in tree for k in panels)  # every panel is placed
    assert main(["replay", "run.mcap", "--foxglove"]) == 0
    out = capsys.readouterr().out
    assert str(FOXGLOVE_LAYOUT) in out and "run.mcap" in out


# ---------------------------------------------------------------------------- signals and full disks (issue 18)
# `overtakezoo eval --archive` in a subprocess, 10 scenarios in chunks of 4, 4, 2. ``hook`` patches the
# recorder to send the process a real SIGTERM at a chosen point (deterministic: no timing involved).
_EVAL = """
import os, signal, sys
from overtakezoo.benchmark.archive import mcapfile, recorder as archive
from overtakezoo.benchmark.cli import main
Rec, term = archive.ArchiveRecorder, lambda: os.kill(os.getpid(), signal.SIGTERM)
{hook}
sys.exit(main(["eval", "--suite", "table1", "--decider", "always-overtake", "--shard", "0/300", "--chunk-size", "4",
               "--out", {out!r}, "--archive", {path!r}]))
"""


def _eval_subprocess(tmp_path, hook, **kw):
    target = tmp_path / "run.mcap"
    code = _EVAL.format(hook=hook, out=str(tmp_path / "res.json"), path=str(target))
    return target, subprocess.Popen([sys.executable, "-c", code], stderr=subprocess.PIPE, text=True, **kw)


def _held_episodes(err):
    """The N of the CLI's 'interrupted: ... holds the N whole episodes'."""
    line = next(x for x in err.splitlines() if x.startswith("interrupted:"))
    return int(line.split("holds the ")[1].split()[0])


def test_sigterm_while_a_chunk_is_written_keeps_each_episode_once(tmp_path):
    """SIGTERM arriving while the second chunk's episodes are written: that chunk is finished first,
    the archive holds episodes 0-7 once each (it used to write the cut chunk a second time) and the
    command exits 143 like any SIGTERM."""
    hook = """
add, seen = Rec._add, []
def _add(self, topic, t, text):
    add(self, topic, t, text)
    if topic == "/episode/spec":
        seen.append(1)
        if len(seen) == 6:  # the second episode of chunk 1
            term()
Rec._add = _add
"""
    target, proc = _eval_subprocess(tmp_path, hook)
    err = proc.communicate(timeout=120)[1]
    assert proc.returncode == 143 and err.endswith("terminated\n"), err
    index = read_index(target)
    assert [e.index for e in index.entries] == list(range(8)) and index.note is None
    assert _held_episodes(err) == 8 and not list(tmp_path.glob(".run.mcap.tmp-*"))


def test_second_sigterm_while_finishing_keeps_the_archive(tmp_path):
    """A first SIGTERM in the middle of chunk 1, a second one while the file is finished: the archive
    still holds the whole episodes the message names (the second signal used to delete it), and the
    finishing is announced."""
    hook = """
step, finish = Rec.record_step, mcapfile.McapFile.finish
def record_step(self, core, modes, res):
    step(self, core, modes, res)
    if self.episodes == 4 and self._chunk.step == 150:
        term()
def term_and_finish(self):
    term()
    finish(self)
Rec.record_step, mcapfile.McapFile.finish = record_step, term_and_finish
"""
    target, proc = _eval_subprocess(tmp_path, hook)
    err = proc.communicate(timeout=120)[1]
    assert proc.returncode == 143 and err.endswith("terminated\n"), err
    assert "finishing " in err and "finished episodes of the open chunk" in err
    index = read_index(target)
    held = [e.index for e in index.entries]
    assert index.note is None and len(held) == _held_episodes(err) and held[:4] == list(range(4))
    assert len(set(held)) == len(held) and not list(tmp_path.glob(".run.mcap.tmp-*"))


def test_sigterm_from_outside_exits_143_with_the_archive_finished(tmp_path):
    """The documented exit status of SIGTERM (143) holds with --archive too (it was 130). The run
    says when its first chunk is written and waits there; this test then sends the SIGTERM."""
    hook = """
end = Rec.end_chunk
def end_chunk(self, core):
    end(self, core)
    print("chunk written", file=sys.stderr, flush=True)
    signal.pause()
Rec.end_chunk = end_chunk
"""
    target, proc = _eval_subprocess(tmp_path, hook)
    try:
        assert proc.stderr.readline() == "chunk written\n"
        proc.send_signal(signal.SIGTERM)
        err = proc.communicate(timeout=120)[1]
    finally:
        proc.kill()
    assert proc.returncode == 143 and err.endswith("terminated\n"), err
    assert [e.index for e in list_episodes(target)] == list(range(4)) and _held_episodes(err) == 4


def test_full_disk_while_archiving_is_one_error_line_and_keeps_the_old_file(tmp_path, capsys, monkeypatch):
    """ENOSPC in the middle of an archive: one `error:` line (no OSError traceback), no temp file,
    the previous archive untouched."""
    import errno

    from overtakezoo.benchmark.archive import recorder as archive

    target = tmp_path / "run.mcap"
    target.write_bytes(b"the previous archive")
    write, room = archive._Offsets.write, [200_000]

    def full(self, data):
        room[0] -= len(data)
        if room[0] < 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return write(self, data)

    monkeypatch.setattr(archive._Offsets, "write", full)
    err = one_line_error(
        capsys,
        [
            "eval",
            "--suite",
            "table1",
            "--decider",
            "always-overtake",
            "--shard",
            "0/300",
            "--chunk-size",
            "4",
            "--out",
            str(tmp_path / "res.json"),
            "--archive",
            str(target),
            "--no-progress",
        ],
    )
    assert err == f"error: cannot write {target}: No space left on device"
    assert target.read_bytes() == b"the previous archive" and sorted(os.listdir(tmp_path)) == ["run.mcap"]


def test_a_killed_writers_temp_file_is_swept_by_the_next_write_not_a_live_one(tmp_path):
    """SIGKILL leaves its temp file (readable, see above); the next write of that archive deletes it,
    while the temp file of a writer still running stays."""
    from overtakezoo.envs.io import check_writable

    target = tmp_path / "run.mcap"
    code = _WRITER.format(tests=os.path.dirname(__file__), path=str(target), how="kill")
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=120).returncode == -9
    [dead] = tmp_path.glob(".run.mcap.tmp-*")
    live = ArchiveRecorder(target)
    other = ArchiveRecorder(target)  # a second live writer of the same archive, in this process
    check_writable(target)  # what `eval --archive` does first
    assert sorted(tmp_path.glob(".run.mcap.tmp-*")) == sorted([live.tmp_path, other.tmp_path])
    assert not dead.exists()
    live.close(), other.close()
    assert list(tmp_path.iterdir()) == [target]


def _drive(rec, suite, index, compact=()):
    """Step one chunk by hand (modes from the episode and step, not the row), recording it; at the steps
    in ``compact`` the finished rows are compacted away (``core.clone(rows=keep)`` and ``keep_rows``),
    as the runner will do."""
    from overtakezoo.envs import OvertakeCore

    core = OvertakeCore(suite.config)
    core.reset(suite.scenarios().take(index))
    ids = np.arange(len(index))  # each current row's episode (position in index)
    rec.begin_chunk(core, index)
    k = 0
    while not core.done.all():
        modes = np.select([(k // 40 + ids) % 4 == 0, (k // 40 + ids) % 4 == 3], [0, 2], 1).astype(np.int64)
        rec.record_step(core, modes, core.step(modes))
        k += 1
        if k in compact:
            keep = np.flatnonzero(~core.done)
            assert 0 < keep.size < core.num  # a real compaction
            core, ids = core.clone(rows=keep), ids[keep]
            rec.keep_rows(keep)
    rec.end_chunk(core)


def _same_episodes(a, b):
    assert [e.index for e in a] == [e.index for e in b]
    for x, y in zip(a, b, strict=True):
        for name, u in vars(x).items():
            v = getattr(y, name)
            if isinstance(u, dict):
                assert u.keys() == v.keys()
                for key in u:
                    np.testing.assert_array_equal(np.asarray(u[key]), np.asarray(v[key]), err_msg=f"{name}.{key}")
            else:
                np.testing.assert_array_equal(np.asarray(u), np.asarray(v), err_msg=name)


def _scenes_by_episode(path):
    """Each episode's /tf and /scene/* messages, decoded, with times relative to its start (the
    absolute times in them masked: episodes may be written in another order)."""
    import re

    entries, out = list_episodes(path), {}
    starts = [e.start_ns for e in entries]
    for topic, t, msg in _decoded(path):
        if topic == "/tf" or topic.startswith("/scene/"):
            e = entries[int(np.searchsorted(starts, t, side="right")) - 1]
            text = re.sub(r"Time\(sec=\d+, nanosec=\d+\)", "T", repr(msg))
            out.setdefault(e.index, []).append((topic, t - e.start_ns, text))
    return out


@pytest.mark.parametrize("early", [False, True])
def test_keep_rows_compaction_mid_chunk_reads_back_the_same_episodes(tmp_path, monkeypatch, early):
    """A chunk recorded whole, and again with its finished rows compacted away twice mid-chunk
    (keep_rows): the same episodes, scene included. ``early``: a tiny buffer budget, so finished
    episodes are also written before the chunk ends (and compaction meets written rows)."""
    from overtakezoo.benchmark.archive import recorder as rec_mod

    if early:
        monkeypatch.setattr(rec_mod, "FLUSH_ROW_STEPS", 2000)
    suite = load_suite("table1")
    index = np.arange(100, 300)
    paths = [tmp_path / "whole.mcap", tmp_path / "compacted.mcap"]
    for path, compact in zip(paths, [(), (120, 260)], strict=True):
        with ArchiveRecorder(path, scene_every=3) as rec:
            _drive(rec, suite, index, compact)
    _same_episodes(read_archive(paths[0]), read_archive(paths[1]))
    assert len(read_archive(paths[0])) == len(index)
    assert _scenes_by_episode(paths[0]) == _scenes_by_episode(paths[1])
    with ArchiveRecorder(tmp_path / "bad.mcap") as rec:  # dropping a running row is refused
        from overtakezoo.envs import OvertakeCore

        core = OvertakeCore(suite.config)
        core.reset(suite.scenarios().take(index[:4]))
        rec.begin_chunk(core, index[:4])
        with pytest.raises(ValueError, match="only finished rows"):
            rec.keep_rows(np.array([0, 1]))


def test_the_runner_dropping_finished_rows_writes_the_same_archive(tmp_path, monkeypatch):
    """eval --archive with the runner's compaction (finished rows dropped, the recorder's keep_rows)
    writes the same bytes as stepping the whole batch."""
    from overtakezoo import zoo
    from overtakezoo.benchmark.run import runner

    suite = load_suite("table1")
    digests = []
    for floor in (10**9, 8):
        monkeypatch.setattr(runner, "MIN_COMPACT_ROWS", floor)
        path = tmp_path / f"run-{floor}.mcap"
        with ArchiveRecorder(path) as rec:
            run_suite(suite, zoo.load("rule-fsm", suite.config), progress=False, recorder=rec, limit=40)
        digests.append(path.read_bytes())
    assert digests[0] == digests[1] and len(list_episodes(tmp_path / "run-8.mcap")) == 40
