"""Train d3rlpy's DiscreteCQL on our Minari dataset and write its ONNX policy with its policy card.

    pip install -e '.[data,onnx]' 'd3rlpy>=2.8,<2.9' torch==2.13.0     # one venv (d3rlpy pins gymnasium 1.0.0)
    python examples/d3rlpy_cql.py --steps 20000 --seed 0 --out runs/d3rlpy-cql
    overtakezoo eval --suite table1 --policy runs/d3rlpy-cql/policy.onnx

The dataset is the official medium one, ``overtakezoo/table1/rule-fsm-v0`` (rule-fsm with epsilon
0.1 on table1-train), read with Minari from ``$MINARI_DATASETS_PATH`` (else ``$OVERTAKEZOO_HOME/
datasets``, else Minari's ``~/.minari/datasets``); when it is not there it is fetched as
``overtakezoo dataset download`` does (from the registry's mirrors, else rebuilt from its recipe and
verified). Its episodes become one ``d3rlpy.dataset.MDPDataset`` of raw observations (the env's
observation vector, standardised inside the policy by d3rlpy's ``StandardObservationScaler``).

One transition is one simulator step (0.1 s): the dataset records a decider that decides every
step, so the card written into ``policy.onnx`` says ``action_repeat=1`` and ``eval`` asks the policy
every step (README, "Archives and datasets"). d3rlpy's own ``save_policy("policy.onnx")`` exports
the greedy policy: int64 argmax actions (one per row) for a fixed batch of 1 (input ``(1, 34)``,
output ``(1,)``), which ``eval`` runs row by row. Torch runs at one thread.
"""

from __future__ import annotations

import argparse
import functools
import json
import time
from pathlib import Path
from unittest import mock

import numpy as np

DATASET = "overtakezoo/table1/rule-fsm-v0"
SUITE = "table1-train"  # the suite the dataset was recorded on: the card's observation contract
HOLD = 1  # one transition per simulator step

# zoo/hyperparams/cql.toml's values where d3rlpy has the same knob (chosen on table1-train, not table1);
# alpha at d3rlpy's default 1.0, where our own cql stays close to the data's behaviour.
HYPERPARAMS = dict(learning_rate=3e-4, batch_size=256, gamma=0.995, alpha=1.0, target_update_interval=1000)
HIDDEN = [128, 128]


def load_dataset(name: str, fetch: bool = True):
    """The Minari dataset ``name`` from our datasets folder, fetched (or rebuilt) first if missing."""
    from overtakezoo.benchmark.datasets import store

    if fetch and not (store.datasets_dir() / name).is_dir():
        from overtakezoo.benchmark.datasets.fetch import download

        download(name, progress=False, say=print)
    return store.load(name)


def to_mdp_dataset(dataset):
    """Every episode of a Minari dataset as one ``d3rlpy.dataset.MDPDataset``: each episode's T steps
    (its observations without the final one), terminal at its last step if it terminated (crash or
    success), timeout if it was truncated (rule-fsm-v0 has none)."""
    import d3rlpy

    obs, act, rew, term, tout = [], [], [], [], []
    for e in dataset.iterate_episodes():
        n = len(e.actions)
        obs.append(np.asarray(e.observations, np.float32)[:n])
        act.append(np.asarray(e.actions, np.int64))
        rew.append(np.asarray(e.rewards, np.float32))
        end_t, end_tr = np.zeros(n, np.float32), np.zeros(n, np.float32)
        end_t[-1] = float(e.terminations[-1])
        end_tr[-1] = float(e.truncations[-1] and not e.terminations[-1])
        term.append(end_t)
        tout.append(end_tr)
    return d3rlpy.dataset.MDPDataset(
        observations=np.concatenate(obs),
        actions=np.concatenate(act),
        rewards=np.concatenate(rew),
        terminals=np.concatenate(term),
        timeouts=np.concatenate(tout),
        action_space=d3rlpy.constants.ActionSpace.DISCRETE,
        action_size=int(dataset.action_space.n),
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20_000, help="gradient steps to train for")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--dataset", default=DATASET)
    parser.add_argument("--out", default=".", help="folder for policy.onnx, train.json and d3rlpy's logs")
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    args = parser.parse_args(argv)

    import d3rlpy
    import torch

    from overtakezoo.benchmark.run.artifacts import write_card

    torch.set_num_threads(args.threads)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    d3rlpy.seed(args.seed)

    data = to_mdp_dataset(load_dataset(args.dataset))
    cql = d3rlpy.algos.DiscreteCQLConfig(
        **HYPERPARAMS,
        encoder_factory=d3rlpy.models.VectorEncoderFactory(hidden_units=HIDDEN),
        observation_scaler=d3rlpy.preprocessing.StandardObservationScaler(),
    ).create(device="cpu:0")
    wall, cpu = time.perf_counter(), time.process_time()
    cql.fit(
        data,
        n_steps=args.steps,
        n_steps_per_epoch=min(args.steps, 10_000),
        show_progress=False,
        save_interval=10**9,
        experiment_name="cql",
        with_timestamp=False,
        logger_adapter=d3rlpy.logging.FileAdapterFactory(root_dir=str(out / "d3rlpy_logs")),
    )
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    policy = out / "policy.onnx"
    # d3rlpy's own export (greedy int64 actions). d3rlpy 2.8.1 hands torch.onnx.export a traced
    # ScriptFunction, which torch >= 2.9's default exporter (dynamo=True) refuses: ask for the
    # TorchScript-based exporter for this call only.
    with mock.patch.object(torch.onnx, "export", functools.partial(torch.onnx.export, dynamo=False)):
        cql.save_policy(str(policy))
    write_card(policy, action_repeat=HOLD, suite=SUITE, name="d3rlpy-cql")  # into the ONNX metadata
    stats = {
        "dataset": args.dataset,
        "transitions": int(data.transition_count),
        "steps": args.steps,
        "seed": args.seed,
        "threads": args.threads,
        "d3rlpy": d3rlpy.__version__,
        "hyperparams": {**HYPERPARAMS, "hidden": HIDDEN},
        "train_wall_s": round(wall, 1),
        "train_cpu_s": round(cpu, 1),
        "steps_per_s": round(args.steps / wall, 1),
    }
    (out / "train.json").write_text(json.dumps(stats, indent=1) + "\n")
    print(
        f"wrote {policy} (card inside): {args.steps} gradient steps on {stats['transitions']} transitions in "
        f"{wall / 60:.1f} min ({cpu / 60:.1f} CPU min, {stats['steps_per_s']} steps/s, torch {args.threads} thread(s))"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
