"""What the offline-RL trainers (bc, cql) share: a Minari dataset as arrays of transitions, the
dataset's identity for the model card, typed hyperparameter files, and the card itself. Numpy only.

**One transition per simulator step, and the learned decider acts every step (``action_repeat`` =
1).** The datasets record a decider that decides every control cycle (``table1``'s
``decision_interval`` is 1; rule-fsm is a per-tick state machine) with its epsilon-random mode drawn
per decision, i.e. per step. Each recorded step is therefore an exact transition of the per-step
problem: (features of obs[t], the mode applied at t, reward[t], obs[t+1], done). Grouping 10 steps
into one decision held 1 s (what dqn / ppo do) would label each group with one mode although the
recorded mode changes inside 55 % of the 10-step groups (measured on rule-fsm, epsilon 0.1, the
whole table1-train), and behaviour cloning would copy a 10 Hz rule at 1 Hz. A dataset of a decider
that holds its decisions (dqn's 10 steps) is still exact per step; the clone may then switch at any
step. Acting every step costs evaluation little (one numpy MLP pass over the batch per step). The
discount is therefore per 0.1 s (``gamma`` in ``cql.toml``).

A timeout ends the episode as a failure (``timeout_terminal``, as for dqn): the observation has no
clock. The input is the speed-relative features of :mod:`overtakezoo.zoo.features`, computed with
the configuration recorded in the dataset's env spec.
"""

from __future__ import annotations

import dataclasses
import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from overtakezoo.envs import EnvConfig

from .members.features import FEATURES_VERSION, speed_relative

HYPERPARAMS = Path(__file__).resolve().parent / "hyperparams"
T = TypeVar("T")


# ----------------------------------------------------------------------------- hyperparameters
def load_hyperparams(cls: type[T], path: str | Path, overrides: dict[str, Any] | None = None) -> T:
    """Schema ``cls`` (zoo/schema.py) from a TOML file + ``overrides``: an unknown key, a wrong type
    or an out-of-range value is one error naming the file and the key."""
    from .schema import load_hyperparams as load, merged, read_toml

    return load(cls, merged(read_toml(path), overrides or {}), str(path))


# ----------------------------------------------------------------------------- data
@dataclass
class Transitions:
    """Per-step transitions of a dataset, features already computed (float32)."""

    obs: np.ndarray  # (M, D) features of the observation a mode was chosen on
    action: np.ndarray  # (M,) int64 mode applied for the step
    reward: np.ndarray  # (M,) float32
    next_obs: np.ndarray  # (M, D) features of the next observation
    done: np.ndarray  # (M,) float32: the episode ended (a timeout too, with timeout_terminal)
    episode: np.ndarray  # (M,) int64 episode number, for held-out splits
    config: EnvConfig  # the configuration the data was recorded with (observation layout, scales)

    def __len__(self) -> int:
        return len(self.action)


def load_dataset(name: str) -> Any:
    """A Minari dataset by name through ``overtakezoo.benchmark.datasets.load`` (imported here: the
    command layer owns the datasets folder; training is the only caller)."""
    from overtakezoo.benchmark import datasets

    return datasets.load(name)


def transitions(dataset: Any, timeout_terminal: bool = True) -> Transitions:
    """Every step of every episode of a Minari ``dataset`` as a :class:`Transitions`."""
    config = dataset_config(dataset)
    obs, nxt, act, rew, done, ep = [], [], [], [], [], []
    for i, e in enumerate(dataset.iterate_episodes()):  # one slice per episode; features are batched below
        o = np.asarray(e.observations)
        obs.append(o[:-1])
        nxt.append(o[1:])
        act.append(np.asarray(e.actions, np.int64))
        rew.append(np.asarray(e.rewards, np.float32))
        end = np.asarray(e.terminations, bool) | (np.asarray(e.truncations, bool) & timeout_terminal)
        done.append(end.astype(np.float32))
        ep.append(np.full(len(e.actions), i, np.int64))
    if not act:
        raise ValueError("dataset has no episodes")

    def feats(parts: list[np.ndarray]) -> np.ndarray:
        return speed_relative(np.concatenate(parts), config).astype(np.float32)

    return Transitions(feats(obs), np.concatenate(act), np.concatenate(rew), feats(nxt), np.concatenate(done),
                       np.concatenate(ep), config)


def dataset_config(dataset: Any) -> EnvConfig:
    """The env configuration recorded in the dataset's env spec (``overtakezoo dataset build``)."""
    spec = getattr(dataset.spec, "env_spec", None)
    cfg = (getattr(spec, "kwargs", None) or {}).get("config")
    if cfg is None:
        raise ValueError("dataset records no OvertakeZoo env configuration (not built by `overtakezoo dataset build`)")
    return EnvConfig.from_dict(cfg)


def dataset_identity(name: str, dataset: Any, data: Transitions) -> dict[str, Any]:
    """What the model card records about the training data: name, description, and content hashes:
    ``content_sha256`` is the registry's identity (``overtakezoo.benchmark.datasets.content_sha256``:
    the episode arrays and fixed metadata, not the HDF5 bytes); ``transitions_sha256`` hashes the
    arrays trained on."""
    from overtakezoo.benchmark.datasets import content_sha256

    content, kind = content_sha256(dataset), "overtakezoo.benchmark.datasets.content_sha256"
    meta = dict(getattr(dataset.storage, "metadata", {}) or {})
    h = hashlib.sha256()
    for a in (data.obs, data.action, data.reward, data.next_obs, data.done, data.episode):
        h.update(np.ascontiguousarray(a).tobytes())
    return {"name": name, "description": meta.get("description"), "algorithm_name": meta.get("algorithm_name"),
            "episodes": int(dataset.total_episodes), "steps": int(dataset.total_steps),
            "content_sha256": content, "content_hash": kind, "transitions_sha256": h.hexdigest()}


# ----------------------------------------------------------------------------- card
def model_card(name: str, algorithm: str, arrays_sha256: str, hidden: list[int], obs_dim: int, hp: Any,
               identity: dict[str, Any], seed: int, wall_time_s: float, extra: dict[str, Any]) -> dict[str, Any]:
    """The model card of an offline-trained decider (``zoo/pretrained/<name>.json``)."""
    from .members.learned import MASK_VERSION

    return {
        "name": name, "version": "1", "algorithm": algorithm,
        "architecture": {"obs_dim": obs_dim, "hidden": list(hidden), "num_actions": 3, "activation": "relu",
                         "output": "logits" if name == "bc" else "q-values"},
        "features": FEATURES_VERSION, "action_repeat": 1, "action_mask": bool(hp.action_mask),
        "action_mask_version": MASK_VERSION,
        "hyperparameters": dataclasses.asdict(hp), "dataset": identity, "seed": seed,
        "wall_time_s": round(wall_time_s, 1), **extra,
        "weights_file": f"{name}.npz", "weights_sha256": arrays_sha256,
        "results": {},
        "reproduce": f"overtakezoo train {name} --dataset {identity['name']} --seed {seed}",
    }


# ----------------------------------------------------------------------------- train + export
def prepare(name: str, timeout_terminal: bool, out: str | Path | None
            ) -> tuple[Transitions, dict[str, Any], Path | None]:
    """Load dataset ``name`` as transitions, with its identity; check ``out`` is writable first."""
    from overtakezoo.envs.io import check_writable_dir

    out_dir = check_writable_dir(out) if out else None  # fail before training, not after it
    dataset = load_dataset(name)
    data = transitions(dataset, timeout_terminal)
    return data, dataset_identity(name, dataset, data), out_dir


def export(net: Any) -> tuple[bytes, Any]:
    """A trained torch MLP (``nn.Linear`` layers with ReLU between) as ``.npz`` bytes and the
    :class:`NumpyMLP` read back from those bytes, so evaluation here uses exactly what the file holds."""
    from .members.mlp import NumpyMLP, npz_bytes, read_npz

    data = npz_bytes(NumpyMLP.from_linears([m for m in net.modules() if type(m).__name__ == "Linear"]).arrays())
    return data, NumpyMLP.from_arrays(read_npz(data))


def finish(name: str, algorithm: str, net: Any, data: Transitions, hp: Any, identity: dict[str, Any],
           stats: dict[str, Any], out_dir: Path | None, eval_suite: str | None, progress: bool) -> dict[str, Any]:
    """Export ``net``, evaluate it on ``eval_suite`` (the benchmark runner), write ``<name>.npz``,
    ``<name>.json`` and the results file into ``out_dir``; returns the model card."""
    from overtakezoo.envs.io import atomic_write_bytes, atomic_write_json

    from .common import evaluate
    from .members.learned import sha256_bytes
    from .members.learned import MLPDecider

    weights, mlp = export(net)
    wall = float(stats.pop("wall_time_s"))
    card = model_card(name, algorithm, sha256_bytes(weights), hp.hidden, data.obs.shape[1], hp, identity,
                      hp.seed, wall, {"training": stats})
    full = None
    if eval_suite:
        from overtakezoo.envs.suites import load_suite

        suite = load_suite(eval_suite)
        summary, full = evaluate(MLPDecider(mlp, name, suite.config, card), suite, progress=progress)
        card["results"][suite.name] = summary
    if out_dir:
        atomic_write_bytes(out_dir / f"{name}.npz", weights)
        atomic_write_json(out_dir / f"{name}.json", card)
        if full is not None:  # the runner's results file, ready for `overtakezoo submit`
            full.save(out_dir / f"{name}-{eval_suite}.results.json")
    return card
