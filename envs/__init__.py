"""OvertakeZoo simulation: scenarios, the batched core, the shared planner and the env faces."""

from overtakezoo.envs.config import (
    ABORT,
    FOLLOW,
    MODE_NAMES,
    OVERTAKE,
    ConfigError,
    EnvConfig,
    ModeParams,
    PlannerConfig,
)
from overtakezoo.envs.core import CRASH, OFFROAD, OUTCOME_NAMES, RUNNING, SUCCESS, TIMEOUT, OvertakeCore, StepResult
from overtakezoo.envs.model.observation import observation_layout, observation_size
from overtakezoo.envs.scenarios import ScenarioDistribution, Scenarios, make_scenario
from overtakezoo.envs.version import SIM_VERSION

__all__ = [
    "ABORT",
    "FOLLOW",
    "OVERTAKE",
    "MODE_NAMES",
    "ConfigError",
    "EnvConfig",
    "ModeParams",
    "PlannerConfig",
    "CRASH",
    "OFFROAD",
    "OUTCOME_NAMES",
    "RUNNING",
    "SUCCESS",
    "TIMEOUT",
    "OvertakeCore",
    "StepResult",
    "observation_layout",
    "observation_size",
    "ScenarioDistribution",
    "Scenarios",
    "make_scenario",
    "SIM_VERSION",
]

# The env faces (thin adapters over the core). Importing this package registers
# "overtakezoo/Overtake-v1" (table1-train, decisions held 1 s), "overtakezoo/Overtake-v0" (the env's
# defaults, one core step per env step) and every suite's id with Gymnasium and PettingZoo.
from overtakezoo.envs.faces.gym import OvertakeEnv, register_envs  # noqa: E402
from overtakezoo.envs.faces.pettingzoo import OvertakeParallelEnv, env, parallel_env, sb3_vec_env  # noqa: E402
from overtakezoo.envs.faces.vector import OvertakeVectorEnv, make_vec  # noqa: E402

register_envs()
__all__ += [
    "OvertakeEnv",
    "OvertakeParallelEnv",
    "OvertakeVectorEnv",
    "env",
    "parallel_env",
    "sb3_vec_env",
    "make_vec",
    "register_envs",
    "Renderer",
    "draw_frame",
    "frame_from_core",
]


def __getattr__(name: str):
    # Rendering pulls in matplotlib: load it only when asked for.
    if name in ("Renderer", "draw_frame", "frame_from_core"):
        from overtakezoo.envs.faces import render

        return getattr(render, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
