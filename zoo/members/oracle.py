"""``oracle``: a privileged upper bound that searches the future by simulating it.

Every ``replan_s`` seconds (its ``action_repeat``: the runner holds each decision that long), for
the rows where a decision is still open, the oracle clones those rows of the live core
(``OvertakeCore.clone``: every state array, the NPCs' hidden state included) and simulates candidate
policies forward in one batch (all rows x all candidates, no loop over scenarios):

- ``overtake``: OVERTAKE now and hold it to the end of the episode;
- ``retreat``: drop back (ABORT while in the opposite lane, FOLLOW once back), checked for
  ``retreat_horizon_s`` seconds only (following is safe; the next re-plan looks again).

Decision: overtake when the simulated overtake ends in success; otherwise retreat / follow (an
aborting row keeps aborting). The simulation is the real simulator on a copy of the real state,
so a verified overtake is replayed exactly and is not re-checked (``trust_verified``). Rows never
interact, so the copy's future equals the live row's future under the same modes. The oracle
reads everything (future NPC behaviour included): its leaderboard row tells how many scenarios
are solvable by a follow-then-overtake decision at 1 s resolution. Never train on it.
"""

from __future__ import annotations

import numpy as np

from overtakezoo.envs import ABORT, FOLLOW, OVERTAKE, EnvConfig, observation_size
from overtakezoo.envs.core import CRASH, SUCCESS
from overtakezoo.zoo.base import Decider, ObservationError, register

CAND_OVERTAKE, CAND_RETREAT = 0, 1


def simulate(core, rows: np.ndarray, cand: np.ndarray, retreat_steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Simulate candidate ``cand[i]`` from the live state of ``rows[i]`` (one batch); returns the
    outcome of each copy (RUNNING for a retreat that survived its horizon) and the time it ended."""
    sim = core.clone(rows)
    lane_w = sim.scen.lane_width
    retreat = cand == CAND_RETREAT
    steps = 0
    while not sim.done.all():
        aborting = retreat & (sim.y > 0.25 * lane_w)
        modes = np.where(cand == CAND_OVERTAKE, OVERTAKE, np.where(aborting, ABORT, FOLLOW))
        sim.advance(modes)  # (outcomes only: no observation)
        steps += 1
        if steps >= retreat_steps:
            sim.done |= retreat  # a retreat survived its horizon: freeze it, no crash
    return sim.outcome.copy(), sim.t.copy()


class LookAhead(Decider):
    """What the privileged look-ahead members share (``oracle``, ``joint-oracle``): they re-plan every
    ``replan_s`` seconds on clones of the core they are bound to, check a retreat for
    ``retreat_horizon_s`` seconds, and skip rows (roads) whose plan a simulation already verified
    while ``trust_verified``. Subclasses size their state in ``_size`` and plan in ``act_batch``."""

    privileged = True
    decision: np.ndarray  # (rows,) the mode each row holds until its next re-plan
    verified: np.ndarray  # what a simulation showed succeeds (rows, or roads for the joint oracle)

    def __init__(
        self,
        config: EnvConfig | None = None,
        replan_s: float = 1.0,
        retreat_horizon_s: float = 8.0,
        trust_verified: bool = True,
    ) -> None:
        super().__init__(config)
        self.action_repeat = max(1, int(round(replan_s / self.config.dt)))  # core steps between re-plans
        self.retreat_steps = max(1, int(round(retreat_horizon_s / self.config.dt)))
        self.trust_verified = trust_verified  # off: re-plan even what a simulation verified
        self.core = None
        self.sim_steps = 0  # simulated copies x steps (cost accounting)
        self._size(0)

    def _size(self, rows: int) -> None:
        raise NotImplementedError

    def bind(self, core) -> None:
        # A look-ahead reads the core, not the observation, yet takes the same input as every member:
        # a core whose observations its act would refuse (another width) is refused here.
        if core.obs_size != observation_size(self.config):
            raise ObservationError(
                f"{self.name}: the bound core's observations have {core.obs_size} features, "
                f"expected {observation_size(self.config)} (observation_size of the {self.name}'s config)"
            )
        self.core = core
        self._size(core.num)

    def _bound(self, obs: np.ndarray):
        """The bound core, checked against the observation ``act_batch`` was given."""
        core = self.core
        if core is None:
            raise RuntimeError(f"the {self.name} is privileged: call bind(core) after core.reset")
        if obs.shape[0] != core.num:
            raise ValueError(f"observation has {obs.shape[0]} rows but the bound core has {core.num}")
        if self.decision.shape[0] != core.num:
            self._size(core.num)
        return core


class Oracle(LookAhead):
    """Privileged look-ahead oracle: overtakes when a simulation of the real future shows that
    overtaking now ends in success, follows otherwise (an upper bound; never train on it)."""

    name = "oracle"
    version = "1"
    row_state = ("decision", "verified")

    def _size(self, n: int) -> None:
        self.decision = np.full(n, FOLLOW, np.int64)
        self.verified = np.zeros(n, bool)

    def reset(self, mask: np.ndarray | None = None) -> None:
        if mask is None or self.decision.shape[0] != len(mask):
            self._size(self.decision.shape[0] if mask is None else len(mask))
            return
        mask = np.asarray(mask, bool)
        self.decision[mask] = FOLLOW
        self.verified[mask] = False

    def act_batch(self, obs: np.ndarray) -> np.ndarray:
        core = self._bound(obs)
        due = ~core.done & ~(self.verified & self.trust_verified)
        rows = np.flatnonzero(due)
        if rows.size:
            self._replan(rows)
        return self.decision.copy()

    def plan(self, rows: np.ndarray) -> np.ndarray:
        """Re-plan rows ``rows`` of the bound core now (whatever was verified) and return their
        decisions: the oracle as a labeller of states another decider drove to (``train dagger``)."""
        rows = np.asarray(rows, np.int64)
        if rows.size:
            self._replan(rows)
        return self.decision[rows].copy()

    def _replan(self, rows: np.ndarray) -> None:
        core = self.core
        lane_w = core.scen.lane_width[rows]
        # Following from the ego lane needs no check (the next re-plan looks again); a row that is
        # overtaking or still out in the opposite lane also gets its way back simulated.
        exposed = (core.mode[rows] != FOLLOW) | (core.y[rows] > 0.25 * lane_w)
        back = rows[exposed]
        sim_rows = np.concatenate([rows, back])
        cand = np.concatenate([np.full(rows.size, CAND_OVERTAKE), np.full(back.size, CAND_RETREAT)])
        outcome, t_end = simulate(core, sim_rows, cand, self.retreat_steps)
        self.sim_steps += int(np.sum(t_end - core.t[sim_rows]) / self.config.dt + 0.5)
        k = rows.size
        ot_ok = outcome[:k] == SUCCESS
        retreat_ok = np.ones(k, bool)
        retreat_end = np.full(k, np.inf)
        retreat_ok[exposed] = outcome[k:] != CRASH
        retreat_end[exposed] = t_end[k:]
        # Neither is safe: keep overtaking if that crashes later (more time for the next re-plan).
        later = (core.mode[rows] == OVERTAKE) & (t_end[:k] >= retreat_end)
        retreat_mode = np.where(core.y[rows] > 0.25 * lane_w, ABORT, FOLLOW)
        choice = np.where(ot_ok | (~retreat_ok & later), OVERTAKE, retreat_mode)
        self.decision[rows] = choice
        self.verified[rows] = ot_ok

    def card(self) -> str:
        return (
            "oracle v1 (privileged): every 1 s clones the live simulator rows and simulates 'overtake now "
            "and hold' to the end of the episode and 'drop back / follow' for 8 s, all rows in one batch; "
            "overtakes only when the simulated overtake succeeds. An upper bound on follow-then-overtake "
            "deciders at 1 s resolution; never train on it."
        )


register("oracle", lambda config=None, **kw: Oracle(config, **kw))
