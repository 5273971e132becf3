"""TorchRL on OvertakeZoo's multi-AV suite duel: one Q-network shared by both AVs of a road, exported to ONNX.

    python examples/torchrl_marl.py --seed 0 --out runs/torchrl
    overtakezoo eval --suite duel --policy runs/torchrl/policy.onnx

Independent Q-learning with shared parameters (one DQN for every automated vehicle, each AV learning
from its own transitions as in TorchRL's ``sota-implementations/multiagent/iql.py``), on the PettingZoo
ParallelEnv face of the training suite ``duel-train`` (two AVs per road, one per direction; agents
``av_0``, ``av_1``; actions 0 follow / 1 overtake / 2 abort; one env step is one decision held 10 core
steps, 1 s). TorchRL's own parts do the work: ``PettingZooWrapper`` (both AVs in one group
``agents``; ``use_mask=True`` since an AV that finishes leaves the episode before the other,
``done_on_any=False`` so the road runs on until both are done), ``SerialEnv`` of roads, ``Collector``,
``EGreedyModule``, ``QValueModule`` / ``QValueActor``, ``DuelingMlpDQNet``, ``MultiStepTransform``
(3-step returns), ``TensorDictReplayBuffer``, ``DQNLoss`` and ``HardUpdate``. The glue written here:
infos reduced to the outcome code, the AVs' rows split out of each road and the finished AVs' rows
dropped, and the action mask of the zoo's DQN members in the network. The exported ``policy.onnx``
maps the raw observation (N, D) to (N, 3) Q-values (``eval`` takes their argmax and drives every AV
of a road with it); its policy card (``action_repeat=10``, suite duel-train) goes into the ONNX
metadata (docs/guides/torchrl.md).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import random
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn
from pettingzoo.utils.wrappers import BaseParallelWrapper
from tensordict import TensorDict
from tensordict.nn import TensorDictModule, TensorDictSequential
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs import MultiStepTransform, SerialEnv
from torchrl.envs.libs.pettingzoo import PettingZooWrapper
from torchrl.envs.utils import MarlGroupMapType
from torchrl.modules import EGreedyModule, QValueActor, QValueModule
from torchrl.modules.models import DuelingMlpDQNet
from torchrl.objectives import DQNLoss, HardUpdate

from overtakezoo.benchmark.run.artifacts import write_card
from overtakezoo.envs import ABORT, FOLLOW, OVERTAKE, observation_layout
from overtakezoo.envs.faces.pettingzoo import parallel_env
from overtakezoo.zoo.members.learned import IN_LANE

SUITE, HOLD = "duel-train", 10  # a suite's PettingZoo env holds each decision 10 core steps (1 s)
GROUP = "agents"  # TorchRL's group of all AVs (MarlGroupMapType.ALL_IN_ONE_GROUP)
OUTCOMES = ("running", "success", "crash", "timeout", "off-road")


@dataclass
class Args:
    seed: int = 0
    """seed of random, numpy, torch and the roads"""
    out: str = "runs/torchrl"
    """folder for policy.onnx and train.json"""
    total_frames: int = 44_800
    """road steps to collect (TorchRL's frames: one per road and env step; about 1.8 AV decisions each)"""
    roads: int = 16
    """PettingZoo envs (roads) in TorchRL's SerialEnv"""
    frames_per_batch: int = 128
    """road steps per collection (8 per road; total_frames is a multiple of it)"""
    n_step: int = 3
    """n-step returns (MultiStepTransform)"""
    gamma: float = 0.99
    lr: float = 5e-4
    batch_size: int = 256
    buffer_size: int = 200_000
    learning_starts: int = 5_000
    """AV transitions stored before the first gradient step"""
    decisions_per_update: float = 4.0
    """AV transitions collected per gradient step"""
    target_update: int = 1_000
    """gradient steps between hard target syncs"""
    eps_start: float = 1.0
    eps_end: float = 0.02
    eps_fraction: float = 0.3
    """share of total_frames over which epsilon falls"""
    grad_clip: float = 10.0
    hidden: int = 128


def parse_args() -> Args:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    for f in dataclasses.fields(Args):
        parser.add_argument(f"--{f.name.replace('_', '-')}", type=type(f.default), default=f.default)
    return Args(**vars(parser.parse_args()))


class OutcomeInfos(BaseParallelWrapper):
    """The face's infos reduced to the outcome code (0 running, 1 success, 2 crash, 3 timeout, 4 off-road):
    TorchRL turns every info entry into a tensor, and some of the face's are None or strings."""

    def reset(self, seed=None, options=None):
        obs, infos = self.env.reset(seed=seed, options=options)
        return obs, {a: {"outcome": info["outcome"]} for a, info in infos.items()}

    def step(self, actions):
        obs, rewards, terminations, truncations, infos = self.env.step(actions)
        return obs, rewards, terminations, truncations, {a: {"outcome": i["outcome"]} for a, i in infos.items()}


def make_env() -> PettingZooWrapper:
    with warnings.catch_warnings():  # "PettingZoo in TorchRL is tested using version == 1.24.3"
        warnings.simplefilter("ignore", UserWarning)
        return PettingZooWrapper(
            OutcomeInfos(parallel_env(SUITE)),
            group_map=MarlGroupMapType.ALL_IN_ONE_GROUP,
            use_mask=True,  # a finished AV leaves `agents`: its later rows are masked out
            done_on_any=False,  # the road goes on until every AV is done (the default ends it at the first)
            categorical_actions=True,
        )


class QNet(nn.Module):
    """Raw observation (N, D) -> (N, 3) Q-values: scaled by the observation space's bounds, a dueling MLP
    (TorchRL's DuelingMlpDQNet), and the action mask of the zoo's DQN members (zoo/members/learned.py,
    version 3) applied as a large negative value, so that the argmax, the target's max and the exported
    file all keep to it: abort only while overtaking or aborting, follow only from follow or inside the
    own lane, no overtake while an abort is still bringing the AV back to its lane."""

    MASKED = -1e6

    def __init__(self, low: np.ndarray, high: np.ndarray, layout: dict[str, slice], hidden: int) -> None:
        super().__init__()
        low, high = torch.as_tensor(low), torch.as_tensor(high)
        self.register_buffer("center", (high + low) / 2)
        self.register_buffer("scale", ((high - low) / 2).clamp(min=0.5))
        self.mode, self.lateral = layout["mode"].start, layout["ego"].start + 2  # mode one-hot; y / lane width
        self.net = DuelingMlpDQNet(
            3,
            mlp_kwargs_feature={
                "in_features": low.shape[0],
                "num_cells": [hidden],
                "out_features": hidden,
                "activation_class": nn.ReLU,
                "activate_last_layer": True,
            },
            mlp_kwargs_output={"in_features": hidden, "depth": 0},
        )

    def allowed(self, obs: torch.Tensor) -> torch.Tensor:
        in_follow = obs[..., self.mode + FOLLOW] > 0.5
        in_abort = obs[..., self.mode + ABORT] > 0.5
        in_lane = obs[..., self.lateral].abs() < IN_LANE
        allowed = [None] * 3
        allowed[FOLLOW], allowed[OVERTAKE], allowed[ABORT] = in_follow | in_lane, ~in_abort | in_lane, ~in_follow
        return torch.stack(allowed, -1)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        q = self.net((obs - self.center) / self.scale)
        return torch.where(self.allowed(obs), q, torch.full_like(q, self.MASKED))


def av_rows(data: TensorDict) -> TensorDict:
    """A collected batch [roads, T] (both AVs of a road in the group ``agents``) as one trajectory per AV,
    [roads * 2, T], with the keys of a single-agent DQN. A timeout ends an AV's episode like a crash
    (``terminated`` is ``done``: the time limit is part of the task, as in the zoo's trainers)."""
    a, n = data[GROUP], data["next", GROUP]
    rows = TensorDict(
        {
            "observation": a["observation"],
            "action": a["action"],
            "mask": a["mask"],  # alive before the step: the AV's own transition
            "next": {
                "observation": n["observation"],
                "reward": n["reward"],
                "done": n["done"],
                "terminated": n["done"].clone(),
            },
        },
        batch_size=a.batch_size,  # [roads, T, 2]
    )
    return rows.transpose(1, 2).contiguous().reshape(-1, rows.shape[1])


def main() -> None:
    args = parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    random.seed(args.seed)
    np.random.seed(args.seed)
    torch.manual_seed(args.seed)
    # One thread: the MLP is small, and on 2 cores a second torch thread competes with the simulator.
    torch.set_num_threads(1)

    probe = parallel_env(SUITE)
    space = probe.observation_space("av_0")
    qnet = QNet(space.low, space.high, observation_layout(probe.config), args.hidden)

    env = SerialEnv(args.roads, make_env)
    env.set_seed(args.seed)
    action_spec = env.full_action_spec_unbatched[GROUP, "action"][0]  # one AV's: Categorical(3)

    # Acting: Q-values and the mask of ("agents", "observation"), greedy action, epsilon-greedy within the mask.
    obs_key = (GROUP, "observation")
    policy = TensorDictSequential(
        TensorDictModule(qnet, in_keys=[obs_key], out_keys=[(GROUP, "action_value")]),
        TensorDictModule(qnet.allowed, in_keys=[obs_key], out_keys=[(GROUP, "action_mask")]),
        QValueModule(
            action_value_key=(GROUP, "action_value"),
            out_keys=[(GROUP, "action"), (GROUP, "action_value"), (GROUP, "chosen_action_value")],
            spec=action_spec,
            action_space="categorical",
        ),
    )
    explore = EGreedyModule(
        spec=action_spec,
        eps_init=args.eps_start,
        eps_end=args.eps_end,
        annealing_num_steps=int(args.eps_fraction * args.total_frames),
        action_key=(GROUP, "action"),
        action_mask_key=(GROUP, "action_mask"),
    )
    collector = Collector(
        env,
        TensorDictSequential(policy, explore),
        frames_per_batch=args.frames_per_batch,
        total_frames=args.total_frames,
        auto_register_policy_transforms=False,  # the policy keeps no state between steps: no InitTracker
    )

    # Learning: the same network on one row per AV transition.
    loss = DQNLoss(
        QValueActor(qnet, in_keys=["observation"], spec=action_spec),
        loss_function="smooth_l1",
        delay_value=True,
    )
    loss.make_value_estimator(gamma=args.gamma)  # TD(0) on the n-step transitions (steps_to_next_obs)
    target = HardUpdate(loss, value_network_update_interval=args.target_update)
    optimizer = torch.optim.Adam(loss.parameters(), lr=args.lr)
    # done_keys=["done"]: "done" cuts the n-step windows; ("next", "terminated") then moves with the
    # next observation, so a window that reaches the AV's end is terminal (with the default done keys
    # it would keep the first step's False and bootstrap from the final observation).
    n_step = MultiStepTransform(args.n_step, args.gamma, done_keys=["done"])
    buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(args.buffer_size), batch_size=args.batch_size)

    start = time.perf_counter()
    frames = decisions = updates = 0
    pending = 0.0
    ends = np.zeros(len(OUTCOMES), np.int64)
    for i, data in enumerate(collector):
        frames += data.numel()
        rows = av_rows(data)
        finished = rows["mask"] & rows["next", "done"].squeeze(-1)
        outcome = data["next", GROUP, "info", "outcome"].transpose(1, 2).reshape(rows.shape)
        ends += np.bincount(outcome[finished].long().numpy(), minlength=len(OUTCOMES))
        explore.step(data.numel())
        windows = n_step.inv(rows)
        if windows is None:
            continue
        live = windows[windows["mask"]]  # AVs still driving; a finished AV's rows are padding
        buffer.extend(live)
        decisions += live.numel()
        if len(buffer) < args.learning_starts:
            continue
        pending += live.numel() / args.decisions_per_update
        while pending >= 1:
            pending -= 1
            loss_vals = loss(buffer.sample())
            optimizer.zero_grad()
            loss_vals["loss"].backward()
            nn.utils.clip_grad_norm_(loss.parameters(), args.grad_clip)
            optimizer.step()
            target.step()
            updates += 1
        if (i + 1) % 50 == 0:
            n = max(int(ends.sum()), 1)
            print(
                f"frames {frames:>7}  {time.perf_counter() - start:5.0f} s  decisions {decisions}"
                f"  updates {updates}  eps {explore.eps.item():.3f}  AV episodes {n}  success {ends[1] / n:.3f}"
                f"  crash {ends[2] / n:.3f}  timeout {ends[3] / n:.3f}",
                flush=True,
            )
            ends[:] = 0
    wall = time.perf_counter() - start
    collector.shutdown()

    # Export the Q-network (raw observation -> Q-values, mask inside), batch axis dynamic, then the card.
    policy_file = out / "policy.onnx"
    qnet.eval()
    with warnings.catch_warnings():  # dynamo=False (the TorchScript exporter) warns that it is the legacy one
        warnings.simplefilter("ignore", DeprecationWarning)
        torch.onnx.export(
            qnet,
            (torch.zeros(2, space.shape[0]),),
            str(policy_file),
            input_names=["obs"],
            output_names=["q_values"],
            dynamic_axes={"obs": {0: "n"}, "q_values": {0: "n"}},
            dynamo=False,
        )
    write_card(policy_file, action_repeat=HOLD, suite=SUITE)
    stats = {
        "suite": SUITE,
        "seed": args.seed,
        "frames": frames,
        "decisions": decisions,
        "updates": updates,
        "threads": 1,
        "train_wall_s": round(wall, 1),
        "args": dataclasses.asdict(args),
    }
    (out / "train.json").write_text(json.dumps(stats, indent=1) + "\n")
    print(
        f"wrote {policy_file} (policy card inside: action_repeat {HOLD}, suite {SUITE}): {frames} road "
        f"steps, {decisions} AV decisions, {updates} updates in {wall / 60:.1f} min, torch 1 thread"
    )


if __name__ == "__main__":
    main()
