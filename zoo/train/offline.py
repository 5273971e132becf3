"""What the offline trainers (:mod:`.bc`, :mod:`.cql`) learn from: a recorded dataset as per-step
transitions, and what the model card records of it. Numpy only.

The dataset comes loaded: a Minari dataset, which ``overtakezoo.benchmark.run.training`` reads through
the benchmark's dataset registry (``overtakezoo dataset``), and with it the registry's content hash;
the zoo reads no dataset folder itself.

**One transition per simulator step, and the offline members act every step (``action_repeat`` =
1; dqn, double-dqn, ps-dqn and ppo hold each decision 10 steps).** The datasets record a decider
that decides every control cycle (``table1``'s ``decision_interval`` is 1; rule-fsm is a per-tick
state machine) with its epsilon-random mode drawn per decision, i.e. per step. Each recorded step is
therefore an exact transition of the per-step problem: (features of obs[t], the mode applied at t,
reward[t], obs[t+1], done). Grouping 10 steps into one decision held 1 s (what dqn / ppo do) would
label each group with one mode although the recorded mode changes inside 55 % of the 10-step groups
(measured on rule-fsm, epsilon 0.1, the whole table1-train), and behaviour cloning would copy a
10 Hz rule at 1 Hz. A dataset of a decider that holds its decisions (dqn's 10 steps) is still exact
per step; the clone may then switch at any step. Acting every step costs evaluation little (one
numpy MLP pass over the batch per step). The discount is therefore per 0.1 s (``gamma`` in
``cql.toml``).

A timeout ends the episode as a failure (``timeout_terminal``, as for dqn): the observation has no
clock. The input is the speed-relative features of :mod:`overtakezoo.zoo.members.features`,
computed with the configuration recorded in the dataset's env spec.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from overtakezoo.envs import EnvConfig
from overtakezoo.envs.io import check_writable_dir
from overtakezoo.zoo.members.features import speed_relative
from overtakezoo.zoo.train.contract import (
    Trained,
    TrainError,
    dataset_source,
    finish,
    hyperparams_file,
    load_hyperparams,
    model_card,
    reproduce,
)


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
        raise TrainError("dataset has no episodes")

    def feats(parts: list[np.ndarray]) -> np.ndarray:
        return speed_relative(np.concatenate(parts), config).astype(np.float32)

    return Transitions(
        feats(obs),
        np.concatenate(act),
        np.concatenate(rew),
        feats(nxt),
        np.concatenate(done),
        np.concatenate(ep),
        config,
    )


def dataset_config(dataset: Any) -> EnvConfig:
    """The env configuration recorded in the dataset's env spec (``overtakezoo dataset build``)."""
    spec = getattr(dataset.spec, "env_spec", None)
    cfg = (getattr(spec, "kwargs", None) or {}).get("config")
    if cfg is None:
        raise TrainError("dataset records no OvertakeZoo env configuration (not built by `overtakezoo dataset build`)")
    return EnvConfig.from_dict(cfg)


def identity(dataset: Any, data: Transitions, about: dict[str, Any]) -> dict[str, Any]:
    """What the model card records about the training data: ``about`` (from the caller, which knows
    the dataset registry: ``name``, ``content_sha256``, the registry's identity of the content, and
    ``content_hash``, the function that computes it), the dataset's description and size, and
    ``transitions_sha256``, a hash of the arrays trained on."""
    meta = dict(getattr(dataset.storage, "metadata", {}) or {})
    h = hashlib.sha256()
    for a in (data.obs, data.action, data.reward, data.next_obs, data.done, data.episode):
        h.update(np.ascontiguousarray(a).tobytes())
    return {
        "name": about["name"],
        "description": meta.get("description"),
        "algorithm_name": meta.get("algorithm_name"),
        "episodes": int(dataset.total_episodes),
        "steps": int(dataset.total_steps),
        "content_sha256": about["content_sha256"],
        "content_hash": about["content_hash"],
        "transitions_sha256": h.hexdigest(),
    }


def train_offline(
    member: str,
    schema: type[Any],
    fit: Callable[..., tuple[Any, dict[str, Any]]],
    algorithm: str,
    kind: str,
    dataset: Any,
    about: dict[str, Any],
    *,
    steps: int | None,
    seed: int | None,
    out: str | Path | None,
    resume: str | Path | None,
    hyperparams: str | Path | None,
    overrides: dict[str, Any] | None,
    progress: bool,
) -> Trained:
    """What bc and cql do around their ``fit(data, hp, progress) -> (net, stats)``: the
    hyperparameters (``seed`` and ``steps`` override the file), the transitions, the model card
    and the outputs (:func:`.contract.finish`)."""
    if resume:
        raise TrainError(f"{member} keeps no checkpoint (it trains in minutes): run it again without --resume")
    out_dir = check_writable_dir(out) if out else None  # fail before training, not after it
    given = {k: v for k, v in {"seed": seed, "steps": steps}.items() if v is not None}
    hp, hp_file = load_hyperparams(schema, hyperparams or hyperparams_file(member), {**(overrides or {}), **given})
    data = transitions(dataset, hp.timeout_terminal)
    net, stats = fit(data, hp, progress)
    stats = dict(stats)
    wall = float(stats.pop("wall_time_s"))
    source = dataset_source(identity(dataset, data, about), data.config)
    card = model_card(
        member,
        algorithm=algorithm,
        architecture={"kind": kind},
        hp=hp,
        hp_file=hp_file,
        action_repeat=1,
        action_mask=hp.action_mask,
        source=source,
        steps=hp.steps,
        steps_unit="gradient steps",
        seed=hp.seed,
        wall_time_s=wall,
        training=stats,
        reproduce=reproduce(member, source, hp.steps, hp.seed),
    )
    return finish(card, module=net, out=out_dir)


def progress_bar(total: int, desc: str, progress: bool) -> Any:
    """A tqdm bar over ``total`` gradient steps, or None."""
    if not progress:
        return None
    from tqdm import tqdm

    return tqdm(total=total, unit="step", desc=desc, dynamic_ncols=True, mininterval=1.0)
