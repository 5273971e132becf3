"""CleanRL-style PPO on OvertakeZoo in one file: train, export the actor to ONNX, write its policy card.

    python examples/cleanrl_ppo.py --seed 0 --out runs/cleanrl-ppo
    overtakezoo eval --suite table1 --policy runs/cleanrl-ppo/policy.onnx

Written after CleanRL's ``ppo.py`` (hyperparameters in one dataclass, the rollout, GAE and clipped
PPO update inline), for the discrete 3-mode action (follow / overtake / abort) of
``overtakezoo/table1-train-v2``: one env step is one decision held 10 core steps (1 s), and all
``num_envs`` scenarios step in one natively batched core. The exported ``policy.onnx`` maps the
env's raw observation (N, D) to (N, 3) logits (``eval`` takes their argmax); its policy card
(``action_repeat=10``, suite table1-train) goes into the ONNX metadata (README, "Guide: CleanRL-style PPO").
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

import gymnasium as gym
import numpy as np
import torch
import torch.nn as nn
import torch.optim as optim
from torch.distributions.categorical import Categorical

import overtakezoo.envs  # noqa: F401  registers overtakezoo/<suite>-v<version>
from overtakezoo.benchmark.run.artifacts import write_card

SUITE, ENV_ID, HOLD = "table1-train", "overtakezoo/table1-train-v2", 10  # the suite id holds 10 core steps


@dataclass
class Args:
    seed: int = 0
    """seed of random, numpy, torch and the env"""
    out: str = "runs/cleanrl-ppo"
    """folder for policy.onnx and train.json"""
    total_timesteps: int = 491_520
    """decisions to train for (all envs together)"""
    num_envs: int = 256
    """scenarios stepped as one batch"""
    num_steps: int = 32
    """decisions per env per rollout"""
    learning_rate: float = 1e-3
    anneal_lr: bool = True
    gamma: float = 0.99
    gae_lambda: float = 0.95
    num_minibatches: int = 4
    update_epochs: int = 5
    clip_coef: float = 0.2
    ent_coef: float = 0.01
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    hidden: int = 128


def parse_args() -> Args:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    for f in dataclasses.fields(Args):
        kind = (lambda s: s.lower() in ("1", "true", "yes")) if f.type in (bool, "bool") else type(f.default)
        parser.add_argument(f"--{f.name.replace('_', '-')}", type=kind, default=f.default)
    return Args(**vars(parser.parse_args()))


def make_env(args: Args) -> gym.vector.VectorEnv:
    # SAME_STEP autoreset, as CleanRL's loop expects: a finished row restarts in the step that ends it.
    return gym.make_vec(
        ENV_ID,
        num_envs=args.num_envs,
        vectorization_mode="vector_entry_point",
        autoreset_mode=gym.vector.AutoresetMode.SAME_STEP,
    )


def layer_init(layer: nn.Linear, std: float = np.sqrt(2), bias_const: float = 0.0) -> nn.Linear:
    torch.nn.init.orthogonal_(layer.weight, std)
    torch.nn.init.constant_(layer.bias, bias_const)
    return layer


class Agent(nn.Module):
    def __init__(self, space: gym.spaces.Box, n_actions: int, hidden: int) -> None:
        super().__init__()
        # The observation Box has finite bounds: scale each feature to about [-1, 1] inside the
        # model, so the exported actor takes the env's raw observation.
        low, high = torch.as_tensor(space.low), torch.as_tensor(space.high)
        self.register_buffer("center", (high + low) / 2)
        self.register_buffer("scale", ((high - low) / 2).clamp(min=0.5))
        d = space.shape[0]
        self.critic = nn.Sequential(
            layer_init(nn.Linear(d, hidden)),
            nn.Tanh(),
            layer_init(nn.Linear(hidden, hidden)),
            nn.Tanh(),
            layer_init(nn.Linear(hidden, 1), std=1.0),
        )
        self.actor = nn.Sequential(
            layer_init(nn.Linear(d, hidden)),
            nn.Tanh(),
            layer_init(nn.Linear(hidden, hidden)),
            nn.Tanh(),
            layer_init(nn.Linear(hidden, n_actions), std=0.01),
        )

    def norm(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.center) / self.scale

    def get_value(self, x: torch.Tensor) -> torch.Tensor:
        return self.critic(self.norm(x))

    def get_action_and_value(self, x: torch.Tensor, action: torch.Tensor | None = None):
        x = self.norm(x)
        probs = Categorical(logits=self.actor(x))
        if action is None:
            action = probs.sample()
        return action, probs.log_prob(action), probs.entropy(), self.critic(x)

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # what is exported: raw observation -> (N, 3) logits
        return self.actor(self.norm(x))


def main() -> None:
    args = parse_args()
    batch_size = args.num_envs * args.num_steps
    minibatch_size = batch_size // args.num_minibatches
    num_iterations = args.total_timesteps // batch_size
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    random.seed(args.seed)
    np.random.seed(args.seed)
    torch.manual_seed(args.seed)
    # One thread: the MLP is small, so splitting its matmuls over threads costs more in
    # synchronisation than it saves, and on 2 cores a second torch thread competes with the simulator.
    torch.set_num_threads(1)
    device = torch.device("cpu")

    envs = make_env(args)
    agent = Agent(envs.single_observation_space, envs.single_action_space.n, args.hidden).to(device)
    optimizer = optim.Adam(agent.parameters(), lr=args.learning_rate, eps=1e-5)

    obs = torch.zeros((args.num_steps, args.num_envs) + envs.single_observation_space.shape)
    actions = torch.zeros((args.num_steps, args.num_envs), dtype=torch.long)
    logprobs, rewards, dones, values = (torch.zeros((args.num_steps, args.num_envs)) for _ in range(4))

    start = time.perf_counter()
    next_obs, _ = envs.reset(seed=args.seed)
    next_obs, next_done = torch.tensor(next_obs), torch.zeros(args.num_envs)
    for iteration in range(1, num_iterations + 1):
        if args.anneal_lr:
            optimizer.param_groups[0]["lr"] = (1.0 - (iteration - 1.0) / num_iterations) * args.learning_rate
        outcomes = []  # 1 success, 2 crash, 3 timeout, 4 off-road: of the episodes ended in this rollout
        for step in range(args.num_steps):
            obs[step], dones[step] = next_obs, next_done
            with torch.no_grad():
                action, logprob, _, value = agent.get_action_and_value(next_obs)
            actions[step], logprobs[step], values[step] = action, logprob, value.flatten()
            next_obs, reward, terminations, truncations, infos = envs.step(action.numpy())
            # The 60 s limit is part of the task: a timeout ends the episode like a crash does (no bootstrap).
            next_done = torch.tensor(np.logical_or(terminations, truncations), dtype=torch.float32)
            rewards[step] = torch.tensor(reward, dtype=torch.float32)
            next_obs = torch.tensor(next_obs)
            if "final_info" in infos:
                outcomes.extend(infos["final_info"]["outcome"][infos["_final_info"]].tolist())

        with torch.no_grad():  # GAE
            next_value = agent.get_value(next_obs).flatten()
            advantages = torch.zeros_like(rewards)
            lastgaelam = 0
            for t in reversed(range(args.num_steps)):
                nextnonterminal = 1.0 - (next_done if t == args.num_steps - 1 else dones[t + 1])
                nextvalues = next_value if t == args.num_steps - 1 else values[t + 1]
                delta = rewards[t] + args.gamma * nextvalues * nextnonterminal - values[t]
                advantages[t] = lastgaelam = delta + args.gamma * args.gae_lambda * nextnonterminal * lastgaelam
            returns = advantages + values

        b_obs = obs.reshape((-1,) + envs.single_observation_space.shape)
        b_logprobs, b_actions = logprobs.reshape(-1), actions.reshape(-1)
        b_advantages, b_returns, b_values = advantages.reshape(-1), returns.reshape(-1), values.reshape(-1)

        b_inds = np.arange(batch_size)
        for _epoch in range(args.update_epochs):
            np.random.shuffle(b_inds)
            for begin in range(0, batch_size, minibatch_size):
                mb = b_inds[begin : begin + minibatch_size]
                _, newlogprob, entropy, newvalue = agent.get_action_and_value(b_obs[mb], b_actions[mb])
                ratio = (newlogprob - b_logprobs[mb]).exp()
                mb_adv = b_advantages[mb]
                mb_adv = (mb_adv - mb_adv.mean()) / (mb_adv.std() + 1e-8)
                pg_loss = torch.max(
                    -mb_adv * ratio, -mb_adv * torch.clamp(ratio, 1 - args.clip_coef, 1 + args.clip_coef)
                ).mean()
                newvalue = newvalue.view(-1)  # clipped value loss, as CleanRL's default
                v_clipped = b_values[mb] + torch.clamp(newvalue - b_values[mb], -args.clip_coef, args.clip_coef)
                v_loss = 0.5 * torch.max((newvalue - b_returns[mb]) ** 2, (v_clipped - b_returns[mb]) ** 2).mean()
                loss = pg_loss - args.ent_coef * entropy.mean() + v_loss * args.vf_coef
                optimizer.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(agent.parameters(), args.max_grad_norm)
                optimizer.step()

        ends = np.bincount(np.asarray(outcomes, int), minlength=5)
        n = max(len(outcomes), 1)
        print(
            f"iteration {iteration}/{num_iterations}  {time.perf_counter() - start:5.0f} s  episodes {len(outcomes)}"
            f"  success {ends[1] / n:.3f}  crash {ends[2] / n:.3f}  timeout {ends[3] / n:.3f}",
            flush=True,
        )
    wall = time.perf_counter() - start
    envs.close()

    # Export the actor alone (raw observation -> logits), batch axis dynamic, then write the policy card into it.
    policy = out / "policy.onnx"
    agent.eval()
    with warnings.catch_warnings():  # dynamo=False (the TorchScript exporter) warns that it is the legacy one
        warnings.simplefilter("ignore", DeprecationWarning)
        torch.onnx.export(
            agent,
            (torch.zeros(2, envs.single_observation_space.shape[0]),),
            str(policy),
            input_names=["obs"],
            output_names=["logits"],
            dynamic_axes={"obs": {0: "n"}, "logits": {0: "n"}},
            dynamo=False,
        )
    write_card(policy, action_repeat=HOLD, suite=SUITE)
    stats = {
        "env_id": ENV_ID,
        "seed": args.seed,
        "decisions": num_iterations * batch_size,
        "threads": 1,
        "train_wall_s": round(wall, 1),
        "args": dataclasses.asdict(args),
    }
    (out / "train.json").write_text(json.dumps(stats, indent=1) + "\n")
    print(
        f"wrote {policy} (policy card inside: action_repeat {HOLD}, suite {SUITE}): "
        f"{stats['decisions']} decisions in {wall / 60:.1f} min, torch 1 thread"
    )


if __name__ == "__main__":
    main()
