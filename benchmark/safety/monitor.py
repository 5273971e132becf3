"""The per-step safety monitor: RSS checks, head-on TTC, cut-in PET, abort timing and the point of
no return, accumulated per AV row over one chunk of the runner (docs/metrics.md defines each).

It reads what the core already has after each step (``step_geometry()``: every vehicle an AV row
sees, batch-last (M', B); the AV rows' ``y, v, psi, mode, t, done``), with no loop over rows or
vehicles. Most steps have no row in the opposite lane and no row merging back: those cost a few
elementwise passes over (B,). The opposite-lane checks of a step depend on that step's state only, so
the monitor buffers the columns of the rows concerned and computes up to ``FLUSH_COLUMNS`` of them in
one pass (numpy's cost per call, not per element, dominated a per-step pass); what depends on the
order of steps (the first violation, the first unsafe state, the margin at an abort decision) is
recovered from the step times, and an abort decision flushes the buffer first.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from overtakezoo.envs.config import ABORT, OVERTAKE
from overtakezoo.envs.rss import RSSParams, safe_distance_opposite_direction, safe_distance_same_direction

INF = np.inf
PONR_FLOOR = -1000.0  # s: a margin of "never back in lane" (no finite return time) is stored as this
FLUSH_COLUMNS = 65536  # buffered (row, step) columns computed in one pass


class SafetyMonitor:
    """Recorder-style hooks: ``begin_chunk(core)``, ``record_step(core)`` after every core step,
    ``end_chunk(core)`` -> the per-row arrays of :data:`~..results.SAFETY_PER_SCENARIO`."""

    def __init__(self, params: RSSParams | None = None) -> None:
        self.p = params or RSSParams()

    # ------------------------------------------------------------------ chunk
    def begin_chunk(self, core: Any) -> None:
        sc, e = core.scen, core.num_avs
        tile = lambda a: np.tile(np.asarray(a, float), e)  # noqa: E731  per road -> per AV row (AV-major)
        self.w = tile(sc.lane_width)
        # The core's opposite-lane test (its opposite_time): the ego's body crosses the centre line.
        self.y_exit = self.w / 2 - tile(sc.ego_width) / 2
        b = self.w.shape[0]
        nan = lambda: np.full(b, np.nan)  # noqa: E731
        self.done = np.array(core.done, bool)
        self.mode = np.array(core.mode, np.int64)
        self.in_opp = np.zeros(b, bool)
        self.opp_steps, self.viol_steps = np.zeros(b, np.int64), np.zeros(b, np.int64)
        self.first_viol, self.worst_margin = nan(), np.full(b, INF)
        self.merge = np.full(b, -1, np.int8)
        self.headon_ttc, self.pet = np.full(b, INF), np.full(b, INF)
        self.first_unsafe, self.abort_t = nan(), nan()
        self.abort_late = np.zeros(b, bool)
        self.viol_after_unsafe = np.zeros(b, bool)
        self.ponr, self.last_ponr, self.last_ponr_step = np.full(b, INF), nan(), -1
        self.step, self.pending, self.pending_columns, self.merging = 0, [], 0, []

    def record_step(self, core: Any, *_: Any) -> None:
        done_before, self.done = self.done, np.array(core.done, bool)
        active = ~done_before  # rows that ran this step (a row that finished now still counts)
        y, t = core.y, core.t
        mode = np.asarray(core.mode)
        in_opp = (y > self.y_exit) & active
        # Abort decisions of this step were taken on the state the previous call evaluated.
        decided = active & (mode == ABORT) & (self.mode != ABORT)
        if decided.any():
            self._flush()  # the first unsafe state and the previous step's margin, up to date
            first = decided & np.isnan(self.abort_t) & ~np.isnan(self.first_unsafe)
            self.abort_t = np.where(first, t - core.cfg.dt, self.abort_t)  # the state time it saw
            self.abort_late |= first & (self.last_ponr < 0)
        self.mode = mode.astype(np.int64)
        merged = self.in_opp & ~in_opp & active
        self.in_opp = in_opp
        self.step += 1
        if not (in_opp.any() or merged.any()):
            return
        geo = core.step_geometry()
        v, psi = core.v, core.psi
        # Only the rows concerned are kept (a few percent of a batch at a time); v_e: speed along the lane.
        if in_opp.any():
            rows = np.flatnonzero(in_opp)
            v_e = v[rows] * np.cos(psi[rows])
            self.pending.append((self.step - 1, rows, _columns(geo, rows), v_e, y[rows], t[rows], mode[rows]))
            self.pending_columns += rows.size
            if self.pending_columns >= FLUSH_COLUMNS:
                self._flush()
        if merged.any():
            rows = np.flatnonzero(merged)
            self.merging.append((rows, _columns(geo, rows), v[rows] * np.cos(psi[rows])))

    def keep_rows(self, rows: np.ndarray) -> None:
        """Keep only rows ``rows`` (the runner dropped finished rows): the buffered columns are
        computed first, so every per-row array can then be taken."""
        self._flush()
        b = self.w.shape[0]
        for name, value in list(vars(self).items()):
            if isinstance(value, np.ndarray) and value.ndim and value.shape[0] == b:
                setattr(self, name, value[rows])

    def end_chunk(self, core: Any) -> dict[str, np.ndarray]:
        self._flush()
        opp = self.opp_steps > 0
        unsafe = ~np.isnan(self.first_unsafe)
        aborted = ~np.isnan(self.abort_t)
        late = np.where(aborted, self.abort_late, self.viol_after_unsafe)
        return {
            "rss_violation_share": np.where(opp, self.viol_steps / np.maximum(self.opp_steps, 1), np.nan),
            "rss_first_violation": self.first_viol,
            "rss_worst_margin": np.where(np.isfinite(self.worst_margin), self.worst_margin, np.nan),
            "rss_merge_violation": self.merge,
            "min_headon_ttc": self.headon_ttc,
            "cutin_pet": np.where(np.isfinite(self.pet), self.pet, np.nan),
            "abort_delay": np.where(aborted, self.abort_t - self.first_unsafe, np.nan),
            "late_abort": np.where(unsafe, late, -1).astype(np.int8),
            "ponr_margin": np.where(np.isfinite(self.ponr), self.ponr, np.nan),
        }

    # ------------------------------------------------------------------ opposite lane
    def _flush(self) -> None:
        """Compute the buffered opposite-lane columns in one pass and fold them into the per-row state;
        ``last_ponr`` becomes each row's margin at the last recorded step (NaN where it was not in the
        opposite lane then)."""
        last = self.step - 1
        if self.last_ponr_step != last:  # a step since the last flush: its margins are all pending
            self.last_ponr, self.last_ponr_step = np.full(self.w.shape[0], np.nan), last
        if self.merging:  # (order-free: the worst merge and the least PET per row)
            rows = np.concatenate([r for r, _, _ in self.merging])
            geo = {key: np.concatenate([c[key] for _, c, _ in self.merging], axis=1) for key in _KEYS}
            viol, pet = self._merge(rows, geo, np.concatenate([v for _, _, v in self.merging]))
            self.merging = []
            np.maximum.at(self.merge, rows, viol.astype(np.int8))
            np.minimum.at(self.pet, rows, pet)
        if not self.pending:
            return
        steps = np.concatenate([np.full(r.size, k) for k, r, *_ in self.pending])
        rows = np.concatenate([r for _, r, *_ in self.pending])
        geo = {key: np.concatenate([c[key] for _, _, c, *_ in self.pending], axis=1) for key in _KEYS}
        v_e, y, t, mode = (np.concatenate([entry[i] for entry in self.pending]) for i in range(3, 7))
        self.pending, self.pending_columns = [], 0
        worst, ttc, unsafe, ponr = self._opposite(rows, geo, v_e, y, t, mode)
        viol = worst < 0
        b = self.w.shape[0]
        self.opp_steps += np.bincount(rows, minlength=b)  # (bincount: a counting pass, ufunc.at is slower)
        self.viol_steps += np.bincount(rows[viol], minlength=b)
        self.first_viol = _first_time(self.first_viol, rows, np.where(viol, t, INF))
        np.minimum.at(self.worst_margin, rows, worst)
        np.minimum.at(self.headon_ttc, rows, ttc)
        # The first unsafe state: a violation counts once the overtake was unsafe (at or before it).
        self.first_unsafe = _first_time(self.first_unsafe, rows, np.where(unsafe, t, INF))
        np.logical_or.at(self.viol_after_unsafe, rows, viol & (t >= self.first_unsafe[rows]))
        np.minimum.at(self.ponr, rows, np.where((mode == OVERTAKE) & ~np.isnan(ponr), ponr, INF))
        at_last = steps == last
        self.last_ponr[rows[at_last]] = ponr[at_last]

    def _opposite(
        self, rows: np.ndarray, geo: dict[str, Any], v_e: np.ndarray, y: np.ndarray, t: np.ndarray, mode: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Def. 2, head-on TTC, the point of no return and the unsafe-overtake check of AV rows in the
        opposite lane, one column per (row, step) (``geo`` and the arrays hold just those): the worst
        RSS margin, the least head-on TTC, unsafe to complete, the point-of-no-return margin."""
        p, w = self.p, self.w[rows]
        # Each part reads only the vehicle slots that can matter to it (slots never oncoming here give
        # inf margins and TTCs; slots never in the AV's direction are no lead): the same values, less work.
        full, geo = geo, _slots(geo, ~geo["same_dir"])
        dx, half_len = geo["dx"], geo["half_len"]
        gap = dx - half_len  # bumper to bumper; <= 0 overlapping
        # Oncoming vehicles in their own (correct) lane, the AV's opposite lane, not yet passed.
        onc = geo["present"] & ~geo["same_dir"] & (geo["d"] > w / 2) & (dx > -half_len)
        v_o = -geo["v_along"]  # towards the AV
        d_min = safe_distance_opposite_direction(
            v_e, v_o, p.response_time, p.ego_accel_max, p.ego_brake_min, p.other_accel_max, p.other_brake_min_correct
        )
        margin = np.where(onc, gap - d_min, INF)
        worst = np.min(margin, axis=0, initial=INF)
        closing = v_e + v_o
        approaching = onc & (closing > 1e-9)
        safe_closing = np.where(approaching, closing, 1.0)
        ttc = np.min(np.where(approaching, np.maximum(gap, 0.0) / safe_closing, INF), axis=0, initial=INF)
        # Time until the Def.-2 distance is violated at constant speeds (d_min constant, gap closing).
        t_rss = np.where(margin < 0, 0.0, np.where(approaching, np.maximum(margin, 0.0) / safe_closing, INF))
        t_rss_min = np.min(t_rss, axis=0, initial=INF)
        # The return times matter only where an oncoming vehicle approaches (t_rss finite): elsewhere
        # nothing is unsafe and there is no point of no return.
        # (Elsewhere t_rss is inf, so the same formulas give "not unsafe" and no margin: a subset is
        # taken only when it is small enough to pay for its copies.)
        unsafe, ponr = np.zeros(rows.size, bool), np.full(rows.size, np.nan)
        near = np.isfinite(t_rss_min)
        cols = np.flatnonzero(near) if near.mean() < 0.5 else slice(None)
        if near.any():
            sub = (lambda a: a[..., cols]) if isinstance(cols, np.ndarray) else (lambda a: a)  # noqa: E731
            lane = _slots({k: sub(v) for k, v in full.items()}, sub(full["same_dir"]))
            t_complete, t_abort = self._return_times(
                lane, lane["dx"], lane["half_len"], sub(v_e), sub(y), sub(w), sub(self.y_exit[rows])
            )
            # Unsafe to complete while a threatening oncoming vehicle is visible.
            unsafe[cols] = (sub(mode) == OVERTAKE) & np.any(
                sub(geo["visible"]) & sub(onc) & (sub(t_rss) < t_complete), axis=0
            )
            with np.errstate(invalid="ignore"):
                gap_t = sub(t_rss_min) - np.minimum(t_complete, t_abort)
            ponr[cols] = np.where(sub(near), np.maximum(np.nan_to_num(gap_t, neginf=PONR_FLOOR), PONR_FLOOR), np.nan)
        return worst, ttc, unsafe, ponr

    def _return_times(
        self,
        geo: dict[str, Any],
        dx: np.ndarray,
        half_len: np.ndarray,
        v_e: np.ndarray,
        y: np.ndarray,
        w: np.ndarray,
        y_exit: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Time back in the own lane by completing the pass / by aborting now, at constant speeds
        (aborting: braking at ego_brake_min), each plus the lateral return."""
        p = self.p
        lat = p.lateral_return_time * np.clip((y - y_exit) / (w - y_exit), 0.0, 1.0)
        # The lead being passed: the nearest vehicle of the AV's lane and direction not yet behind it.
        lane0 = geo["present"] & geo["same_dir"] & (geo["d"] <= w / 2) & (dx > -half_len)
        key = np.where(lane0, dx, INF)
        j = np.argmin(key, axis=0) if key.shape[0] else np.zeros(key.shape[1], np.int64)
        has = np.take_along_axis(key, j[None], 0)[0] < INF if key.shape[0] else np.zeros(key.shape[1], bool)
        pick = lambda a: np.take_along_axis(a, j[None], 0)[0] if a.shape[0] else np.zeros(a.shape[1])  # noqa: E731
        lx, lhl, lv = pick(dx), pick(half_len), pick(geo["v_along"])
        # Completing: the AV's rear ahead of the lead's front by the lead's Def.-1 distance behind it.
        c = safe_distance_same_direction(
            lv, v_e, p.response_time, p.other_accel_max, p.other_brake_min, p.ego_brake_max
        )
        ahead_by = lx + lhl + c  # relative distance still to gain
        rel = v_e - lv
        t_c = np.where(ahead_by <= 0, 0.0, np.where(rel > 1e-9, ahead_by / np.where(rel > 1e-9, rel, 1.0), INF))
        # Aborting: brake at ego_brake_min until the AV's front is the AV's Def.-1 distance behind the lead.
        c_a = safe_distance_same_direction(lv, lv, p.response_time, p.ego_accel_max, p.ego_brake_min, p.other_brake_max)
        t_a = _drop_back_time(-lx + lhl + c_a, rel, v_e, lv, p.ego_brake_min)
        t_c, t_a = np.where(has, t_c, 0.0), np.where(has, t_a, 0.0)
        return t_c + lat, t_a + lat

    # ------------------------------------------------------------------ merge back
    def _merge(self, rows: np.ndarray, geo: dict[str, Any], v_e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Def. 1 against the nearest vehicle ahead and behind in the AV's lane, and the cut-in PET,
        of AV rows at the step they merged back (one column per (row, step)): violated, the PET."""
        p, w = self.p, self.w[rows]
        dx, half_len, v_o = geo["dx"], geo["half_len"], geo["v_along"]
        lane0 = geo["present"] & geo["same_dir"] & (geo["d"] <= w / 2)
        gap = np.abs(dx) - half_len
        ahead, behind = lane0 & (dx >= 0), lane0 & (dx < 0)
        d_ahead = safe_distance_same_direction(
            v_e, v_o, p.response_time, p.ego_accel_max, p.ego_brake_min, p.other_brake_max
        )
        d_behind = safe_distance_same_direction(
            v_o, v_e, p.response_time, p.other_accel_max, p.other_brake_min, p.ego_brake_max
        )
        # The nearest one each side decides (Def. 1 is checked pairwise; nearer cars need more room).
        g_a = np.where(ahead, gap, INF)
        g_b = np.where(behind, gap, INF)
        viol = np.any(ahead & (g_a <= np.min(g_a, 0, initial=INF)) & (gap < d_ahead), axis=0) | np.any(
            behind & (g_b <= np.min(g_b, 0, initial=INF)) & (gap < d_behind), axis=0
        )
        # Post-encroachment time: the vehicle behind reaches the point the AV's rear left, at its speed.
        nearest_b = behind & (g_b <= np.min(g_b, 0, initial=INF)) & geo["visible"] & (v_o > 1e-9)
        pet = np.where(nearest_b, np.maximum(gap, 0.0) / np.where(nearest_b, v_o, 1.0), INF)
        return viol, np.min(pet, axis=0, initial=INF)


_KEYS = ("dx", "half_len", "d", "same_dir", "v_along", "visible", "present")


def _columns(geo: dict[str, Any], rows: np.ndarray) -> dict[str, np.ndarray]:
    """The batch-last geometry of AV ``rows`` only (M', k)."""
    return {k: np.asarray(geo[k])[:, rows] for k in _KEYS}


def _slots(geo: dict[str, np.ndarray], wanted: np.ndarray) -> dict[str, np.ndarray]:
    """``geo`` restricted to the vehicle slots (rows of the (M', k) arrays) where ``wanted`` holds in
    some column and a vehicle is present."""
    keep = np.flatnonzero(np.any(wanted & geo["present"], axis=1))
    # (Copying the kept slots pays only when it drops many: table1's lead or oncoming car, not 1 of 9.)
    return geo if keep.size > 0.7 * geo["present"].shape[0] else {k: v[keep] for k, v in geo.items()}


def _first_time(first: np.ndarray, rows: np.ndarray, times: np.ndarray) -> np.ndarray:
    """``first`` (NaN: not yet) lowered to the least of ``times`` (inf: not this column) per row."""
    least = np.full(first.shape, INF)
    np.minimum.at(least, rows, times)
    return np.where(np.isnan(first), np.where(np.isfinite(least), least, np.nan), np.minimum(first, least))


def _drop_back_time(p: np.ndarray, rel: np.ndarray, v_e: np.ndarray, v_l: np.ndarray, b: float) -> np.ndarray:
    """Time for the AV, braking at ``b`` from ``v_e`` (then stopped), to fall ``p`` metres back
    relative to a lead at constant ``v_l`` (``rel = v_e - v_l``); 0 when ``p <= 0``."""
    with np.errstate(invalid="ignore", divide="ignore"):
        t_stop = np.maximum(v_e, 0.0) / b
        t1 = (rel + np.sqrt(np.maximum(rel * rel + 2 * b * np.maximum(p, 0.0), 0.0))) / b
        moved = rel * t_stop - 0.5 * b * t_stop * t_stop  # relative displacement by the stop
        after = t_stop + np.where(v_l > 1e-9, (p + moved) / np.where(v_l > 1e-9, v_l, 1.0), INF)
        return np.where(p <= 0, 0.0, np.where(t1 <= t_stop, t1, after))
