"""``fuzzy``: a Mamdani fuzzy overtaking decider with three modes, vectorized over the batch.

Literature followed:

- Basjaruddin, Kuspriyanto, Saefudin, Nugraha, "Overtaking Assistant System Based on Fuzzy
  Logic", TELKOMNIKA 13(1), 2015: Mamdani inference on the distance to the car ahead
  (near / medium / far) and to the car in the other lane (near / far); near ahead -> tailgate,
  medium ahead & near other -> tailgate, medium ahead & far other -> overtake, far ahead ->
  approach. Rules 1-4 below are theirs (tailgate and approach are both our FOLLOW mode).
- A three-mode design (``docs/planner.md``, "Fuzzy deciders"): a time-margin ratio (clear distance
  available / distance needed to complete the pass, Glennon, TRR 1195, 1988), pass progress and
  the current mode give an output "go-ness" in [0, 1] by centroid; overtake above a threshold,
  abort below a lower one while in the opposite lane and early in the pass (hysteresis), follow
  otherwise.

Inference is written by hand in numpy: memberships are evaluated per row, rule strengths are
min over antecedents, each output set is clipped at the max strength of its rules, the clipped
sets are joined by max on a discretized output universe and defuzzified by centroid, all as (N, U)
arrays. scikit-fuzzy is not installed and its ControlSystem simulates one input vector at a time
in Python, which would put a loop over scenarios in the hot path.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from overtakezoo.envs import ABORT, FOLLOW, OVERTAKE, EnvConfig, ScenarioDistribution, observation_layout
from overtakezoo.envs.model.observation import SLOT_FEATURES
from overtakezoo.zoo.base import Decider, register
from overtakezoo.zoo.members.rule_fsm import lead_from_obs

INF = np.inf


def trap(x: np.ndarray, a: float, b: float, c: float, d: float) -> np.ndarray:
    """Trapezoid membership rising a->b, flat b->c, falling c->d; a == b or c == d is a vertical
    edge (a == b == -inf or c == d == inf: an open shoulder). NaN inputs get 0."""
    x = np.asarray(x, float)
    rise = (x >= a).astype(float) if a == b else np.clip((x - a) / (b - a), 0.0, 1.0)
    fall = (x <= d).astype(float) if c == d else np.clip((d - x) / (d - c), 0.0, 1.0)
    return np.where(np.isnan(x), 0.0, np.minimum(rise, fall))


def membership(x: np.ndarray, shape: tuple[float, ...]) -> np.ndarray:
    """A triangle (a, b, c) or a trapezoid (a, b, c, d)."""
    if len(shape) == 3:
        return trap(x, shape[0], shape[1], shape[1], shape[2])
    if len(shape) == 4:
        return trap(x, *shape)
    raise ValueError(f"a membership is a triangle (a, b, c) or a trapezoid (a, b, c, d), got {shape!r}")


# Input terms: variable -> term -> triangle (a, b, c) or trapezoid (a, b, c, d). Distances in m,
# times in s, ratios unitless.
INPUTS: dict[str, dict[str, tuple[float, ...]]] = {
    "lead_gap": {"near": (-INF, -INF, 8.0, 14.0), "medium": (8.0, 14.0, 20.0, 30.0), "far": (20.0, 30.0, INF, INF)},
    "oncoming_gap": {"near": (-INF, -INF, 25.0, 45.0), "far": (30.0, 55.0, INF, INF)},
    "closing_ttc": {"short": (-INF, -INF, 5.0, 9.0), "long": (7.0, 12.0, INF, INF)},
    "time_margin": {"low": (-INF, -INF, 0.9, 1.1), "ok": (0.9, 1.3, 1.8), "high": (1.4, 1.8, INF, INF)},
    "progress": {"early": (-INF, -INF, 0.25, 0.5), "late": (0.3, 0.6, INF, INF)},
    # Glennon's critical position: distance needed to complete / distance needed to abort.
    "complete_vs_abort": {"before": (1.0, 1.3, INF, INF), "past": (-INF, -INF, 0.8, 1.0)},
    "passing": {"no": (-INF, -INF, 0.0, 1.0), "yes": (0.0, 1.0, INF, INF)},  # crisp 0/1 input
}

# Output "go-ness" on [0, 1]: abort / hold (follow) / go (overtake).
OUTPUT: dict[str, tuple[float, ...]] = {
    "abort": (0.0, 0.0, 0.1, 0.4),
    "hold": (0.2, 0.5, 0.8),
    "go": (0.6, 0.9, 1.0, 1.0),
}

# The rule base: (antecedents {variable: term}, consequent). Antecedents are ANDed (min).
RULES: list[tuple[dict[str, str], str]] = [
    # Before the pass: Basjaruddin et al. 2015 (approach / tailgate / overtake), with our "near"
    # meaning within the planner's avoiding distance (where a pass starts).
    ({"passing": "no", "lead_gap": "far"}, "hold"),  # approach
    ({"passing": "no", "lead_gap": "medium", "oncoming_gap": "near"}, "hold"),  # tailgate
    ({"passing": "no", "lead_gap": "near", "oncoming_gap": "near"}, "hold"),  # tailgate
    ({"passing": "no", "lead_gap": "medium", "oncoming_gap": "far", "time_margin": "high"}, "go"),
    ({"passing": "no", "lead_gap": "near", "oncoming_gap": "far", "time_margin": "high"}, "go"),
    # ... gated by the Glennon time margin and the closing time of the oncoming car.
    ({"passing": "no", "time_margin": "low"}, "hold"),
    ({"passing": "no", "time_margin": "ok"}, "hold"),
    ({"passing": "no", "closing_ttc": "short"}, "hold"),
    # During the pass: keep going with margin or once past half way; abort early without margin.
    ({"passing": "yes", "time_margin": "high"}, "go"),
    ({"passing": "yes", "time_margin": "ok"}, "go"),
    ({"passing": "yes", "progress": "late"}, "go"),
    ({"passing": "yes", "complete_vs_abort": "past"}, "go"),  # past Glennon's critical position
    ({"passing": "yes", "progress": "early", "time_margin": "low", "complete_vs_abort": "before"}, "abort"),
    ({"passing": "yes", "progress": "early", "closing_ttc": "short", "complete_vs_abort": "before"}, "abort"),
]


@dataclass(frozen=True)
class FuzzyParams:
    go_threshold: float = 0.6  # overtake above
    abort_threshold: float = 0.35  # abort below, while passing early
    early_progress: float = 0.5  # an abort is considered only before this pass progress
    max_start_gap: float = 30.0  # m: a pass starts only behind a lead this close
    required_gap: float = 5.0  # m ahead of the lead before merging back (Glennon's g)
    clearance: float = 10.0  # m clearance to the oncoming car at the end of the pass (C)
    abort_deceleration: float = 2.0  # m/s^2 (Glennon's d)
    universe: int = 101  # points of the discretized output universe


class MamdaniRules:
    """A rule base evaluated for a whole batch at once."""

    def __init__(self, inputs=INPUTS, output=OUTPUT, rules=RULES, points: int = 101) -> None:
        self.inputs, self.output, self.rules = inputs, output, rules
        for ante, cons in rules:
            if cons not in output:
                raise ValueError(f"rule consequent {cons!r} is not an output term")
            for var, term in ante.items():
                if term not in inputs.get(var, {}):
                    raise ValueError(f"rule antecedent {var} is {term!r}: unknown variable or term")
        self.u = np.linspace(0.0, 1.0, points)
        self.out_sets = {k: membership(self.u, v) for k, v in output.items()}  # (U,)

    def infer(self, values: dict[str, np.ndarray]) -> np.ndarray:
        """Centroid of the aggregated output for each row; 0.5 (hold) where no rule fires."""
        missing = sorted(set(self.inputs) - set(values))
        if missing:
            raise ValueError(f"fuzzy inputs missing: {', '.join(missing)}")
        n = len(next(iter(values.values())))
        mu = {var: {t: membership(values[var], p) for t, p in terms.items()} for var, terms in self.inputs.items()}
        clip = {k: np.zeros(n) for k in self.output}
        for ante, cons in self.rules:
            s = np.ones(n)
            for var, term in ante.items():
                s = np.minimum(s, mu[var][term])
            clip[cons] = np.maximum(clip[cons], s)
        agg = np.zeros((n, self.u.size))
        for k, level in clip.items():
            agg = np.maximum(agg, np.minimum(level[:, None], self.out_sets[k][None, :]))
        mass = agg.sum(axis=1)
        return np.where(mass > 1e-9, (agg * self.u).sum(axis=1) / np.maximum(mass, 1e-9), 0.5)


class FuzzyDecider(Decider):
    """Mamdani fuzzy decider (Basjaruddin et al. 2015 rule base + Glennon time margin) with follow /
    overtake / abort and hysteresis between the go and abort thresholds."""

    name = "fuzzy"
    version = "1"

    def __init__(self, config: EnvConfig | None = None, params: FuzzyParams | None = None) -> None:
        super().__init__(config)
        self.params = params or FuzzyParams()
        self.engine = MamdaniRules(points=self.params.universe)
        self.layout = observation_layout(self.config)
        self.dist = ScenarioDistribution.from_dict(self.config.scenario)
        self.v_cap = min(self.config.planner.modes["overtake"].velocity, self.dist.speed_limit)
        self.mode = np.zeros(0, np.int64)

    row_state = ("mode",)

    def reset(self, mask: np.ndarray | None = None) -> None:
        if mask is None:
            self.mode = np.zeros(0, np.int64)
        elif self.mode.shape[0] == len(mask):
            self.mode[np.asarray(mask, bool)] = FOLLOW

    def features(self, obs: np.ndarray) -> dict[str, np.ndarray]:
        """The fuzzy inputs from the observation (plus the current mode)."""
        cfg, oc, p, dist = self.config, self.config.observation, self.params, self.dist
        n = len(obs)
        rows = np.arange(n)
        ego = obs[:, self.layout["ego"]].astype(float)
        v_e = ego[:, 0] * oc.speed_scale
        lateral = ego[:, 2]
        Le, L = dist.ego_length, dist.vehicle_length
        # The vehicle being passed: the nearest ego-lane vehicle ahead, or while in the opposite lane
        # the nearest one not yet cleared by the required gap.
        ego_slots = obs[:, self.layout["ego_lane"]].reshape(n, -1, SLOT_FEATURES).astype(float)
        ex = ego_slots[:, :, 1] * oc.position_scale
        in_opp = lateral > 0.5
        cand = (ego_slots[:, :, 0] > 0.5) & ((ex > 0.0) | (in_opp[:, None] & (ex > -(Le + L) / 2 - p.required_gap - L)))
        key = np.where(cand, ex, np.inf)
        li = np.argmin(key, axis=1)
        has_lead = np.isfinite(key[rows, li])
        lead_dx = np.where(has_lead, key[rows, li], np.inf)
        v_1 = v_e + ego_slots[rows, li, 3] * oc.speed_scale
        lead_gap = np.where(has_lead, lead_from_obs(obs, cfg, self.layout, dist)["gap"], np.inf)
        # Nearest oncoming vehicle ahead.
        opp = obs[:, self.layout["opposite_lane"]].reshape(n, -1, SLOT_FEATURES).astype(float)
        ox = opp[:, :, 1] * oc.position_scale
        okey = np.where((opp[:, :, 0] > 0.5) & (ox > -(Le + L) / 2), ox, np.inf)
        oi = np.argmin(okey, axis=1)
        has_onc = np.isfinite(okey[rows, oi])
        onc_gap = np.where(has_onc, okey[rows, oi] - (Le + L) / 2, np.inf)
        closing = np.where(has_onc, -opp[rows, oi, 3] * oc.speed_scale, 0.0)
        v_2 = np.maximum(closing - v_e, 0.0)
        ttc = np.where(closing > 1e-3, np.maximum(onc_gap, 0.0) / np.maximum(closing, 1e-3), np.inf)
        # Glennon: ego front relative to the lead's front; time and distance to complete the pass.
        delta = -lead_dx + (Le - L) / 2
        m = self.v_cap - v_1
        t_c = np.where(m > 0.1, (Le + p.required_gap - delta) / np.maximum(m, 0.1), np.inf)
        t_c = np.maximum(t_c, 0.0)
        d_c = (self.v_cap + v_2) * t_c + p.clearance
        with np.errstate(invalid="ignore"):  # inf / inf where there is no oncoming car (masked next)
            margin = np.where(has_onc, np.maximum(onc_gap, 0.0) / np.maximum(d_c, 1e-3), np.inf)
        margin = np.where(has_lead, margin, np.inf)
        d_a = self._abort_distance(v_e, v_1, v_2, delta, L)
        critical = np.where(has_lead, d_c / np.maximum(d_a, 1e-3), 0.0)
        progress = np.where(has_lead, (delta + L) / (Le + L + p.required_gap), 1.0)
        passing = (self.mode != FOLLOW).astype(float)
        return {
            "lead_gap": lead_gap,
            "oncoming_gap": onc_gap,
            "closing_ttc": ttc,
            "time_margin": margin,
            "complete_vs_abort": critical,
            "progress": progress,
            "passing": passing,
            "lateral": lateral,
            "has_lead": has_lead,
        }

    def _abort_distance(self, v_e, v_1, v_2, delta, L_1):
        """Glennon's distance needed to abort, D_a = ego travel + oncoming travel + C over the abort
        time, with the ego's speed floored where the shared planner's ABORT holds it (the lead's speed
        minus the drop-back, never below 0) instead of Glennon's unbounded deceleration."""
        pc, p = self.config.planner, self.params
        d = p.abort_deceleration
        v_ab = np.maximum(v_1 - pc.abort_drop_back, 0.0)
        s_need = np.maximum(delta + L_1 + pc.abort_clearance, 0.0)  # ego front back behind the lead
        t1 = np.maximum(v_e - v_ab, 0.0) / d  # braking phase
        lost1 = (v_1 - v_e) * t1 + d * t1**2 / 2  # relative distance lost while braking
        # Reached while braking: solve d t^2 / 2 - m t - s_need = 0 (Glennon's t_a).
        m = v_e - v_1
        t_brake = (m + np.sqrt(np.maximum(m**2 + 2 * d * s_need, 0.0))) / d
        rel = np.maximum(v_1 - v_ab, 1e-3)
        t_a = np.where(lost1 >= s_need, t_brake, t1 + (s_need - lost1) / rel)
        t_b = np.minimum(t_a, t1)
        ego_travel = v_e * t_b - d * t_b**2 / 2 + v_ab * np.maximum(t_a - t1, 0.0)
        return ego_travel + v_2 * t_a + p.clearance

    def act_batch(self, obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs)
        if self.mode.shape[0] != obs.shape[0]:
            self.mode = np.full(obs.shape[0], FOLLOW, np.int64)
        f = self.features(obs)
        go = self.engine.infer(f)
        p = self.params
        early = f["progress"] < p.early_progress
        in_opp = f["lateral"] > 0.25
        mode = self.mode
        start = (mode == FOLLOW) & f["has_lead"] & (f["lead_gap"] < p.max_start_gap) & (go > p.go_threshold)
        low = (mode == OVERTAKE) & early & (go < p.abort_threshold)
        resume = (mode == ABORT) & in_opp & (go > p.go_threshold)  # past the critical position after all
        abort = low & in_opp  # drop back behind the lead
        cancel = low & ~in_opp  # still in the ego lane: just stay behind
        # A pass is over once the lead is cleared and the ego is back in its lane; an abort once the
        # ego is back in its lane.
        finished = (mode == OVERTAKE) & ~f["has_lead"] & ~in_opp
        back = (mode == ABORT) & (f["lateral"] < 0.1)
        new = np.where(start, OVERTAKE, mode)
        new = np.where(abort, ABORT, new)
        new = np.where(resume, OVERTAKE, new)
        new = np.where(finished | back | cancel, FOLLOW, new)
        self.mode = new
        return new.copy()

    def card(self) -> str:
        return (
            "fuzzy v1: Mamdani fuzzy decider (Basjaruddin et al., TELKOMNIKA 2015 rule base, plus a "
            "Glennon time margin, pass progress and mode; min/max inference, centroid on a "
            f"{self.params.universe}-point universe); overtake when go-ness > {self.params.go_threshold}, "
            f"abort when < {self.params.abort_threshold} early in a pass, follow otherwise. "
            f"{len(RULES)} rules, vectorized in numpy."
        )


register("fuzzy", lambda config=None, **kw: FuzzyDecider(config, **kw))
