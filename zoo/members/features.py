"""The learned members' input: the observation re-expressed relative to the road's speed limit.

The env's observation scales speeds and distances by fixed constants (``observation.speed_scale``,
``position_scale``), chosen for table1's 15 km/h. At urban-50's 50 km/h the same features are ~3x
larger, so a network trained at one speed sees inputs it never met at another. Here every speed is
divided by the row's speed limit ``L`` (ego feature 4 of the observation) and every distance by
``L * HORIZON_S``, the distance covered in ``HORIZON_S`` seconds at the limit (the sensor range too:
how far the ego sees becomes how long it sees ahead): a gap becomes a time,
a closing speed a fraction of the limit. A scenario driven at k times the speeds with k times the
distances gives the same features. The speed limit itself is kept as ``log(L / speed_scale)``, so
the network can still tell a 15 km/h shuttle road from a 50 km/h street (braking distances do not
scale linearly with speed).

The layout is the observation's (``observation_layout``): mode one-hot, blocked flags, lateral
offsets and presence flags pass through unchanged, so the action mask reads features as it reads
observations. The same function serves training and inference: numpy arrays in, float64 numpy out;
a torch tensor (the device trainer's observations, zoo/train/devppo.py) stays a tensor on its device.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from overtakezoo.envs import EnvConfig, observation_layout
from overtakezoo.envs.model.observation import SLOT_FEATURES

FEATURES_VERSION = "speed-relative-v1"
HORIZON_S = 10.0  # distances in units of 10 s at the speed limit: table1's 60 m sight is ~1.4


def speed_relative(obs: Any, config: EnvConfig) -> Any:
    """(N, D) observations -> (N, D) float64 features (see the module docstring)."""
    if type(obs).__module__.startswith("torch"):  # a tensor: computed on its device, in its dtype
        out = obs.clone()
        limit = (obs[:, observation_layout(config)["ego"].start + 4] * config.observation.speed_scale).clamp(min=1e-3)
        log = type(limit).log
    else:
        out = np.array(obs, np.float64)
        limit = np.maximum(out[:, observation_layout(config)["ego"].start + 4] * config.observation.speed_scale, 1e-3)
        log = np.log
    oc, lay = config.observation, observation_layout(config)
    ego = lay["ego"].start  # (limit: the speed limit in m/s; > 0 for any valid scenario)
    speed = oc.speed_scale / limit  # observation speed unit -> fraction of the limit
    dist = oc.position_scale / (limit * HORIZON_S)  # observation distance unit -> horizons
    out[:, ego + 0] *= speed
    out[:, ego + 3] *= dist
    out[:, ego + 4] = log(limit / oc.speed_scale)
    out[:, ego + 5] *= dist
    for lane in ("ego_lane", "opposite_lane"):
        s = lay[lane]
        slots = out[:, s].reshape(len(out), -1, SLOT_FEATURES)  # presence, x, y, vx, vy
        slots[:, :, 1] *= dist[:, None]
        slots[:, :, 3:5] *= speed[:, None, None]
        out[:, s] = slots.reshape(len(out), -1)
    return out
