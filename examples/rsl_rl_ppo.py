"""Train PPO with rsl-rl's own OnPolicyRunner on OvertakeZoo, export it with rsl-rl's own exporter,
and write the policy card, so that `overtakezoo eval --policy <out>/policy.onnx` runs it as trained.

    python examples/rsl_rl_ppo.py --iterations 60 --seed 0 --out runs/rsl-ppo
    overtakezoo eval --suite table1 --policy runs/rsl-ppo/policy.onnx

What it sets up (see README, "Guide: rsl-rl"):
- the env: ``OvertakeRslRlEnv`` on the ``table1-train`` suite's scenarios and simulator settings,
  each decision held 10 core steps (1 s at dt = 0.1 s: the zoo's decision hold);
- the policy: rsl-rl's ``MLPModel`` with the zoo's categorical action distribution plugged in
  through ``distribution_cfg["class_name"]`` (rsl-rl ships only Gaussian and Beta ones), the
  observation normalizer inside the model (so the exported file takes the env's raw observation);
- the export: ``OnPolicyRunner.export_policy_to_onnx`` (the argmax mode as a float column), then
  ``write_card(..., action_repeat=10, suite="table1-train")`` writes the hold and the observation
  contract into the ONNX file's metadata.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import torch

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")  # rsl_rl imports GitPython, which wants a git binary
from rsl_rl.runners import OnPolicyRunner  # noqa: E402

from overtakezoo.benchmark.run.artifacts import write_card  # noqa: E402
from overtakezoo.envs.faces.rsl_rl import OvertakeRslRlEnv  # noqa: E402
from overtakezoo.envs.suites import load_suite  # noqa: E402

SUITE = "table1-train"
ACTION_REPEAT = 10  # core steps per decision: 1 s at dt = 0.1 s, as the zoo's learned members

TRAIN_CFG = {
    "num_steps_per_env": 32,
    "save_interval": 50,
    "obs_groups": {"actor": ["policy"], "critic": ["policy"]},
    "algorithm": {
        "class_name": "PPO",
        "num_learning_epochs": 5,
        "num_mini_batches": 4,
        "clip_param": 0.2,
        "gamma": 0.99,
        "lam": 0.95,
        "value_loss_coef": 1.0,
        "entropy_coef": 0.03,
        "learning_rate": 1e-3,
        "max_grad_norm": 1.0,
        "schedule": "adaptive",
        "desired_kl": 0.01,
    },
    "actor": {
        "class_name": "MLPModel",
        "hidden_dims": [128, 128],
        "activation": "elu",
        "obs_normalization": True,
        "distribution_cfg": {
            "class_name": "overtakezoo.zoo.train.categorical:CategoricalDistribution",
            "num_categories": 3,
        },
    },
    "critic": {"class_name": "MLPModel", "hidden_dims": [128, 128], "activation": "elu", "obs_normalization": True},
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--iterations", type=int, default=60, help="PPO iterations (256 x 32 decisions each)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="runs/rsl-ppo", help="directory for policy.onnx (and rsl-rl's files)")
    parser.add_argument("--num-envs", type=int, default=256)
    args = parser.parse_args()

    torch.set_num_threads(1)
    torch.manual_seed(args.seed)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    suite = load_suite(SUITE)
    env = OvertakeRslRlEnv(
        args.num_envs,
        suite.config,
        source=suite.scenarios(),
        seed=args.seed,
        action_repeat=ACTION_REPEAT,
        bootstrap_timeouts=False,
    )  # the 60 s limit is part of the task: a timeout is a failure
    runner = OnPolicyRunner(env, TRAIN_CFG, log_dir=None, device="cpu")

    t0 = time.perf_counter()
    for it in range(args.iterations):
        before = dict(env.episode_counts)
        runner.learn(1)
        runner.current_learning_iteration = it + 1  # learn(1) does not advance it itself
        done = {k: v - before.get(k, 0) for k, v in env.episode_counts.items()}
        eps = max(done.get("episodes", 0), 1)
        print(
            f"iteration {it + 1}/{args.iterations}  {time.perf_counter() - t0:6.0f} s  episodes {eps}  "
            f"success {done.get('success', 0) / eps:.2f}  crash {done.get('crash', 0) / eps:.2f}",
            flush=True,
        )
    print(f"trained {args.iterations} iterations in {(time.perf_counter() - t0) / 60:.1f} min", flush=True)

    runner.export_policy_to_onnx(str(out))  # rsl-rl's own exporter: <out>/policy.onnx
    card = write_card(out / "policy.onnx", action_repeat=ACTION_REPEAT, suite=SUITE)
    print(f"wrote {card} (policy card inside: action_repeat {ACTION_REPEAT}, suite {SUITE})")


if __name__ == "__main__":
    main()
