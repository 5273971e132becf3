"""MCAP episode archives: a recorder the runner drives, and a reader that rebuilds episodes.

File layout (JSON messages, ``jsonschema`` schemas, zstd-compressed chunks):

- ``/episode/spec``    one message per episode at its start: the scenario row (every ``Scenarios`` field).
- ``/episode/index``   one message per episode at its start: its time range, steps and outcome.
- ``/ego``             per step: x, y, psi, v, a, steer (step 0 is the state after reset).
- ``/npcs``            per step: s, v, lane of every NPC slot (padding slots have ``present`` false in the spec).
- ``/decision``        per step >= 1: the mode applied during the step that ended at this time.
- ``/planner``         per step >= 1: rollout end offsets, blocked flags, chosen rollout.
- ``/reward``          per step >= 1: reward of that step (the return is in the summary).
- ``/episode/summary`` one message per episode at its end: outcome and episode statistics.
- ``/scene`` (``foxglove.SceneUpdate``) and ``/tf`` (``foxglove.FrameTransform``) at steps 0,
  K, 2K, ... (``scene_every`` = K, default 1: every step) and always at the episode's final step,
  so Foxglove's 3D panel shows road, vehicles and rollouts; vehicles the sensor does not see are
  grey and translucent, and the final update shows the outcome (a text, the vehicle hit in magenta).

Times: episodes lie back to back on one simulated-time line in the order they are written, each
starting ``EPISODE_GAP_NS`` after the previous one ends: ``log_time = start_ns + step * dt_ns``.
Every message carries ``episode`` (the global scenario index) and ``step``. Episode boundaries are
findable without reading any chunk: one ``episode`` metadata record per episode (index, time
range, outcome) sits in the summary section's metadata index; ``/episode/index`` and
``/episode/summary`` repeat them in the data.

Cut files: every episode is closed by a chunk of its own (``Writer.flush``) followed by its
``episode`` metadata record, so a file cut anywhere (a killed writer) holds whole episodes up to
the last metadata record; :mod:`.reader` recovers them. The recorder writes to a temp file
beside the target and renames it when finished (also on Ctrl-C or SIGTERM, with the whole
episodes), so the target is always either absent, the previous file, or complete. Writing a chunk's
episodes and finishing the file are not cut by SIGTERM or Ctrl-C (a second one included): the signal
waits until they are done. A full disk drops the temp file and raises a ``WriteError``.

Modules: this one records (capture per step, serialize per chunk); :mod:`.reader` reads;
:mod:`.format` holds topics and schemas; :mod:`.scene` builds the Foxglove scene; :mod:`.sink` is the
batched write path into mcap's Writer.

Non-finite numbers (an infinite reveal distance, ``min_ttc`` without a conflict, ``completion_time``
of a failure) are written as ``null``; the reader maps them back (inf or NaN by field).

The recorder is one class because capture, chunk serialization and the signal-safe file lifecycle
share its state; the Foxglove scene is in :mod:`.scene`, the reading side in :mod:`.reader`.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import os
import signal
import sys
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from overtakezoo.envs import MODE_NAMES, OUTCOME_NAMES

from overtakezoo.benchmark.archive.format import (EPISODE_GAP_NS, FORMAT_VERSION, FOXGLOVE_SCHEMAS, SCHEMAS, SUMMARY_FIELDS, json_number, json_ready)
from overtakezoo.benchmark.errors import UserError
from overtakezoo.envs.io import WriteError, atomic_output
from overtakezoo.benchmark.archive.scene import flatten_scenes, scene_messages, scene_state
from overtakezoo.benchmark.archive.sink import MessageSink


# ---------------------------------------------------------------------------- recorder
@dataclass
class _Chunk:
    index: np.ndarray  # (N,) global scenario indices
    steps: list[dict[str, np.ndarray]] = field(default_factory=list)  # active rows only, per step
    scenes: list[dict[str, np.ndarray]] = field(default_factory=list)  # Foxglove scene captures
    prev_done: np.ndarray | None = None  # core.done before the current step
    step: int = 0  # core.step calls so far (a row's step k is the chunk's step k: all rows start together)


class ArchiveRecorder:
    """Records every episode of a run into one MCAP file.

    The runner calls :meth:`begin_chunk` after ``core.reset``, :meth:`record_step` after each
    ``core.step`` and :meth:`end_chunk` when the chunk is done. Per step only the rows still running
    are kept (compact numpy arrays); messages are serialized at :meth:`end_chunk`, episode by
    episode in scenario order, so each episode's messages are contiguous (reading one episode
    decompresses only the chunks it spans). ``scene_every`` thins the Foxglove scene (0: none).

    The file is written to a temp file beside ``path`` (``tmp_path``, by
    :func:`overtakezoo.envs.io.atomic_output`) and renamed to ``path`` by :meth:`close` (two runs
    writing one archive never mix their bytes: the last to finish wins).
    Used as a context manager, SIGTERM raises KeyboardInterrupt while it is open (or whatever the
    previous SIGTERM handler raises: the CLI's exits 143), so an interrupted run still finishes the
    file with its whole episodes; a SIGTERM or Ctrl-C that arrives while episodes are written or the
    file is finished is held until that is done. ``progress``: a bar while a chunk's episodes are
    written (on a terminal) and a line when an interrupted run is finished.
    """

    def __init__(self, path: str | os.PathLike, scene_every: int = 1, chunk_size: int = 4 << 20,
                 metadata: dict[str, Any] | None = None, progress: bool = False) -> None:
        from mcap.writer import CompressionType, Writer

        self.path = Path(path)
        self.scene_every = int(scene_every)
        if self.scene_every < 0:
            raise UserError(f"scene_every must be >= 0 (0: no scene), got {scene_every}")
        # The file goes through the one atomic-write implementation (temp file beside the target,
        # renamed by close(); a FIFO or device target is streamed into; a symlink is followed).
        self._output = contextlib.ExitStack()
        try:
            self._stream = self._output.enter_context(atomic_output(self.path))
        except WriteError as exc:
            raise UserError(f"cannot write archive {self.path}: {exc.strerror}") from None
        self.tmp_path = Path(self._stream.name)  # what a killed run leaves: readable up to its last whole episode
        self._writer = Writer(_Offsets(self._stream), compression=CompressionType.ZSTD, chunk_size=chunk_size)
        self._writer.start(profile="", library="overtakezoo")
        self._channels: dict[str, int] = {}
        for topic, (name, schema) in {**SCHEMAS, **FOXGLOVE_SCHEMAS}.items():
            sid = self._writer.register_schema(name=name, encoding="jsonschema",
                                               data=json.dumps(schema, separators=(",", ":")).encode())
            self._channels[topic] = self._writer.register_channel(topic=topic, message_encoding="json", schema_id=sid)
        self._sink = MessageSink(self._writer)
        self._meta = {k: str(v) for k, v in (metadata or {}).items()}
        self._chunk: _Chunk | None = None
        self._core: Any = None
        self._dt_ns = 0
        self._clock_ns = 0  # where the next episode starts on the timeline
        self.episodes = 0
        self.progress = progress
        self._closed = False
        self._signals: dict[int, Any] = {}  # signal -> the handler ours replaced (while a context manager)
        self._busy = 0  # > 0 while writes that must not be cut run
        self._pending: int | None = None  # a signal held until they are done
        self._told = False  # the user was told why the exit waits

    # -- runner hooks
    def begin_chunk(self, core: Any, scenario_index: np.ndarray) -> None:
        if self._dt_ns == 0:
            self._dt_ns = int(round(core.cfg.dt * 1e9))
            self._meta.setdefault("config", json.dumps(_clean_tree(core.cfg.to_dict()), sort_keys=True))
            self._meta.update({"format_version": FORMAT_VERSION, "episode_gap_ns": str(EPISODE_GAP_NS),
                               "dt_ns": str(self._dt_ns), "scene_every": str(self.scene_every)})
            self._writer.add_metadata("overtakezoo", self._meta)
        if getattr(core, "auto_reset", False):
            raise ValueError("archives record evaluation cores (auto_reset=False): rows must not be replaced")
        self._core = core
        self._chunk = _Chunk(index=np.asarray(scenario_index, dtype=np.int64).reshape(-1))
        rows = np.arange(core.num)
        self._chunk.prev_done = core.done.copy()
        self._chunk.steps.append(self._snapshot(core, rows, None, None, None) | {"step": 0})
        if self.scene_every:
            self._chunk.scenes.append(scene_state(core, rows) | {"step": 0})

    def record_step(self, core: Any, modes: np.ndarray, step_result: Any) -> None:
        ch = self._chunk
        if ch is None:
            raise RuntimeError("record_step before begin_chunk")
        # Rows that ran this step: those not finished before it (finished rows are frozen).
        active = ~ch.prev_done
        ch.prev_done = core.done.copy()
        rows = np.flatnonzero(active)
        ch.step += 1
        if rows.size == 0:
            return
        step = ch.step
        ch.steps.append(self._snapshot(core, rows, core.mode, core.last_plan, step_result.reward) | {"step": step})
        if self.scene_every:  # every K-th step, and the final step of each row
            scene_rows = rows if step % self.scene_every == 0 else rows[ch.prev_done[rows]]
            if scene_rows.size:
                ch.scenes.append(scene_state(core, scene_rows) | {"step": step})

    def end_chunk(self, core: Any) -> None:
        ch = self._chunk
        if ch is None:
            return
        with self._writing():  # the chunk is marked written in the same uncut step (no episode twice)
            self._write_chunk(core, ch)
            self._chunk = None

    def close(self) -> None:
        """Finish the file and rename it to ``path``. A chunk still open (an interrupted run)
        contributes its finished episodes only. Idempotent; a failure drops the temp file."""
        if self._closed:
            return
        with self._writing():
            ch = self._chunk
            if ch is not None and self._core is not None:
                if self.progress and not self._told:
                    self._told = True
                    print(f"finishing {self.path}: writing the {int(ch.prev_done.sum())} finished episodes of "
                          "the open chunk", file=sys.stderr, flush=True)
                self._write_chunk(self._core, ch, whole=ch.prev_done)
                self._chunk = None
            self._sink.flush()
            self._writer.finish()
            self._closed = True
            self._output.close()  # renames the finished file into place

    @contextlib.contextmanager
    def _writing(self) -> Any:
        """Writes that must not be cut (half an episode in the file, or a file never finished): a
        signal arriving meanwhile is held and raised when they are done. A failure here leaves no
        file to finish: the temp file goes, a full disk or other OSError becomes a WriteError."""
        self._busy += 1
        try:
            yield
        except BaseException as exc:
            self._closed = True
            with contextlib.suppress(OSError):  # closing the temp file may fail again (the disk still full)
                self._output.__exit__(type(exc), exc, exc.__traceback__)
            if isinstance(exc, OSError) and not isinstance(exc, WriteError):
                raise WriteError(self.path, exc.strerror or str(exc)) from None
            raise
        finally:
            self._busy -= 1
        if not self._busy and self._pending is not None:
            signum, self._pending = self._pending, None
            self._forward(signum, None)

    def _on_signal(self, signum: int, frame: Any) -> None:
        if self._busy:
            self._pending = self._pending or signum
        else:
            self._forward(signum, frame)

    def _forward(self, signum: int, frame: Any) -> None:
        previous = self._signals.get(signum)
        if callable(previous):  # Python's Ctrl-C handler; the CLI's SIGTERM handler (exit 143)
            previous(signum, frame)
        elif previous != signal.SIG_IGN:
            raise KeyboardInterrupt(signal.Signals(signum).name)

    def __enter__(self) -> "ArchiveRecorder":
        if threading.current_thread() is threading.main_thread():
            for signum in (signal.SIGTERM, signal.SIGINT):
                self._signals[signum] = signal.signal(signum, self._on_signal)
        return self

    def __exit__(self, *exc: Any) -> None:
        try:
            self.close()
        finally:
            for signum, previous in self._signals.items():
                signal.signal(signum, previous)
            self._signals.clear()

    # -- capture (numpy, no per-row Python)
    @staticmethod
    def _snapshot(core: Any, rows: np.ndarray, mode: Any, plan: Any, reward: Any) -> dict[str, np.ndarray]:
        snap = {"rows": rows, "t": core.t[rows], "ego": np.stack(
            [core.x[rows], core.y[rows], core.psi[rows], core.v[rows], core.a[rows], core.steer[rows]], axis=1),
            "npc_s": core.npc_s[rows], "npc_v": core.npc_v[rows], "ret": core.episode_return[rows]}
        if mode is not None:
            snap.update(mode=mode[rows].astype(np.int8), rollout=plan.rollout[rows].astype(np.int8),
                        offsets=plan.offsets[rows], blocked=plan.blocked[rows], reward=np.asarray(reward)[rows])
        return snap

    # -- serialization
    def _write_chunk(self, core: Any, ch: _Chunk, whole: np.ndarray | None = None) -> None:
        """Write each episode of the chunk contiguously, in global scenario order (only the rows
        ``whole`` marks, when given), each closed by its own chunk and metadata record."""
        n = len(ch.index)
        # Flatten the per-step captures to records ordered by (row, step): one lexsort for the chunk.
        rows = np.concatenate([s["rows"] for s in ch.steps])
        steps = np.concatenate([np.full(len(s["rows"]), s["step"]) for s in ch.steps])
        order = np.lexsort((steps, rows))
        rows, steps = rows[order], steps[order]
        cat = lambda key: np.concatenate([s[key] for s in ch.steps])[order]  # noqa: E731
        t, ego, npc_s, npc_v = (cat(k) for k in ("t", "ego", "npc_s", "npc_v"))
        # Decision / planner / reward exist from step 1 on; pad step 0 so they align with the states.
        m_r = core.last_plan.offsets.shape[1] if core.last_plan is not None else 1
        first = ch.steps[0]
        first.update(mode=np.zeros(len(first["rows"]), np.int8), rollout=np.zeros(len(first["rows"]), np.int8),
                     offsets=np.zeros((len(first["rows"]), m_r)), blocked=np.zeros((len(first["rows"]), m_r), bool),
                     reward=np.zeros(len(first["rows"])))
        mode, rollout, offsets, blocked, reward = (cat(k) for k in ("mode", "rollout", "offsets", "blocked", "reward"))
        bounds = np.searchsorted(rows, np.arange(n + 1))
        scen = core.scen.to_arrays()
        info = core.info()
        lanes = core.scen.npc_lane.tolist()
        scenes, sbounds = flatten_scenes(ch.scenes, n)
        sink = self._sink
        order = np.argsort(ch.index, kind="stable")
        if whole is not None:
            order = order[whole[order]]
        bar = tqdm(order.tolist(), unit="episode", desc=f"writing {self.path.name}", leave=False,
                   disable=not self.progress or not sys.stderr.isatty())
        for k, r in enumerate(bar):
            if self._pending is not None and self.progress and not self._told:  # a held signal: say why we wait
                self._told = True
                print(f"finishing {self.path}: writing the {len(order) - k} remaining episodes of this chunk "
                      "first", file=sys.stderr, flush=True)
            ep = int(ch.index[r])
            base = self._clock_ns
            a, b = int(bounds[r]), int(bounds[r + 1])
            last = b - a - 1  # the final step of this episode
            end = base + last * self._dt_ns
            outcome = int(info["outcome"][r])
            spec = {"episode": ep, "step": 0, "t": 0.0,
                    "scenario": {name: json_ready(arr[r]) for name, arr in scen.items()}}
            self._add("/episode/spec", base, json.dumps(spec, separators=(",", ":")))
            self._add("/episode/index", base, json.dumps({
                "episode": ep, "step": 0, "start_ns": base, "end_ns": end, "steps": last,
                "outcome_name": OUTCOME_NAMES[outcome]}, separators=(",", ":")))
            msgs = self._state_messages(ep, base, lanes[r], t[a:b], ego[a:b], npc_s[a:b], npc_v[a:b], mode[a:b],
                                        rollout[a:b], offsets[a:b], blocked[a:b], reward[a:b])
            sa, sb = int(sbounds[r]), int(sbounds[r + 1])
            if sb > sa:
                sl = {k: v[sa:sb] for k, v in scenes.items()}
                ks = sl["step"]
                msgs.extend(scene_messages(ep, base, r, scen, ks, ego[a + ks], npc_s[a + ks], sl,
                                           (outcome, int(info["crash_npc"][r])) if ks[-1] == last else None,
                                           self._dt_ns, self._channels["/scene"], self._channels["/tf"]))
                msgs.sort(key=lambda m: m[1])  # stable: a step's scene and tf after its state messages
            sink.pending.extend(msgs)
            sink.flush()
            summary = {k: json_ready(info[k][r]) for k in SUMMARY_FIELDS}
            summary.update(episode=ep, step=last, t=json_ready(t[b - 1]), outcome_name=OUTCOME_NAMES[outcome],
                           start_ns=base, end_ns=end)
            self._add("/episode/summary", end, json.dumps(summary, separators=(",", ":")))
            sink.flush()
            self._writer.flush()  # the episode's last chunk is on disk before its metadata record
            self._writer.add_metadata("episode", {
                "episode": str(ep), "start_ns": str(base), "end_ns": str(end), "steps": str(last),
                "outcome": OUTCOME_NAMES[outcome], "episode_return": json_number(float(info["episode_return"][r]))})
            self._stream.flush()  # the episode is whole on disk (a killed writer keeps it)
            self.episodes += 1
            self._clock_ns = end + EPISODE_GAP_NS

    def _state_messages(self, ep: int, base: int, lanes: list[int], t: np.ndarray, ego: np.ndarray,
                        npc_s: np.ndarray, npc_v: np.ndarray, mode: np.ndarray, rollout: np.ndarray,
                        offsets: np.ndarray, blocked: np.ndarray, reward: np.ndarray) -> list[tuple[int, int, bytes]]:
        """/ego, /npcs (steps 0..T) and /decision, /planner, /reward (steps 1..T) of one episode.

        All steps go through one %-format call, the per-step values interleaved in template order.
        Floats are shortest round-trip reprs (exact); an episode holding a
        non-finite value (none seen in practice) writes those as null through ``%s``.
        """
        steps = len(t)
        m_n, m_o = npc_s.shape[1], offsets.shape[1]
        head = f'{{"episode":{ep},"step":%d,'
        lane = ",".join(map(str, lanes))
        ego_t = head + '"t":%r,"x":%r,"y":%r,"psi":%r,"v":%r,"a":%r,"steer":%r}\n'
        npc_t = head + '"s":[' + ",".join(["%r"] * m_n) + '],"v":[' + ",".join(["%r"] * m_n) + \
            f'],"lane":[{lane}]}}\n'
        dec_t = head + '%s\n'
        plan_t = head + '"offsets":[' + ",".join(["%r"] * m_o) + '],"blocked":%s,"rollout":%d}\n'
        rew_t = head + '"reward":%r}\n'
        floats = [t[:, None], ego, npc_s, npc_v, offsets, reward[:, None]]
        fixed_offsets = bool(np.isfinite(offsets).all() and (offsets == offsets[:1]).all())
        if fixed_offsets:  # the usual case (they depend on the lane width only): format them once
            plan_t = plan_t.replace(",".join(["%r"] * m_o), ",".join(map(repr, offsets[0].tolist())))
            offsets = offsets[:, :0]
        if all(np.isfinite(x).all() for x in floats):
            num = lambda x: x.T.tolist()  # noqa: E731  (one list per column)
        else:
            ego_t, npc_t, plan_t, rew_t = (x.replace("%r", "%s") for x in (ego_t, npc_t, plan_t, rew_t))
            num = lambda x: [[json_number(v) for v in col] for col in x.T.tolist()]  # noqa: E731
        weights = 1 << np.arange(blocked.shape[1])
        codes = (blocked.astype(np.int64) @ weights).tolist()
        bl_json = {c: _ENCODE(((c & weights) > 0).tolist()) for c in set(codes)}
        ks = list(range(steps))
        # One list per template field, in template order; zip + chain interleave them in C.
        cols = [ks, *num(t[:, None]), *num(ego), ks, *num(npc_s), *num(npc_v),
                ks, [_MODE_JSON[m] for m in mode.tolist()],
                ks, *num(offsets), [bl_json[c] for c in codes], rollout.tolist(), ks, *num(reward[:, None])]
        split = 1 + 7 + 1 + 2 * m_n  # the ego and npc fields; step 0 has only these
        first = ((ego_t + npc_t) % tuple(c[0] for c in cols[:split])).encode().split(b"\n")[:-1]
        rest = ((ego_t + npc_t + dec_t + plan_t + rew_t) * (steps - 1) % tuple(
            itertools.chain.from_iterable(itertools.islice(zip(*cols), 1, None)))).encode().split(b"\n")[:-1]
        chan = self._channels
        step_chans = [chan[x] for x in ("/ego", "/npcs", "/decision", "/planner", "/reward")]
        times = (base + np.repeat(np.arange(1, steps), 5) * self._dt_ns).tolist()
        out = [(step_chans[0], base, first[0]), (step_chans[1], base, first[1])]
        out.extend(zip(step_chans * (steps - 1), times, rest))
        return out

    def _add(self, topic: str, log_time: int, text: str) -> None:
        self._sink.append((self._channels[topic], log_time, text.encode()))


_ENCODE = json.JSONEncoder(separators=(",", ":"), allow_nan=False).encode  # C-accelerated lists of floats
_MODE_JSON = [f'"mode":{m},"mode_name":"{name}"}}' for m, name in enumerate(MODE_NAMES)]


class _Offsets:
    """The stream mcap's Writer writes to. It asks ``tell()`` for record offsets, which a FIFO
    target cannot answer: the offset is the number of bytes written (the file starts empty)."""

    def __init__(self, stream: Any) -> None:
        self._stream, self._pos = stream, 0

    def write(self, data: Any) -> int:
        n = self._stream.write(data)
        self._pos += n
        return n

    def tell(self) -> int:
        return self._pos

    def flush(self) -> None:
        self._stream.flush()


def recorder_for_run(path: str | os.PathLike, suite: Any, decider: Any, scene_every: int = 1,
                     progress: bool = False) -> ArchiveRecorder:
    """An :class:`ArchiveRecorder` for ``run_suite(suite, decider, recorder=...)``; the file's
    ``overtakezoo`` metadata names the suite (with its hash) and the decider."""
    return ArchiveRecorder(path, scene_every=scene_every, progress=progress, metadata={
        "suite": suite.name, "suite_version": suite.version, "suite_hash": suite.hash,
        "decider": decider.name, "decider_version": decider.version})


def _clean_tree(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _clean_tree(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean_tree(v) for v in obj]
    return json_ready(obj)
