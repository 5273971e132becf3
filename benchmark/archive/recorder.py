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

Modules: this one records (capture per step, serialize per finished episode); :mod:`.reader` reads;
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
from operator import itemgetter
from pathlib import Path
from typing import Any

import numpy as np

from overtakezoo.envs import MODE_NAMES, OUTCOME_NAMES

from overtakezoo.benchmark.archive.format import (EPISODE_GAP_NS, FORMAT_VERSION, FOXGLOVE_SCHEMAS, SCHEMAS, SUMMARY_FIELDS, json_number, json_ready)
from overtakezoo.benchmark.errors import UserError
from overtakezoo.envs.io import WriteError, atomic_output
from overtakezoo.benchmark.archive.scene import rollout_geometry, scene_messages
from overtakezoo.benchmark.archive.sink import MessageSink


# ---------------------------------------------------------------------------- recorder
BLOCK_STEPS = 32  # steps per capture block (one preallocated array per block)
FLUSH_ROW_STEPS = 1 << 18  # a chunk buffering more (row, step) captures writes its finished episodes early


class _Block:
    """Captures of steps ``start .. start + BLOCK_STEPS - 1`` for the rows running at ``start``:
    ``f`` (steps, rows, float fields) and ``i`` (steps, rows, int8 fields), filled in place."""

    def __init__(self, start: int, ids: np.ndarray, src: np.ndarray, nf: int, ni: int) -> None:
        self.start, self.ids, self.src = start, ids, src  # chunk-local row ids (increasing); their core rows
        self.cols = np.arange(len(ids))  # the columns still fed by the core (dropped rows are finished)
        self.f = np.empty((BLOCK_STEPS, len(ids), nf))
        self.i = np.empty((BLOCK_STEPS, len(ids), ni), np.int8)


@dataclass
class _Chunk:
    index: np.ndarray  # (N,) global scenario indices, by chunk-local row id
    ids: np.ndarray  # the current core's rows -> chunk-local row ids (keep_rows compacts the core)
    scen: dict[str, np.ndarray]  # the scenario arrays, by row id
    lanes: list[list[int]]
    m_r: int  # rollouts
    last: np.ndarray  # (N,) each row's final step, -1 while it runs
    written: np.ndarray  # (N,) bool: its episode is in the file
    blocks: list[_Block] = field(default_factory=list)
    prev_done: np.ndarray | None = None  # core.done before the current step
    step: int = 0  # core.step calls so far (a row's step k is the chunk's step k: all rows start together)
    info: dict[str, np.ndarray] = field(default_factory=dict)  # summary values of finished rows, by row id


class ArchiveRecorder:
    """Records every episode of a run into one MCAP file.

    The runner calls :meth:`begin_chunk` after ``core.reset``, :meth:`record_step` after each
    ``core.step`` and :meth:`end_chunk` when the chunk is done; :meth:`keep_rows` when it compacts
    finished rows away mid-chunk. Per step the state of the rows still running is copied into
    preallocated numpy blocks (``BLOCK_STEPS`` steps each, no per-row Python); messages are
    serialized per episode, in bulk (one %-template per topic and episode), at :meth:`end_chunk` in
    scenario order, so each episode's messages are contiguous (reading one episode decompresses only
    the chunks it spans). A big chunk (more than ``FLUSH_ROW_STEPS`` buffered row-steps) writes its
    finished episodes early, in scenario order within each batch, and frees their captures: memory
    is bounded by the history of the rows still running. ``scene_every`` thins the Foxglove scene
    (0: none).

    The file is written to a temp file beside ``path`` (``tmp_path``, by
    :func:`overtakezoo.envs.io.atomic_output`) and renamed to ``path`` by :meth:`close` (two runs
    writing one archive never mix their bytes: the last to finish wins).
    Used as a context manager, SIGTERM raises KeyboardInterrupt while it is open (or whatever the
    previous SIGTERM handler raises: the CLI's exits 143), so an interrupted run still finishes the
    file with its whole episodes; a SIGTERM or Ctrl-C that arrives while episodes are written or the
    file is finished is held until that is done. ``progress``: a line when an interrupted run is
    finished (episodes are now written as they finish, so there is no separate writing phase to show).
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
        n = core.num
        self._chunk = ch = _Chunk(index=np.asarray(scenario_index, dtype=np.int64).reshape(-1), ids=np.arange(n),
                                  scen=core.scen.to_arrays(), lanes=core.scen.npc_lane.tolist(),
                                  m_r=core.cfg.planner.num_rollouts + 1, last=np.full(n, -1),
                                  written=np.zeros(n, bool))
        ch.prev_done = core.done.copy()
        self._capture(core, ch, np.ones(n, bool))
        self._finished(core, ch, np.flatnonzero(ch.prev_done))

    def record_step(self, core: Any, modes: np.ndarray, step_result: Any) -> None:
        ch = self._chunk
        if ch is None:
            raise RuntimeError("record_step before begin_chunk")
        # Rows that ran this step: those not finished before it (finished rows are frozen).
        active = ~ch.prev_done
        ch.prev_done = core.done.copy()
        ch.step += 1
        if not active.any():
            return
        self._capture(core, ch, active, step_result.reward)
        self._finished(core, ch, np.flatnonzero(active & ch.prev_done))
        if sum(b.f.shape[1] for b in ch.blocks) * BLOCK_STEPS > FLUSH_ROW_STEPS:
            done = np.flatnonzero((ch.last >= 0) & ~ch.written)
            if len(done) >= 64:  # a big chunk: write its finished episodes now, keeping the buffers bounded
                with self._writing():
                    self._write_episodes(ch, done)

    def keep_rows(self, rows: np.ndarray) -> None:
        """The runner compacted its core to ``rows`` (positions into the current batch, increasing;
        the rows dropped have finished): the next calls get a core whose row i was row ``rows[i]``."""
        ch = self._chunk
        if ch is None:
            raise RuntimeError("keep_rows before begin_chunk")
        rows = np.asarray(rows, dtype=np.int64)
        if (ch.last[np.setdiff1d(ch.ids, ch.ids[rows])] < 0).any():
            raise ValueError("keep_rows: only finished rows may be dropped")
        n_old = len(ch.ids)
        ch.ids, ch.prev_done = ch.ids[rows], ch.prev_done[rows]
        new_pos = np.full(n_old, -1)
        new_pos[rows] = np.arange(len(rows))
        for blk in ch.blocks:  # the core rows feeding each block, renumbered (dropped ones stop)
            src = new_pos[blk.src]
            keep = src >= 0
            blk.cols, blk.src = blk.cols[keep], src[keep]

    def end_chunk(self, core: Any) -> None:
        ch = self._chunk
        if ch is None:
            return
        with self._writing():  # the chunk is marked written in the same uncut step (no episode twice)
            self._finished(core, ch, np.flatnonzero(ch.last[ch.ids] < 0))  # (all are, after run_to_end)
            self._write_episodes(ch, np.flatnonzero((ch.last >= 0) & ~ch.written))
            self._chunk = None

    def close(self) -> None:
        """Finish the file and rename it to ``path``. A chunk still open (an interrupted run)
        contributes its finished episodes only. Idempotent; a failure drops the temp file."""
        if self._closed:
            return
        with self._writing():
            ch = self._chunk
            if ch is not None:
                todo = np.flatnonzero((ch.last >= 0) & ~ch.written)
                if self.progress and not self._told:
                    self._told = True
                    print(f"finishing {self.path}: writing the {len(todo)} finished episodes of "
                          "the open chunk", file=sys.stderr, flush=True)
                self._write_episodes(ch, todo)
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
    def _capture(self, core: Any, ch: _Chunk, active: np.ndarray, reward: Any = None) -> None:
        """Append the state of the running rows to the open block (a new block every BLOCK_STEPS
        steps, holding only the rows still running then)."""
        j = ch.step - ch.blocks[-1].start if ch.blocks else BLOCK_STEPS
        if j >= BLOCK_STEPS:
            src = np.flatnonzero(active)
            m = core.npc_s.shape[1]
            ch.blocks.append(_Block(ch.step, ch.ids[src], src, 8 + 2 * m + ch.m_r, 3 + ch.m_r))
            self._compact(ch)
            j = 0
        blk = ch.blocks[-1]
        r, cols = blk.src, blk.cols
        f = [core.t, core.x, core.y, core.psi, core.v, core.a, core.steer]
        f = np.stack([x[r] for x in f], axis=1)
        plan = core.last_plan
        if plan is None:  # step 0: no decision, plan or reward yet (padded with zeros, as before)
            zf, zi = np.zeros((len(r), 1 + ch.m_r)), np.zeros((len(r), 1 + ch.m_r), np.int8)
            pf, pi = zf, zi
        else:
            pf = np.concatenate([np.asarray(reward)[r, None], plan.offsets[r]], axis=1)
            pi = np.concatenate([plan.rollout[r, None], plan.blocked[r]], axis=1)
        blk.f[j, cols] = np.concatenate([f, core.npc_s[r], core.npc_v[r], pf], axis=1)
        blk.i[j, cols] = np.concatenate([core.mode[r, None], core.rollout[r, None], pi], axis=1)

    def _finished(self, core: Any, ch: _Chunk, rows: np.ndarray) -> None:
        """Rows (of the current core) that just finished: their final step and summary values."""
        if rows.size == 0:
            return
        ids = ch.ids[rows]
        ch.last[ids] = ch.step
        for k, v in core.info().items():
            if k not in ch.info:
                ch.info[k] = np.zeros((len(ch.index),) + np.shape(v)[1:], np.asarray(v).dtype)
            ch.info[k][ids] = v[rows]

    @staticmethod
    def _compact(ch: _Chunk) -> None:
        """Drop the columns of written episodes from blocks where they are most of it (frees memory)."""
        keep_blocks = []
        for blk in ch.blocks:
            live = ~ch.written[blk.ids]
            if not live.any():
                continue
            if live.sum() * 2 < len(live):
                pos = np.full(len(live), -1)
                pos[live] = np.arange(int(live.sum()))
                blk.ids, blk.f, blk.i = blk.ids[live], blk.f[:, live], blk.i[:, live]
                fed = pos[blk.cols] >= 0
                blk.cols, blk.src = pos[blk.cols][fed], blk.src[fed]
            keep_blocks.append(blk)
        ch.blocks[:] = keep_blocks

    # -- serialization
    def _write_episodes(self, ch: _Chunk, ids: np.ndarray) -> None:
        """Write the finished rows ``ids`` contiguously, in global scenario order, each closed by its
        own chunk and metadata record; then free their captures."""
        ids = ids[np.argsort(ch.index[ids], kind="stable")]
        for g in range(0, len(ids), 128):  # gather a group's captures at once (bounded copies)
            group = ids[g:g + 128]
            f_parts, i_parts = [], []
            for blk in ch.blocks:
                if blk.start > ch.last[group].max():
                    break
                cols = np.minimum(np.searchsorted(blk.ids, group), len(blk.ids) - 1)
                f_parts.append(blk.f[:, cols])
                i_parts.append(blk.i[:, cols])
            f, i = np.concatenate(f_parts), np.concatenate(i_parts)  # (steps, group, fields)
            for k, r in enumerate(group.tolist()):
                if self._pending is not None and self.progress and not self._told:  # a held signal: say why
                    self._told = True
                    print(f"finishing {self.path}: writing the {len(ids) - g - k} remaining episodes of this "
                          "chunk first", file=sys.stderr, flush=True)
                last = int(ch.last[r])
                self._write_episode(ch, r, f[:last + 1, k], i[:last + 1, k])
                ch.written[r] = True
        self._compact(ch)

    def _write_episode(self, ch: _Chunk, r: int, f: np.ndarray, i: np.ndarray) -> None:
        ep = int(ch.index[r])
        base = self._clock_ns
        last = len(f) - 1  # the final step of this episode
        end = base + last * self._dt_ns
        info, scen = ch.info, ch.scen
        outcome = int(info["outcome"][r])
        m = (f.shape[1] - 8 - ch.m_r) // 2
        t, ego, npc_s, npc_v = f[:, 0], f[:, 1:7], f[:, 7:7 + m], f[:, 7 + m:7 + 2 * m]
        reward, offsets = f[:, 7 + 2 * m], f[:, 8 + 2 * m:]
        mode, rollout, blocked = i[:, 0].copy(), i[:, 2], i[:, 3:].astype(bool)
        mode[0] = 0  # step 0 has no decision (padding, as the state topics always had)
        spec = {"episode": ep, "step": 0, "t": 0.0,
                "scenario": {name: json_ready(arr[r]) for name, arr in scen.items()}}
        self._add("/episode/spec", base, json.dumps(spec, separators=(",", ":")))
        self._add("/episode/index", base, json.dumps({
            "episode": ep, "step": 0, "start_ns": base, "end_ns": end, "steps": last,
            "outcome_name": OUTCOME_NAMES[outcome]}, separators=(",", ":")))
        msgs = self._state_messages(ep, base, ch.lanes[r], t, ego, npc_s, npc_v, mode, rollout, offsets,
                                    blocked, reward)
        if self.scene_every:  # every K-th step, and the final step
            ks = np.unique(np.append(np.arange(0, last + 1, self.scene_every), last))
            rx, ry = rollout_geometry(self._core.cfg.planner, ego[ks, 0], ego[ks, 1], ego[ks, 3],
                                      np.full(len(ks), scen["lane_width"][r]))
            cap = {"rollout_x": rx, "rollout_y": ry, "blocked": blocked[ks], "mode": i[ks, 0], "rollout": i[ks, 1]}
            msgs.extend(scene_messages(ep, base, r, scen, ks, ego[ks], npc_s[ks], cap,
                                       (outcome, int(info["crash_npc"][r])) if ks[-1] == last else None,
                                       self._dt_ns, self._channels["/scene"], self._channels["/tf"]))
            # Time order, stable: a step's scene and tf after its state messages (numpy, no key calls).
            order = np.argsort(np.fromiter(map(itemgetter(1), msgs), np.int64, len(msgs)), kind="stable")
            msgs = list(itemgetter(*order.tolist())(msgs)) if len(msgs) > 1 else msgs
        sink = self._sink
        sink.pending.extend(msgs)
        sink.flush()
        summary = {k: json_ready(info[k][r]) for k in SUMMARY_FIELDS}
        summary.update(episode=ep, step=last, t=json_ready(t[-1]), outcome_name=OUTCOME_NAMES[outcome],
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
