"""MCAP episode archives: a recorder the runner drives, and a reader that rebuilds episodes.

File layout (format 3; zstd-compressed chunks). Per-episode topics are JSON (``jsonschema``
schemas); per-step topics are CDR with ROS 2 message definitions (``ros2msg``), which Foxglove
and mcap's readers decode natively (:mod:`.format` holds the definitions):

- ``/episode/spec``    one message per episode at its start: the scenario row (every ``Scenarios`` field).
- ``/episode/index``   one message per episode at its start: its time range, steps and outcome.
- ``/state``           per step (``overtakezoo_msgs/msg/State``): episode, step, t, x, y, psi, v, a,
  steer, reward, mode, rollout, npc_s, npc_v (every NPC slot; padding slots have ``present`` false
  in the spec), offsets, blocked. Step 0 is the state after reset (its decision, plan and reward
  fields are zero); step k >= 1 carries the mode, plan and reward of the step that ended there.
- ``/episode/summary`` one message per episode at its end: outcome and episode statistics.
- ``/tf`` (``foxglove_msgs/msg/FrameTransforms``) at steps 0, K, 2K, ... (``scene_every`` = K,
  default 1: every step) and always at the episode's final step: the frames of the ego and NPCs;
  ``/scene/*`` (``foxglove_msgs/msg/SceneUpdate``) when what they draw changes (:mod:`.scene`), so
  Foxglove's 3D panel shows road, vehicles and rollouts; vehicles the sensor does not see are grey
  and translucent, and the final update shows the outcome (a text, the vehicle hit in magenta).

Times: episodes lie back to back on one simulated-time line in the order they are written, each
starting ``EPISODE_GAP_NS`` after the previous one ends: ``log_time = start_ns + step * dt_ns``.
Episode boundaries are findable without reading any chunk: one ``episode`` metadata record per
episode (index, time range, outcome) sits in the summary section's metadata index;
``/episode/index`` and ``/episode/summary`` repeat them in the data.

Encoding: the per-step messages of a group of finished episodes are built by numpy, one pass per
message kind (fixed-shape CDR templates, :mod:`.cdr`), and written by :mod:`.mcapfile` in chunks
of whole episodes: within a chunk, messages are grouped by topic (each topic in time order; MCAP
readers order by time through the message indexes). No Python runs per step or per message.

Cut files: every chunk holds whole episodes and is followed by their ``episode`` metadata records,
so a file cut anywhere (a killed writer) holds whole episodes up to the last metadata record;
:mod:`.reader` recovers them. The recorder writes to a temp file
beside the target and renames it when finished (also on Ctrl-C or SIGTERM, with the whole
episodes), so the target is always either absent, the previous file, or complete. Writing a chunk's
episodes and finishing the file are not cut by SIGTERM or Ctrl-C (a second one included): the signal
waits until they are done. A full disk drops the temp file and raises a ``WriteError``.

Modules: this one records (capture per step, encode per group of finished episodes); :mod:`.reader`
reads; :mod:`.format` holds topics and schemas; :mod:`.scene` builds the Foxglove scene; :mod:`.cdr`
the message templates; :mod:`.mcapfile` writes the MCAP records.

Floats are stored as float64 (exact). In the JSON topics, non-finite numbers (an infinite reveal
distance, ``min_ttc`` without a conflict, ``completion_time`` of a failure) are written as
``null``; the reader maps them back (inf or NaN by field).

The recorder is one class because capture, chunk serialization and the signal-safe file lifecycle
share its state; the Foxglove scene is in :mod:`.scene`, the reading side in :mod:`.reader`.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import struct
import sys
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from overtakezoo.benchmark.archive.cdr import Layout
from overtakezoo.benchmark.archive.format import (
    EPISODE_GAP_NS,
    FORMAT_VERSION,
    ROS2_SCHEMAS,
    SCHEMAS,
    SUMMARY_FIELDS,
    json_number,
    json_ready,
)
from overtakezoo.benchmark.archive.mcapfile import McapFile
from overtakezoo.benchmark.archive.scene import SceneLayouts, scene_records
from overtakezoo.benchmark.errors import UserError
from overtakezoo.envs import OUTCOME_NAMES
from overtakezoo.envs.io import WriteError, atomic_output

# ---------------------------------------------------------------------------- recorder
BLOCK_STEPS = 32  # steps per capture block (one preallocated array per block)
GROUP = 64  # episodes encoded together (one numpy pass per message kind)
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
    encoded per group of ``GROUP`` episodes, one numpy pass per message kind, at :meth:`end_chunk` in
    scenario order, in chunks of whole episodes (reading one episode decompresses only its chunk). A
    big chunk (more than ``FLUSH_ROW_STEPS`` buffered row-steps) writes its finished episodes early,
    in scenario order within each batch, and frees their captures: memory is bounded by the history
    of the rows still running. ``scene_every`` thins the Foxglove scene (0: none).

    The file is written to a temp file beside ``path`` (``tmp_path``, by
    :func:`overtakezoo.envs.io.atomic_output`) and renamed to ``path`` by :meth:`close` (two runs
    writing one archive never mix their bytes: the last to finish wins).
    Used as a context manager, SIGTERM raises KeyboardInterrupt while it is open (or whatever the
    previous SIGTERM handler raises: the CLI's exits 143), so an interrupted run still finishes the
    file with its whole episodes; a SIGTERM or Ctrl-C that arrives while episodes are written or the
    file is finished is held until that is done. ``progress``: a line when an interrupted run is
    finished (episodes are now written as they finish, so there is no separate writing phase to show).
    """

    def __init__(
        self,
        path: str | os.PathLike,
        scene_every: int = 1,
        chunk_size: int = 4 << 20,
        metadata: dict[str, Any] | None = None,
        progress: bool = False,
    ) -> None:
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
        self._file = McapFile(_Offsets(self._stream))
        self._chunk_size = int(chunk_size)
        self._channels: dict[str, int] = {}
        for topic, (name, schema) in SCHEMAS.items():
            self._channels[topic] = self._file.register(
                topic, name, "jsonschema", json.dumps(schema, separators=(",", ":")).encode(), "json"
            )
        for topic, (name, text) in ROS2_SCHEMAS.items():
            self._channels[topic] = self._file.register(topic, name, "ros2msg", text.encode(), "cdr")
        self._lay: tuple[Layout, SceneLayouts] | None = None
        self._json: list[tuple[int, int, bytes]] = []
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
            self._meta.update(
                {
                    "format_version": FORMAT_VERSION,
                    "episode_gap_ns": str(EPISODE_GAP_NS),
                    "dt_ns": str(self._dt_ns),
                    "scene_every": str(self.scene_every),
                }
            )
            self._file.add_metadata("overtakezoo", self._meta)
        if getattr(core, "auto_reset", False):
            raise ValueError("archives record evaluation cores (auto_reset=False): rows must not be replaced")
        self._core = core
        n = core.num
        self._chunk = ch = _Chunk(
            index=np.asarray(scenario_index, dtype=np.int64).reshape(-1),
            ids=np.arange(n),
            scen=core.scen.to_arrays(),
            lanes=core.scen.npc_lane.tolist(),
            m_r=core.cfg.planner.num_rollouts + 1,
            last=np.full(n, -1),
            written=np.zeros(n, bool),
        )
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
                    print(
                        f"finishing {self.path}: writing the {len(todo)} finished episodes of the open chunk",
                        file=sys.stderr,
                        flush=True,
                    )
                self._write_episodes(ch, todo)
                self._chunk = None
            self._file.finish()
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

    def __enter__(self) -> ArchiveRecorder:
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
        m = core.npc_s.shape[1]
        full = len(r) == blk.f.shape[1]  # every column of the block still fed (cols is then 0..n-1)
        fv = blk.f[j] if full else np.empty((len(r), blk.f.shape[2]))
        iv = blk.i[j] if full else np.empty((len(r), blk.i.shape[2]), np.int8)
        for c, x in enumerate((core.t, core.x, core.y, core.psi, core.v, core.a, core.steer)):
            fv[:, c] = x[r]  # column by column into the block (no stacked temporaries)
        fv[:, 7 : 7 + m] = core.npc_s[r]
        fv[:, 7 + m : 7 + 2 * m] = core.npc_v[r]
        iv[:, 0], iv[:, 1] = core.mode[r], core.rollout[r]
        plan = core.last_plan
        if plan is None:  # step 0: no decision, plan or reward yet (padded with zeros, as before)
            fv[:, 7 + 2 * m :] = 0.0
            iv[:, 2:] = 0
        else:
            fv[:, 7 + 2 * m] = np.asarray(reward)[r]
            fv[:, 8 + 2 * m :] = plan.offsets[r]
            iv[:, 2] = plan.rollout[r]
            iv[:, 3:] = plan.blocked[r]
        if not full:
            blk.f[j, cols], blk.i[j, cols] = fv, iv

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

    # -- serialization (numpy over a group of episodes; Python per episode only for its JSON and metadata)
    def _write_episodes(self, ch: _Chunk, ids: np.ndarray) -> None:
        """Write the finished rows ``ids`` in global scenario order, in chunks of whole episodes,
        each chunk followed by its episodes' metadata records; then free their captures."""
        ids = ids[np.argsort(ch.index[ids], kind="stable")]
        for g in range(0, len(ids), GROUP):  # gather a group's captures at once (bounded copies)
            group = ids[g : g + GROUP]
            if self._pending is not None and self.progress and not self._told:  # a held signal: say why
                self._told = True
                print(
                    f"finishing {self.path}: writing the {len(ids) - g} remaining episodes of this chunk first",
                    file=sys.stderr,
                    flush=True,
                )
            f_parts, i_parts = [], []
            for blk in ch.blocks:
                if blk.start > ch.last[group].max():
                    break
                cols = np.minimum(np.searchsorted(blk.ids, group), len(blk.ids) - 1)
                f_parts.append(blk.f[:, cols].transpose(1, 0, 2))
                i_parts.append(blk.i[:, cols].transpose(1, 0, 2))
            # (episodes, steps, fields), contiguous: one copy out of the blocks, episode-major
            self._write_group(ch, group, np.concatenate(f_parts, axis=1), np.concatenate(i_parts, axis=1))
            ch.written[group] = True
        self._compact(ch)

    def _layouts(self, m: int, r: int) -> tuple[Layout, SceneLayouts]:
        if self._lay is None or self._lay[1].m != m or self._lay[1].r != r:
            self._lay = (state_layout(self._channels["/state"], m, r), SceneLayouts(self._channels, m, r))
        return self._lay

    def _write_group(self, ch: _Chunk, group: np.ndarray, f: np.ndarray, i: np.ndarray) -> None:
        """Episodes ``group`` (f, i: their captures, (episodes, steps, fields)) as records: one
        numpy pass per message kind over all their steps, then sliced into chunks of whole episodes."""
        last = ch.last[group]
        n_ep, m, r = len(group), (f.shape[2] - 8 - ch.m_r) // 2, ch.m_r
        valid = np.arange(f.shape[1])[None, :] <= last[:, None]  # (episodes, steps)
        fr, ir = f[valid], i[valid]  # (rows, fields), episode-major
        steps = last + 1
        row0 = np.concatenate([[0], np.cumsum(steps)[:-1]])
        ep = np.repeat(np.arange(n_ep), steps)
        k = np.arange(len(ep)) - row0[ep]
        dt = self._dt_ns
        base = self._clock_ns + np.concatenate([[0], np.cumsum(last * dt + EPISODE_GAP_NS)[:-1]])
        ns = base[ep] + k * dt
        state_lay, scene_lay = self._layouts(m, r)
        mode = np.where(k == 0, 0, ir[:, 0])  # step 0 has no decision (padding)
        st = state_lay.fill(
            len(ep),
            log_time=ns,
            publish_time=ns,
            episode=ch.index[group][ep],
            step=k,
            t=fr[:, 0],
            x=fr[:, 1],
            y=fr[:, 2],
            psi=fr[:, 3],
            v=fr[:, 4],
            a=fr[:, 5],
            steer=fr[:, 6],
            npc_s=fr[:, 7 : 7 + m],
            npc_v=fr[:, 7 + m : 7 + 2 * m],
            reward=fr[:, 7 + 2 * m],
            offsets=fr[:, 8 + 2 * m :],
            mode=mode,
            rollout=ir[:, 2],
            blocked=ir[:, 3:],
        )
        kinds = [(st, ep)]
        if self.scene_every:  # every K-th step, and the final step
            sel = np.flatnonzero((k % self.scene_every == 0) | (k == last[ep]))
            s = {
                "ep": ep[sel],
                "ns": ns[sel],
                "k": k[sel],
                "first": k[sel] == 0,
                "final": k[sel] == last[ep[sel]],
                "x": fr[sel, 1],
                "y": fr[sel, 2],
                "psi": fr[sel, 3],
                "v": fr[sel, 4],
                "npc_s": fr[sel, 7 : 7 + m],
                "mode": ir[sel, 0],
                "chosen": ir[sel, 1],
                "blocked": ir[sel, 3:].astype(bool),
            }
            sc = ch.scen
            e = {
                key: sc[key][group]
                for key in (
                    "lane_width",
                    "road_length",
                    "goal_s",
                    "ego_length",
                    "ego_width",
                    "npc_lane",
                    "npc_length",
                    "npc_width",
                    "npc_present",
                    "sensor_range",
                    "npc_reveal",
                )
            }
            e.update(
                npc_s0=sc["npc_s"][group],
                outcome=ch.info["outcome"][group],
                crash_npc=ch.info["crash_npc"][group],
                index=ch.index[group],
            )
            kinds += [(recs, s["ep"][rows]) for recs, rows in scene_records(scene_lay, self._core.cfg.planner, s, e)]
        # Per kind: its records' bytes, and where each episode's records start.
        blobs = [memoryview(recs.view(np.uint8)) for recs, _ in kinds]  # sliced per chunk without copies
        starts = [np.concatenate([[0], np.cumsum(np.bincount(eps, minlength=n_ep))]) for _, eps in kinds]
        sizes = np.array([recs.dtype.itemsize for recs, _ in kinds])
        ep_bytes = sum(np.diff(st_) * size for st_, size in zip(starts, sizes, strict=True))
        a = 0
        while a < n_ep:  # chunks of whole episodes, about chunk_size bytes each
            b = a + max(1, int(np.searchsorted(np.cumsum(ep_bytes[a:]), self._chunk_size, side="right")))
            b = min(b, n_ep)
            self._write_chunk(
                ch,
                group[a:b],
                base[a:b],
                last[a:b],
                fr[row0[a:b] + last[a:b], 0],
                kinds,
                blobs,
                [(int(st_[a]), int(st_[b])) for st_ in starts],
                sizes,
            )
            a = b
        self._clock_ns = int(base[-1] + last[-1] * dt + EPISODE_GAP_NS)

    def _write_chunk(
        self,
        ch: _Chunk,
        rows: np.ndarray,
        base: np.ndarray,
        last: np.ndarray,
        t_end: np.ndarray,
        kinds: list,
        blobs: list[memoryview],
        spans: list[tuple[int, int]],
        sizes: np.ndarray,
    ) -> None:
        """One MCAP chunk: the episodes' JSON heads, each kind's records for them (by topic, each in
        time order), the summaries; then one metadata record per episode."""
        info = ch.info
        self._json = []
        ends = base + last * self._dt_ns
        # The specs through one template: each field's JSON for all episodes from one dumps call.
        spec_t = '{"episode":%d,"step":0,"t":0.0,"scenario":{' + ",".join(f'"{name}":%s' for name in ch.scen) + "}}"
        cols = [_json_texts(arr[rows]) for arr in ch.scen.values()]
        for r, start, end, steps, texts in zip(
            rows.tolist(), base.tolist(), ends.tolist(), last.tolist(), zip(*cols, strict=True), strict=True
        ):
            ep = int(ch.index[r])
            self._add("/episode/spec", start, spec_t % (ep, *texts))
            self._add(
                "/episode/index",
                start,
                json.dumps(
                    {
                        "episode": ep,
                        "step": 0,
                        "start_ns": start,
                        "end_ns": end,
                        "steps": steps,
                        "outcome_name": OUTCOME_NAMES[int(info["outcome"][r])],
                    },
                    separators=(",", ":"),
                ),
            )
        heads = self._json
        self._json = []
        stats = {key: _json_rows(info[key][rows]) for key in SUMMARY_FIELDS}
        for j, (r, start, end, steps, t) in enumerate(
            zip(rows.tolist(), base.tolist(), ends.tolist(), last.tolist(), _json_rows(t_end), strict=True)
        ):
            summary = {key: col[j] for key, col in stats.items()}
            summary.update(
                episode=int(ch.index[r]),
                step=steps,
                t=t,
                outcome_name=OUTCOME_NAMES[int(info["outcome"][r])],
                start_ns=start,
                end_ns=end,
            )
            self._add("/episode/summary", end, json.dumps(summary, separators=(",", ":")))
        tails, self._json = self._json, []
        parts = [rec for _, _, rec in heads]
        chans, times, lens = [[c for c, _, _ in heads]], [[t_ for _, t_, _ in heads]], [[len(x) for *_, x in heads]]
        for (recs, _), blob, (lo, hi), size in zip(kinds, blobs, spans, sizes, strict=True):  # the per-step kinds
            if hi > lo:
                parts.append(blob[lo * size : hi * size])
                chans.append(np.full(hi - lo, recs["channel"][0]))
                times.append(recs["log_time"][lo:hi])
                lens.append(np.full(hi - lo, size))
        parts += [rec for _, _, rec in tails]
        chans.append([c for c, _, _ in tails])
        times.append([t_ for _, t_, _ in tails])
        lens.append([len(x) for *_, x in tails])
        cat = lambda xs: np.concatenate([np.asarray(x, np.int64) for x in xs])  # noqa: E731
        self._file.write_chunk(parts, cat(chans), cat(times), cat(lens))
        for r, start, end, steps in zip(rows.tolist(), base.tolist(), ends.tolist(), last.tolist(), strict=True):
            self._file.add_metadata(
                "episode",
                {
                    "episode": str(int(ch.index[r])),
                    "start_ns": str(start),
                    "end_ns": str(end),
                    "steps": str(steps),
                    "outcome": OUTCOME_NAMES[int(info["outcome"][r])],
                    "episode_return": json_number(float(info["episode_return"][r])),
                },
            )
        self._file.flush()  # the episodes are whole on disk (a killed writer keeps them)
        self.episodes += len(rows)

    def _add(self, topic: str, log_time: int, text: str) -> None:
        """A JSON message of this chunk, as a whole Message record."""
        data = text.encode()
        chan = self._channels[topic]
        self._json.append(
            (chan, log_time, struct.pack("<BQHIQQ", 0x05, 22 + len(data), chan, 0, log_time, log_time) + data)
        )


def _json_rows(arr: np.ndarray) -> list:
    """Rows of ``arr`` as JSON-ready lists (non-finite floats as None), converted in one call."""
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        return np.where(np.isfinite(arr), arr, None).tolist()
    return arr.tolist()


def _json_texts(arr: np.ndarray) -> list[str]:
    """Each row of ``arr`` (1-D: scalars, 2-D: flat lists) as compact JSON, from one ``json.dumps``
    of all rows split at the row boundaries (numbers, booleans and null hold no commas or brackets)."""
    text = json.dumps(_json_rows(arr), separators=(",", ":"))
    if arr.ndim == 1:
        return text[1:-1].split(",") if len(arr) else []
    if arr.shape[1] == 0:
        return ["[]"] * len(arr)
    return ["[" + x + "]" for x in text[2:-2].split("],[")]


def state_layout(channel: int, m: int, r: int) -> Layout:
    """/state (overtakezoo_msgs/msg/State, format.STATE_MSG) for M NPC slots and R rollouts."""
    lay = Layout(channel).slot("episode", "<u4").slot("step", "<u4")
    for name in ("t", "x", "y", "psi", "v", "a", "steer", "reward"):
        lay.slot(name, "<f8")
    lay.slot("mode", "u1").slot("rollout", "u1")
    for name in ("npc_s", "npc_v", "offsets"):
        lay.u4(m if name != "offsets" else r).slot(name, "<f8", m if name != "offsets" else r)
    return lay.u4(r).slot("blocked", "u1", r)


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


def recorder_for_run(
    path: str | os.PathLike, suite: Any, decider: Any, scene_every: int = 1, progress: bool = False
) -> ArchiveRecorder:
    """An :class:`ArchiveRecorder` for ``run_suite(suite, decider, recorder=...)``; the file's
    ``overtakezoo`` metadata names the suite (with its hash) and the decider."""
    return ArchiveRecorder(
        path,
        scene_every=scene_every,
        progress=progress,
        metadata={
            "suite": suite.name,
            "suite_version": suite.version,
            "suite_hash": suite.hash,
            "decider": decider.name,
            "decider_version": decider.version,
        },
    )


def _clean_tree(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _clean_tree(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean_tree(v) for v in obj]
    return json_ready(obj)
