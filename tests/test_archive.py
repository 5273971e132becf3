"""MCAP archives: a small run recorded through the runner, read back exactly; replay; bad input."""

from __future__ import annotations

import json
import shutil

import jsonschema
import numpy as np
import pytest
from mcap.reader import make_reader

from overtakezoo.benchmark.archive import (EPISODE_STRIDE_NS, ArchiveRecorder, list_episodes, read_archive,
                                           read_episode)
from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.runner import run_suite
from overtakezoo.benchmark.suites import load_suite
from overtakezoo.envs import OUTCOME_NAMES
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
            self.episodes[ep] = {"steps": steps, "ego": log["ego"][: steps + 1, r],
                                 "npc_s": log["npc_s"][: steps + 1, r], "npc_v": log["npc_v"][: steps + 1, r],
                                 "mode": log["mode"][:steps, r], "rew": log["rew"][:steps, r]}


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    path = tmp_path_factory.mktemp("archive") / "run.mcap"
    suite = load_suite("table1")
    with ArchiveRecorder(path, scene_every=5) as rec:
        tee = Tee(rec)
        results = run_suite(suite, MixedDecider(suite.config), shard=SHARD, chunk_size=8, progress=False,
                            recorder=tee)  # 3 chunks: 8, 8, 4
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
        for key, src in (("episode_time", "t"), ("completion_time", "completion_time"),
                         ("opposite_time", "opposite_time"), ("min_ttc", "min_ttc"), ("peak_jerk", "peak_jerk")):
            np.testing.assert_equal(np.round(ep.summary[src], 4), per[key][r])


def test_index_and_single_episode(run):
    path, results, _ = run
    entries = list_episodes(path)
    assert [e.index for e in entries] == list(range(60, 80))
    assert all(e.start_ns == e.index * EPISODE_STRIDE_NS for e in entries)
    ep = read_episode(path, 71)
    full = {e.index: e for e in read_archive(path)}[71]
    assert ep.outcome == full.outcome and np.array_equal(ep.ego["x"], full.ego["x"])
    assert entries[11].outcome == ep.outcome and entries[11].steps == ep.steps
    with pytest.raises(UserError, match="episode 5 is not in"):
        read_episode(path, 5)


def test_messages_follow_their_schemas_and_times_are_monotonic(run):
    path, _, _ = run
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert all(c.compression == "zstd" for c in summary.chunk_indexes)
        seen: dict[str, int] = {}
        last = -1
        for schema, channel, msg in reader.iter_messages(log_time_order=False):
            assert msg.log_time >= last  # written in time order through the whole file
            last = msg.log_time
            data = json.loads(msg.data)
            if seen.get(channel.topic, 0) < 30:  # validating every message would be slow
                jsonschema.validate(data, json.loads(schema.data))
            seen[channel.topic] = seen.get(channel.topic, 0) + 1
            if channel.topic not in ("/scene", "/tf"):
                assert data["episode"] == msg.log_time // EPISODE_STRIDE_NS
    assert summary.schemas[summary.channels[next(c for c, ch in summary.channels.items()
                                                  if ch.topic == "/scene")].schema_id].name == "foxglove.SceneUpdate"
    assert {"/ego", "/npcs", "/decision", "/planner", "/reward", "/episode/spec", "/episode/summary",
            "/scene", "/tf"} <= set(seen)


def test_truncated_or_corrupt_archive_is_one_clear_error(run, tmp_path, capsys):
    path, _, _ = run
    data = path.read_bytes()
    with open(path, "rb") as f:
        chunk = make_reader(f).get_summary().chunk_indexes[1]
    flipped = bytearray(data)
    flipped[chunk.chunk_start_offset + chunk.chunk_length // 2] ^= 0x5A  # inside a compressed chunk
    for name, blob in (("cut.mcap", data[: len(data) // 2]), ("tail.mcap", data[:-100]), ("junk.mcap", b"x" * 50),
                       ("flip.mcap", bytes(flipped))):
        bad = tmp_path / name
        bad.write_bytes(blob)
        with pytest.raises(UserError, match="truncated or corrupt"):
            read_archive(bad)
        if name == "flip.mcap":  # the index is intact: listing works, reading the damaged chunk does not
            episode = chunk.message_start_time // EPISODE_STRIDE_NS
            assert main(["replay", str(bad), "--episode", str(episode), "--out", str(tmp_path / "x.png")]) == 2
        else:
            assert main(["replay", str(bad), "--list"]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error:") and err.count("\n") == 1


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


def test_fast_message_path_writes_the_same_bytes_as_mcap_add_message(tmp_path, monkeypatch):
    from overtakezoo.benchmark import mcap_sink

    suite = load_suite("table1")
    blobs = []
    for fast in (True, False):
        monkeypatch.setattr(mcap_sink, "FAST_WRITES", fast)
        path = tmp_path / f"fast-{fast}.mcap"
        # A small chunk size so chunks are finalized in the middle of episodes too.
        with ArchiveRecorder(path, scene_every=7, chunk_size=64 << 10) as rec:
            assert rec._sink.fast is fast
            run_suite(suite, MixedDecider(suite.config), shard=(0, 600), progress=False, recorder=rec)
        blobs.append(path.read_bytes())
    assert blobs[0] == blobs[1]
    assert len(read_archive(tmp_path / "fast-True.mcap")) == 5


def test_replay_help_has_examples(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["replay", "--help"])
    assert exc.value.code == 0 and "examples:" in capsys.readouterr().out


def test_eval_archive_end_to_end(tmp_path, capsys):
    from overtakezoo.benchmark.archive import read_archive_meta
    from overtakezoo.benchmark.suites import SUITES_DIR

    suite = tmp_path / "tiny.toml"
    suite.write_text((SUITES_DIR / "table1.toml").read_text().replace("count = 3000", "count = 8")
                     .replace('name = "table1"', 'name = "tiny"'))
    out, mcap = tmp_path / "res.json", tmp_path / "run.mcap"
    assert main(["eval", "--suite", str(suite), "--decider", "always-overtake", "--out", str(out),
                 "--archive", str(mcap), "--no-progress"]) == 0
    results = json.loads(out.read_text())
    outcomes = [OUTCOME_NAMES[o] for o in results["scenarios"]["outcome"]]
    assert [e.outcome for e in list_episodes(mcap)] == outcomes
    meta = read_archive_meta(mcap)
    assert meta["suite"] == "tiny" and meta["decider"] == "always-overtake"
    assert main(["eval", "--suite", str(suite), "--decider", "always-overtake", "--out", str(out),
                 "--archive", str(tmp_path)]) == 2  # a directory: refused before the run
    assert "is a directory" in capsys.readouterr().err


def test_non_finite_values_are_written_as_null(tmp_path):
    rec = ArchiveRecorder(tmp_path / "x.mcap")
    rec._dt_ns = 100_000_000
    steps = 4
    msgs = rec._state_messages(
        7, 7 * EPISODE_STRIDE_NS, [0, 1], np.arange(steps) * 0.1, np.ones((steps, 6)), np.full((steps, 2), np.inf),
        np.zeros((steps, 2)), np.ones(steps, np.int8), np.zeros(steps, np.int8), np.ones((steps, 5)),
        np.zeros((steps, 5), bool), np.array([0.0, np.nan, 1.0, 2.0]))
    rec.close()
    decoded = [json.loads(m[2]) for m in msgs]
    assert len(decoded) == 2 + 5 * (steps - 1)
    assert decoded[1]["s"] == [None, None] and decoded[6]["reward"] is None and decoded[11]["reward"] == 1.0
