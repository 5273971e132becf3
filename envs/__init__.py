"""OvertakeZoo simulation: scenarios, the batched core, the shared planner and the env faces."""

from .config import ABORT, FOLLOW, MODE_NAMES, OVERTAKE, ConfigError, EnvConfig, ModeParams, PlannerConfig
from .core import CRASH, OFFROAD, OUTCOME_NAMES, RUNNING, SUCCESS, TIMEOUT, OvertakeCore, StepResult
from .observation import observation_layout, observation_size
from .scenarios import ScenarioDistribution, Scenarios, make_scenario
from .version import SIM_VERSION

__all__ = [
    "ABORT", "FOLLOW", "OVERTAKE", "MODE_NAMES", "ConfigError", "EnvConfig", "ModeParams", "PlannerConfig",
    "CRASH", "OFFROAD", "OUTCOME_NAMES", "RUNNING", "SUCCESS", "TIMEOUT", "OvertakeCore", "StepResult",
    "observation_layout", "observation_size", "ScenarioDistribution", "Scenarios", "make_scenario",
    "SIM_VERSION",
]

# The env faces (thin adapters over the core). Importing this package registers
# "overtakezoo/Overtake-v0" with Gymnasium and PettingZoo.
from .gym_env import OvertakeEnv, register_envs  # noqa: E402
from .pettingzoo_env import OvertakeParallelEnv, env, parallel_env  # noqa: E402
from .vector_env import OvertakeVectorEnv, make_vec  # noqa: E402

register_envs()
__all__ += ["OvertakeEnv", "OvertakeParallelEnv", "OvertakeVectorEnv", "env", "parallel_env", "make_vec",
            "register_envs", "Renderer", "draw_frame", "frame_from_core"]


def __getattr__(name: str):
    # Rendering pulls in matplotlib: load it only when asked for.
    if name in ("Renderer", "draw_frame", "frame_from_core"):
        from . import render

        return getattr(render, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
