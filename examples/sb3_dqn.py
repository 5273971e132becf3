"""Train Stable-Baselines3 DQN on the table1 training suite and write its policy card.

    python examples/sb3_dqn.py --steps 60000 --seed 0 --out runs/sb3-dqn
    overtakezoo eval --suite table1 --policy runs/sb3-dqn/model.zip

One env step of ``overtakezoo/table1-train-v2`` is one decision held 10 core steps (1 s), so the
card written beside ``model.zip`` says ``action_repeat=10`` and ``eval`` holds each decision the
same 10 steps. Torch runs at one thread: on this small MLP SB3 DQN is several times faster so
(README, "Guide: Stable-Baselines3"). Needs ``pip install -e '.[sb3]'``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import gymnasium as gym
import torch

import overtakezoo.envs  # noqa: F401  registers overtakezoo/<suite>-v<version>
from overtakezoo.benchmark.run.artifacts import write_card

SUITE = "table1-train"
ENV_ID = "overtakezoo/table1-train-v2"
HOLD = 10  # the suite id's hold_steps: one decision held 10 core steps

# Chosen on table1-train episodes only (never on table1).
HYPERPARAMS = dict(
    learning_rate=5e-4,
    buffer_size=100_000,
    learning_starts=2_000,
    batch_size=64,
    gamma=0.99,
    train_freq=4,
    gradient_steps=1,
    target_update_interval=1_000,
    exploration_fraction=0.3,
    exploration_final_eps=0.02,
    policy_kwargs=dict(net_arch=[128, 128]),
)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=60_000, help="env steps (decisions) to train for")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=".", help="folder for model.zip, model.card.json, train.json")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (1 is the fast choice here)")
    args = parser.parse_args(argv)

    from stable_baselines3 import DQN

    torch.set_num_threads(args.threads)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    env = gym.make(ENV_ID)
    model = DQN("MlpPolicy", env, seed=args.seed, device="cpu", verbose=0, **HYPERPARAMS)
    wall, cpu = time.perf_counter(), time.process_time()
    model.learn(total_timesteps=args.steps)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    model.save(out / "model")  # writes model.zip
    card = write_card(out / "model", action_repeat=HOLD, suite=SUITE)
    stats = {
        "env_id": ENV_ID,
        "steps": args.steps,
        "seed": args.seed,
        "threads": args.threads,
        "train_wall_s": round(wall, 1),
        "train_cpu_s": round(cpu, 1),
        "steps_per_s": round(args.steps / wall, 1),
    }
    (out / "train.json").write_text(json.dumps(stats, indent=1) + "\n")
    print(
        f"wrote {out / 'model.zip'} and {card}: {args.steps} steps in {wall / 60:.1f} min "
        f"({cpu / 60:.1f} CPU min, {stats['steps_per_s']} steps/s, torch {args.threads} thread(s))"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
