"""``rule-fsm``: OpenPlanner's own behaviour selector (the paper's "OP only" baseline).

A faithful, batched re-implementation of the transitions OpenPlanner uses on a road without
lights, stop signs or intersections, read from hatem-darweesh/common (branch openplanner.1.15):

- ``op_planner/src/BehaviorStateMachine.cpp``: ``ForwardStateII::GetNextState`` (FORWARD ->
  FOLLOW when ``bFullyBlock``; FORWARD -> OBSTACLE_AVOIDANCE when swerving is enabled,
  ``distanceToNext <= minDistanceToAvoid``, not fully blocked and the best rollout differs from
  the current one), ``FollowStateII::GetNextState`` (FOLLOW -> OBSTACLE_AVOIDANCE under the same
  condition; FOLLOW -> FORWARD after the block is released) and ``SwerveStateII::GetNextState``
  (one tick: commit the new rollout, back to FORWARD);
- ``op_planner/src/DecisionMaker.cpp``: ``bFullyBlock`` is the best trajectory's blocked flag
  (every rollout blocked), and a new safe rollout is trusted only after ``nReliableCount``
  consistent ticks (``/op_behavior_selector/evidence_trust_number``, 3 in the launch files of
  hatem-darweesh/core_planning ``op_local_planner``);
- ``op_planner/src/TrajectoryEvaluator.cpp``: the blocked flags themselves, which the shared
  planner computes and the observation carries.

Mapping onto the shared planner's modes (``envs/model/planner.py``): FORWARD and FOLLOW are both our
FOLLOW mode (the centre rollout; the speed planner follows the lead or drives at the cap when
nothing is near); OBSTACLE_AVOIDANCE + the FORWARD that follows it with swerving enabled is our
OVERTAKE mode (the evaluator picks the cheapest unblocked rollout). OpenPlanner has no abort
state, so this decider never emits ABORT: when every rollout gets blocked mid-pass it falls back to
FOLLOW (FORWARD -> FOLLOW), which steers to the centre rollout. It looks no further than the
planner's horizon: it acts on the blocked flags only, plus the lead gap for ``distanceToNext``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from overtakezoo.envs import FOLLOW, OVERTAKE, EnvConfig, ScenarioDistribution, observation_layout
from overtakezoo.envs.model.observation import SLOT_FEATURES
from overtakezoo.zoo.base import Decider, register

EVIDENCE_TRUST_NUMBER = 3  # OpenPlanner launch default (op_behavior_selector/evidence_trust_number)


def lead_from_obs(
    obs: np.ndarray, cfg: EnvConfig, layout: dict[str, Any] | None = None, dist: ScenarioDistribution | None = None
) -> dict[str, np.ndarray]:
    """The nearest perceived ego-lane vehicle ahead of the ego (OpenPlanner's ``distanceToNext``):
    bumper gap (inf if none), relative speed (m/s, ego frame) and slot index (-1 if none).
    ``layout`` and ``dist``: ``cfg``'s, built once by a decider (validating the distribution at every
    decision cost as much as the decision)."""
    lay = layout if layout is not None else observation_layout(cfg)
    dist = dist if dist is not None else ScenarioDistribution.from_dict(cfg.scenario)
    oc = cfg.observation
    slots = obs[:, lay["ego_lane"]].reshape(len(obs), -1, SLOT_FEATURES).astype(float)
    x = slots[:, :, 1] * oc.position_scale
    ahead = (slots[:, :, 0] > 0.5) & (x > 0.0)
    centre = np.where(ahead, x, np.inf)
    idx = np.argmin(centre, axis=1)
    rows = np.arange(len(obs))
    dx = centre[rows, idx]
    gap = dx - (dist.ego_length + dist.vehicle_length) / 2
    rel_v = np.where(np.isfinite(dx), slots[rows, idx, 3] * oc.speed_scale, 0.0)
    return {"gap": gap, "rel_v": rel_v, "slot": np.where(np.isfinite(dx), idx, -1)}


class RuleFSM(Decider):
    """OpenPlanner's behaviour state machine (ForwardStateII / FollowStateII / SwerveStateII): follow,
    swerve into the opposite lane once the lead is within minDistanceToAvoid and a rollout is free
    for 3 ticks, fall back to follow when every rollout is blocked; no look-ahead past the planner's
    horizon and no abort (the paper's "OP only" baseline)."""

    name = "rule-fsm"
    version = "1"
    row_state = ("mode", "count")

    def __init__(self, config: EnvConfig | None = None, evidence: int = EVIDENCE_TRUST_NUMBER) -> None:
        super().__init__(config)
        self.evidence = int(evidence)
        self.layout = observation_layout(self.config)
        self.dist = ScenarioDistribution.from_dict(self.config.scenario)
        self.avoid = self.config.planner.modes["overtake"].avoiding_distance  # minDistanceToAvoid
        self.mode = np.zeros(0, np.int64)
        self.count = np.zeros(0, np.int64)

    def _ensure(self, n: int) -> None:
        if self.mode.shape[0] != n:
            self.mode = np.full(n, FOLLOW, np.int64)
            self.count = np.zeros(n, np.int64)

    def reset(self, mask: np.ndarray | None = None) -> None:
        if mask is None:
            self.mode = np.zeros(0, np.int64)
            self.count = np.zeros(0, np.int64)
            return
        mask = np.asarray(mask, bool)
        self._ensure(mask.shape[0])
        self.mode[mask] = FOLLOW
        self.count[mask] = 0

    def act_batch(self, obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs)
        self._ensure(obs.shape[0])
        blocked = obs[:, self.layout["blocked"]] > 0.5  # (N, n + 1); 0 = ego-lane centre
        fully_blocked = blocked.all(axis=1)  # bFullyBlock: even the best rollout is blocked
        side_free = ~blocked[:, 1:].all(axis=1)  # some rollout towards the opposite lane is free
        gap = lead_from_obs(obs, self.config, self.layout, self.dist)["gap"]
        lead_near = gap <= self.avoid  # distanceToNext <= minDistanceToAvoid
        lateral = obs[:, self.layout["ego"]][:, 2]  # y / lane width

        following = self.mode == FOLLOW
        # FOLLOW/FORWARD -> OBSTACLE_AVOIDANCE: the lead blocks the centre, a side rollout is free;
        # the new rollout is trusted only after `evidence` consistent ticks (nReliableCount).
        want = following & lead_near & blocked[:, 0] & side_free
        self.count = np.where(want, self.count + 1, 0)
        start = want & (self.count >= self.evidence)
        # FORWARD -> FOLLOW on bFullyBlock (immediate in ForwardStateII); a finished swerve (back on
        # the centre lane with nothing to avoid) is plain FORWARD again, i.e. our FOLLOW mode.
        done_pass = ~following & (np.abs(lateral) < 0.25) & ~(lead_near & blocked[:, 0])
        stop = ~following & (fully_blocked | done_pass)
        self.mode = np.where(start, OVERTAKE, np.where(stop, FOLLOW, self.mode))
        self.count = np.where(start | stop, 0, self.count)
        return self.mode.copy()

    def card(self) -> str:
        return (
            "rule-fsm v1: OpenPlanner's behaviour selector (BehaviorStateMachine.cpp ForwardStateII/"
            "FollowStateII/SwerveStateII, evidence_trust_number = 3) acting on the shared planner's "
            "blocked flags and the lead gap; swerves when the lead is within minDistanceToAvoid "
            f"({self.avoid:g} m) and a side rollout is free, falls back to follow when every rollout "
            "is blocked; no abort, no look-ahead past the planner's horizon. The paper's OP-only baseline."
        )


register("rule-fsm", lambda config=None, **kw: RuleFSM(config, **kw))
