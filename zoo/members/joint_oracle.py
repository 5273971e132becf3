"""``joint-oracle``: a privileged, centralised upper bound for roads with several automated vehicles.

The single-ego ``oracle`` plans one AV assuming nobody else decides; beside other AVs it would have
to predict their deciders. The joint oracle drives every AV of a road itself and plans their modes
together. Every ``replan_s`` seconds (its ``action_repeat``), for each road with an open decision,
it clones the road from the live core (``OvertakeCore.clone``: every state array, the NPCs' hidden
state included) once per *joint plan*, a choice for each AV between

- *overtake*: OVERTAKE now and hold it to the end of the episode, and
- *retreat*: drop back (ABORT while in the opposite lane, FOLLOW once back),

2^E plans for E AVs, and simulates all of them for all roads in one batch (no loop over roads or
plans). A simulated road ends when every overtaking AV of it is done and ``retreat_horizon_s`` has
passed (its retreating AVs survived that long). The road takes the plan that scores best: AVs that
succeed minus 2 x AVs that crash (the leaderboard's weights), then the later first crash, then fewer
overtakes. A plan in which every AV still driving overtakes and succeeds is exact (the simulator on
a copy of the real state, held constant) and is not re-checked. Its rows on the multi-agent boards
say how many roads are solvable by joint follow-then-overtake decisions at 1 s resolution. Never train
on it.
"""

from __future__ import annotations

import numpy as np

from overtakezoo.envs import ABORT, FOLLOW, OVERTAKE
from overtakezoo.envs.core import CRASH, RUNNING, SUCCESS
from overtakezoo.zoo.base import register
from overtakezoo.zoo.members.oracle import LookAhead

CRASH_WEIGHT = 2.0  # the leaderboard's K: a crash counts twice a success


def joint_plans(num_avs: int) -> np.ndarray:
    """(2^E, E) bool: every joint plan, True where that AV overtakes."""
    plan = np.arange(2**num_avs)[:, None]
    return ((plan >> np.arange(num_avs)[None, :]) & 1).astype(bool)


class JointOracle(LookAhead):
    """Privileged joint look-ahead: plans every AV of a road together by simulating each joint plan
    of overtake / retreat on clones of the live road (an upper bound; never train on it)."""

    name = "joint-oracle"
    version = "1"
    joint = True  # plans every AV of a road: the runner lets it drive multi-AV suites

    def _size(self, rows: int) -> None:
        num_avs = 1 if self.core is None else self.core.num_avs
        self.decision = np.full(rows, FOLLOW, np.int64)
        self.verified = np.zeros(rows // num_avs, bool)  # per road

    def reset(self, mask: np.ndarray | None = None) -> None:
        core = self.core
        if mask is None or core is None or self.decision.shape[0] != len(mask):
            self._size(self.decision.shape[0] if mask is None else len(mask))
            return
        mask = np.asarray(mask, bool)
        self.decision[mask] = FOLLOW
        self.verified[mask.reshape(core.num_avs, -1).any(axis=0)] = False

    def act_batch(self, obs: np.ndarray) -> np.ndarray:
        core = self._bound(obs)
        open_road = ~core.done.reshape(core.num_avs, -1).all(axis=0) & ~(self.verified & self.trust_verified)
        roads = np.flatnonzero(open_road)
        if roads.size:
            self._replan(roads)
        return self.decision.copy()

    def plan(self, rows: np.ndarray) -> np.ndarray:
        """Re-plan the roads of AV rows ``rows`` of the bound core now (whatever was verified) and
        return those rows' decisions: the joint oracle as a labeller of states another decider drove
        to (``train dagger`` on multi-AV suites). Rows are AV-major: row ``e * num_roads + road``."""
        rows = np.asarray(rows, np.int64)
        roads = np.unique(rows % self.core.num_roads)
        live = ~self.core.done.reshape(self.core.num_avs, -1).all(axis=0)
        if roads.size and live[roads].any():
            self._replan(roads[live[roads]])
        return self.decision[rows].copy()

    def _replan(self, roads: np.ndarray) -> None:
        core, e = self.core, self.core.num_avs
        plans = joint_plans(e)  # (P, E)
        p = plans.shape[0]
        overtakes = np.tile(plans, (roads.size, 1)).T  # (E, R * P): road r's plans side by side
        outcome, t = self._simulate(core.clone(np.repeat(roads, p)), overtakes)
        crashed = outcome == CRASH
        score = (outcome == SUCCESS).sum(axis=0) - CRASH_WEIGHT * crashed.sum(axis=0)
        first_crash = np.where(crashed, t, np.inf).min(axis=0)
        live = ~core.done.reshape(e, -1)[:, roads]  # (E, R): the AVs still driving
        n_over = (overtakes.reshape(e, roads.size, p) & live[:, :, None]).sum(axis=0)
        # Best plan per road: score, then the later first crash, then fewer overtakes (lexicographic).
        order = np.lexsort((n_over, -first_crash.reshape(-1, p), -score.reshape(-1, p)), axis=1)
        best = order[:, 0]  # (R,)
        chosen = plans[best]  # (R, E)
        cols = np.arange(e)[:, None] * core.num_roads + roads[None, :]  # (E, R) live rows
        y, lw = core.y[cols], core.scen.lane_width[roads][None, :]
        self.decision[cols] = np.where(chosen.T, OVERTAKE, np.where(y > 0.25 * lw, ABORT, FOLLOW))
        out = outcome.reshape(e, roads.size, p)[:, np.arange(roads.size), best]  # (E, R)
        everyone = (chosen.T | ~live).all(axis=0) & ((out == SUCCESS) | ~live).all(axis=0)
        self.verified[roads] = everyone & (out != RUNNING).all(axis=0)

    def _simulate(self, sim, overtakes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Run each simulated road under its plan (``overtakes``: (E, n) bool) to its end; returns
        the (E, n) outcomes and clocks. Roads that ended are dropped from the batch once they are a
        quarter of it (a clone of the rest), so the long plans do not carry the finished ones: the
        look-ahead's cost follows the roads still running."""
        e, n = overtakes.shape
        outcome, t = np.empty((e, n), sim.outcome.dtype), np.empty((e, n))
        where = np.arange(n)  # the batch's roads -> their plan columns
        steps = 0
        while where.size:
            lane_w = sim.scen.lane_width[None, :]
            aborting = ~overtakes & (sim.y.reshape(e, -1) > 0.25 * lane_w)
            modes = np.where(overtakes, OVERTAKE, np.where(aborting, ABORT, FOLLOW))
            sim.advance(modes.reshape(-1))  # (outcomes only: no observation)
            steps += 1
            self.sim_steps += where.size
            if steps >= self.retreat_steps:  # end a road once its overtaking AVs are done
                settled = (sim.done.reshape(e, -1) | ~overtakes).all(axis=0)
                sim.done |= np.tile(settled, e)
            ended = sim.done.reshape(e, -1).all(axis=0)
            if 4 * ended.sum() >= where.size:
                outcome[:, where[ended]] = sim.outcome.reshape(e, -1)[:, ended]
                t[:, where[ended]] = sim.t.reshape(e, -1)[:, ended]
                keep = np.flatnonzero(~ended)
                where, overtakes = where[keep], overtakes[:, keep]
                if keep.size:
                    sim = sim.clone(keep)
        return outcome, t

    def card(self) -> str:
        return (
            "joint-oracle v1 (privileged, multi-AV): every 1 s clones each road once per joint plan "
            "(each AV overtakes now and holds it, or drops back and follows) and simulates all plans of all "
            "roads in one batch; the road takes the plan with the most successes minus 2 x crashes. An upper "
            "bound on joint follow-then-overtake decisions at 1 s resolution; never train on it."
        )


register("joint-oracle", lambda config=None, **kw: JointOracle(config, **kw))
