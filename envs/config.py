"""Typed, validated configuration of the simulator, planner and reward.

Every number of the model is a setting here. ``EnvConfig.from_dict`` accepts nested dicts (as read
from a suite's TOML file) and raises :class:`ConfigError` naming the offending key for unknown keys
or out-of-range values.

Every setting is a dataclass field carrying its range (:func:`bounded`, checked by :func:`check_ranges`);
the settings are many, hence the length of this module. ``from_dict`` uses the project's one
dict-to-dataclass builder (:func:`overtakezoo.envs.typed.build`), as the trainers' hyperparameters do.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from overtakezoo.envs.typed import bool_problem, build, number_problem
from overtakezoo.envs.typed import bounded as bounded  # (re-exported: every settings module declares its ranges so)
from overtakezoo.envs.typed import check_ranges as _check_ranges
from overtakezoo.envs.typed import unknown_key as unknown_key

FOLLOW, OVERTAKE, ABORT = 0, 1, 2
MODE_NAMES = ("follow", "overtake", "abort")


class ConfigError(ValueError):
    """A configuration key is unknown or its value is out of range."""


class SuiteError(ConfigError):
    """A suite name, file or shard the user gave is unknown or malformed (the CLI prints one line)."""


def check_ranges(obj: Any, prefix: str, skip: tuple[str, ...] = ()) -> None:
    """Every :func:`~overtakezoo.envs.typed.bounded` field of dataclass ``obj`` inside its range
    (ConfigError naming it)."""
    _check_ranges(obj, prefix, ConfigError, skip)


@dataclass(frozen=True)
class ModeParams:
    """One mode of the shared planner: the six parameters the paper lists per mode.

    ``velocity`` caps the target speed (m/s; also capped by the scenario's speed limit);
    ``acceleration`` is the largest acceleration (m/s^2) the mode may command (braking is set by the
    planner's ``max_braking``); ``following_distance`` is the bumper gap kept behind a same-direction
    leader; ``avoiding_distance`` is the gap to that leader below which the planner may swerve around
    it (OpenPlanner's minDistanceToAvoid); ``rollout_number`` is how many rollouts beyond the centre one
    the mode may use (0 = the ego-lane rollout only, OpenPlanner's swerving off); ``rollout_id`` forces a
    rollout (-1 lets the evaluator choose; 0 is the ego-lane centre).
    """

    velocity: float
    acceleration: float
    following_distance: float
    avoiding_distance: float
    rollout_number: int
    rollout_id: int

    def validate(self, prefix: str, num_rollouts: int) -> None:
        _check(f"{prefix}.velocity", self.velocity, 0.0, 60.0)
        _check(f"{prefix}.acceleration", self.acceleration, 0.0, 10.0)
        _check(f"{prefix}.following_distance", self.following_distance, 0.0, 200.0)
        _check(f"{prefix}.avoiding_distance", self.avoiding_distance, 0.0, 200.0)
        _check(f"{prefix}.rollout_number", self.rollout_number, 0, num_rollouts, integer=True)
        _check(f"{prefix}.rollout_id", self.rollout_id, -1, num_rollouts, integer=True)


def _default_modes() -> dict[str, ModeParams]:
    # Speeds are capped by the scenario's own speed limit (15 km/h in the paper's suites), so the
    # velocity entries are upper bounds. FOLLOW: OpenPlanner with swerving off (rollOutsNumber 0).
    # OVERTAKE: every rollout up to the opposite lane's centre, at the cap, swerving once the lead is
    # within the avoiding distance. ABORT: the centre rollout forced; the planner drops back behind
    # the lead before merging (see planner.py).
    return {
        "follow": ModeParams(40.0, 1.0, 6.0, 12.0, 0, 0),
        "overtake": ModeParams(40.0, 1.5, 3.0, 12.0, 4, -1),
        "abort": ModeParams(40.0, 1.0, 3.0, 12.0, 0, 0),
    }


@dataclass(frozen=True)
class PlannerConfig:
    """OpenPlanner-style rollout planner. The values' public sources (hatem-darweesh/common
    ``op_planner``, hatem-darweesh/core_planning ``op_local_planner`` launch files) and our departures
    from them are in ``docs/planner.md``. Each setting's range is beside it (``bounded``)."""

    # n: rollouts 0..n end at offsets k * lane_width / n (0 = ego-lane centre)
    num_rollouts: int = bounded(4, 1, 16)
    horizon_time: float = bounded(4.0, 0.1, 60.0, "s")  # collision check against predicted paths of perceived vehicles
    # Constant-velocity prediction of perceived vehicles. OpenPlanner's evaluator has it off unless
    # enablePrediction is set (docs/planner.md); table1 runs it off, the env's default keeps it on.
    enable_prediction: bool = True
    car_tip_margin: float = bounded(1.0, 0.0, 100.0, "m")  # held at the current offset before the roll-in starts
    roll_in_speed_factor: float = bounded(1.0, 0.01, 10.0, "s")  # roll-in length = factor * v + margin (m)
    roll_in_margin: float = bounded(4.0, 0.0, 100.0, "m")
    horizontal_safety: float = bounded(1.0, 0.0, 10.0, "m")  # added to half widths (OpenPlanner launch: 1.2)
    vertical_safety: float = bounded(1.5, 0.0, 50.0, "m")  # added to half lengths
    # OpenPlanner's launch files weight the four costs equally; with that, the transition cost keeps
    # a finished pass in the opposite lane, so the centre preference is weighted up here.
    weight_priority: float = bounded(0.35, 0.0, 100.0)
    weight_transition: float = bounded(0.1, 0.0, 100.0)
    weight_lateral: float = bounded(0.35, 0.0, 100.0)
    weight_longitudinal: float = bounded(0.2, 0.0, 100.0)
    keep_margin: float = bounded(0.05, 0.0, 100.0)  # keep the current rollout if its cost is within this of the best
    time_headway: float = bounded(1.0, 0.1, 10.0, "s")  # ego IDM headway behind a leader
    comfortable_braking: float = bounded(2.0, 0.1, 10.0, "m/s^2")  # ego IDM b
    max_braking: float = bounded(5.0, 0.1, 15.0, "m/s^2")  # ego emergency braking bound (1.5 g at most)
    # Off (OpenPlanner's follow behaviour, and every single-ego suite): the speed plan follows only
    # same-direction vehicles, and the jerk limit bounds every brake. On: an oncoming vehicle on the
    # path is braked for too, and a brake beyond comfortable_braking is applied without the jerk limit.
    emergency_braking: bool = False
    max_jerk: float = bounded(3.0, 0.1, 100.0, "m/s^3")
    abort_clearance: float = bounded(2.0, 0.0, 100.0, "m")  # between the ego and the lead before an abort merges back
    abort_drop_back: float = bounded(1.5, 0.0, 40.0, "m/s")  # below the lead's speed while an abort drops back
    lookahead_min: float = bounded(3.0, 0.1, 100.0, "m")  # pure pursuit lookahead = max(min, gain * v)
    lookahead_gain: float = bounded(1.0, 0.01, 10.0, "s")
    max_steer: float = bounded(0.42, 0.01, 1.2, "rad")  # OpenPlanner launch default; 1.2 rad is about 70 degrees
    max_steer_rate: float = bounded(0.6, 0.01, 10.0, "rad/s")
    wheelbase: float = bounded(2.7, 0.5, 10.0, "m")  # a small car to a bus
    modes: dict[str, ModeParams] = field(default_factory=_default_modes)

    def mode(self, index: int) -> ModeParams:
        return self.modes[MODE_NAMES[index]]

    def validate(self) -> None:
        check_ranges(self, "planner.")
        for key in ("enable_prediction", "emergency_braking"):
            _check_bool(f"planner.{key}", getattr(self, key))
        if not isinstance(self.modes, dict):
            raise ConfigError(f"planner.modes: expected a table of modes, got {self.modes!r}")
        unknown = set(self.modes) - set(MODE_NAMES)
        if unknown:
            raise ConfigError(f"planner.modes: unknown mode {sorted(unknown)[0]!r} (expected {', '.join(MODE_NAMES)})")
        for name in MODE_NAMES:
            if name not in self.modes:
                raise ConfigError(f"planner.modes.{name}: missing")
            self.modes[name].validate(f"planner.modes.{name}", self.num_rollouts)


@dataclass(frozen=True)
class NPCConfig:
    """IDM parameters shared by every NPC (Treiber et al. 2000); each range is beside it."""

    max_acceleration: float = bounded(1.0, 0.1, 10.0, "m/s^2")
    comfortable_braking: float = bounded(1.5, 0.1, 10.0, "m/s^2")
    max_braking: float = bounded(6.0, 0.1, 15.0, "m/s^2")
    min_gap: float = bounded(2.0, 0.1, 50.0, "m")
    time_headway: float = bounded(1.2, 0.1, 10.0, "s")
    # A speed-up lead reacts once the ego's front is this close behind it (negative: once level with it).
    speedup_trigger: float = bounded(2.0, -50.0, 50.0, "m")

    def validate(self) -> None:
        check_ranges(self, "npc.")


@dataclass(frozen=True)
class RewardConfig:
    """The reward every face and trainer uses: the paper's shape (progress towards the goal, a bonus
    for finishing in the correct lane, a crash penalty, a small penalty per switch into or out of
    OVERTAKE) plus a cost of time and a timeout penalty, so that following the lead until the time
    limit is never the best return (the paper's weights alone rank always-follow first on
    table1-train; see the README's "Reward" section for the measured returns). Every term lies in
    [-1e6, 1e6] (far beyond any useful weight; it keeps returns finite in float32)."""

    # Progress per step: progress / (1 + distance_to_goal / progress_scale), at most 0.01 per step
    # (~6 over a 60 s episode): small next to the terminal terms, it only breaks ties towards the goal.
    progress: float = bounded(0.01, -1e6, 1e6)
    progress_scale: float = bounded(
        10.0, 1e-3, 1e6, "m"
    )  # the progress term doubles over the last progress_scale metres
    success: float = bounded(10.0, -1e6, 1e6)  # finishing past the goal in the ego lane, ahead of NPC1: the task
    crash: float = bounded(-10.0, -1e6, 1e6)  # a collision costs the success bonus it forgoes, and as much again
    switch: float = bounded(-0.1, -1e6, 1e6)  # per switch into or out of OVERTAKE: discourages dithering, not aborting
    timeout: float = bounded(
        -5.0, -1e6, 1e6
    )  # the time limit is part of the task: not finishing is a failure, half a crash
    offroad: float = bounded(-10.0, -1e6, 1e6)  # leaving the road is as bad as a crash
    # Per step of a running episode (-0.1 per s at dt = 0.1): waiting behind the lead is not free,
    # so a safe pass earns more than following and a pass that can be made is not put off.
    time: float = bounded(-0.01, -1e6, 1e6)

    def validate(self) -> None:
        check_ranges(self, "reward.")


@dataclass(frozen=True)
class ObservationConfig:
    """Per-lane nearest-vehicle slots; positions are divided by ``position_scale`` and speeds by
    ``speed_scale`` so features are O(1)."""

    vehicles_per_lane: int = bounded(2, 1, 16)
    position_scale: float = bounded(50.0, 0.1, 10000.0, "m")
    speed_scale: float = bounded(5.0, 0.01, 100.0, "m/s")
    # Vehicle-to-vehicle messages (opt-in; off keeps every shipped observation and row): a block
    # after the vehicle slots saying, per slot, whether the vehicle is an automated vehicle and
    # whether it is overtaking or aborting (what an AV would broadcast, e.g. in ETSI's Maneuver
    # Coordination Service, TR 103 578). Without it a decentralised AV cannot tell when another AV
    # of its road is about to pull out until that AV has moved sideways.
    v2v: bool = False
    # The share of the episode's time limit still left (opt-in, appended after the v2v block): with
    # a timeout counted as a failure the time left is part of the task's state (Pardo et al. 2018,
    # "Time Limits in Reinforcement Learning"); without it the same observation may call for a
    # cautious wait early and a pass late.
    time_left: bool = False

    def validate(self) -> None:
        check_ranges(self, "observation.")
        _check_bool("observation.v2v", self.v2v)
        _check_bool("observation.time_left", self.time_left)


RENDER_MODES = (None, "rgb_array", "human")
# An episode of at most this many core steps (time_limit / dt): table1's is 600; beyond this a run
# would take hours, almost always a typo (time_limit in ms, dt in s).
MAX_EPISODE_STEPS = 100_000


@dataclass(frozen=True)
class EnvConfig:
    """Everything a face of the simulator needs besides the scenarios themselves."""

    dt: float = bounded(0.1, 1e-3, 1.0, "s")
    decision_interval: int = bounded(1, 1, 1000)  # the decider acts every k steps
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    npc: NPCConfig = field(default_factory=NPCConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)
    observation: ObservationConfig = field(default_factory=ObservationConfig)
    scenario: dict[str, Any] = field(default_factory=dict)  # a ScenarioDistribution as a dict
    # Must be 1. Kept so that every stored configuration (and its hash) keeps its field set: the
    # automated vehicles of a road come from the scenario distribution (platoon_size, oncoming_av).
    num_egos: int = bounded(1, 1, 4096)
    npc_agents: bool = False
    render_mode: str | None = field(default=None, metadata={"choices": RENDER_MODES})
    seed: int | None = None  # None, or an integer in [0, 2**63 - 1] (numpy's seeds are non-negative)

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        check_ranges(self, "")
        if self.num_egos != 1:
            raise ConfigError(
                f"num_egos: {self.num_egos} is no longer supported (only 1): the agents of parallel_env are the "
                "automated vehicles of one road (av_0, av_1, ...; set scenario.platoon_size / scenario.oncoming_av, "
                "or use a multi-AV suite such as duel); for several roads at once use SuperSuit's vector of envs "
                "or step OvertakeCore (see the PettingZoo section of the README)"
            )
        _check_bool("npc_agents", self.npc_agents)
        if self.seed is not None:
            _check("seed", self.seed, 0, 2**63 - 1, integer=True)
        if self.render_mode not in RENDER_MODES:
            raise ConfigError(f"render_mode: {self.render_mode!r} is not one of {', '.join(map(repr, RENDER_MODES))}")
        for key, cls in _NESTED.items():  # a value that is no table (npc = [1, 2]) never reaches .validate
            value = getattr(self, key)
            if not isinstance(value, cls):
                raise ConfigError(
                    f"{key}: expected a table, got {value!r}"
                    if not isinstance(value, dict)
                    else f"{key}: expected a {cls.__name__} (EnvConfig.from_dict builds one from a table)"
                )
        self.planner.validate()
        self.npc.validate()
        self.reward.validate()
        self.observation.validate()
        from overtakezoo.envs.scenarios import ScenarioDistribution

        dist = ScenarioDistribution.from_dict(self.scenario)  # raises ConfigError naming the key
        steps = dist.time_limit / self.dt
        if steps > MAX_EPISODE_STEPS:
            raise ConfigError(
                f"scenario.time_limit: {dist.time_limit:g} s at dt = {self.dt:g} s is {steps:.0f} steps "
                f"per episode, more than {MAX_EPISODE_STEPS} (lower time_limit or raise dt)"
            )

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None = None, **overrides: Any) -> EnvConfig:
        merged = dict(data or {})
        merged.update(overrides)
        # envs/typed.py's builder checks key by key; validate() runs again as the config is made (it also
        # holds a config made directly, EnvConfig(dt=...), and the checks across keys).
        return build(cls, merged, error=ConfigError)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def with_observation(self, **changes: Any) -> EnvConfig:
        """This configuration with observation settings ``changes`` (``v2v=True``)."""
        return dataclasses.replace(self, observation=dataclasses.replace(self.observation, **changes))


def _check_bool(key: str, value: Any) -> None:
    why = bool_problem(value)
    if why:
        raise ConfigError(f"{key}: {why}")


def _check(key: str, value: Any, lo: float, hi: float, integer: bool = False, unit: str = "") -> None:
    why = number_problem(value, lo, hi, integer, unit)
    if why:
        raise ConfigError(f"{key}: {why}")


_NESTED = {"planner": PlannerConfig, "npc": NPCConfig, "reward": RewardConfig, "observation": ObservationConfig}
