"""OvertakeZoo simulation: scenarios, the batched core, the shared planner and the env faces."""

from .config import ABORT, FOLLOW, MODE_NAMES, OVERTAKE, ConfigError, EnvConfig, ModeParams, PlannerConfig
from .core import CRASH, OFFROAD, OUTCOME_NAMES, RUNNING, SUCCESS, TIMEOUT, OvertakeCore, StepResult
from .observation import observation_layout, observation_size
from .scenarios import ScenarioDistribution, Scenarios, make_scenario

__all__ = [
    "ABORT", "FOLLOW", "OVERTAKE", "MODE_NAMES", "ConfigError", "EnvConfig", "ModeParams", "PlannerConfig",
    "CRASH", "OFFROAD", "OUTCOME_NAMES", "RUNNING", "SUCCESS", "TIMEOUT", "OvertakeCore", "StepResult",
    "observation_layout", "observation_size", "ScenarioDistribution", "Scenarios", "make_scenario",
]
