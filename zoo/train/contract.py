"""The trainer contract: what every zoo trainer (:mod:`.dqn`, :mod:`.ppo`, :mod:`.bc`, :mod:`.cql`;
:mod:`.fastppo`, ppo-numpy, a trainer of its own: :data:`TRAINERS`) reads and writes, written once.

A trainer takes what it learns from already loaded (suites, from
``overtakezoo.benchmark.suite_groups.load_training``, or a dataset's transitions, :mod:`.offline`) and returns a
:class:`Trained`; it never imports the benchmark. ``overtakezoo.benchmark.run.training`` loads the
suites or the dataset, calls the trainer, evaluates what it returns with the benchmark runner and
writes the results file (``overtakezoo train`` is that).

1. **Hyperparameters**: ``zoo/hyperparams/<member>.toml``, typed by the trainer's schema dataclass
   (:mod:`.typed`). :func:`load_hyperparams` is the one reader: the file (with its ``base``, another
   file of ``zoo/hyperparams``, resolved as a suite's is: :func:`read_hyperparams`) with
   ``overrides`` merged (``--set``, :func:`parse_overrides`), the env's reward refused (every
   trainer learns from the suite's ``RewardConfig``), a schema's own ``check(hp, where)`` applied
   (ppo checks rsl-rl's keys); anything wrong is one :class:`~.typed.HyperparameterError` naming ``file: key``.
2. **The model card**: :func:`model_card` builds the keys every card has; ``card.schema.json`` (a
   JSON Schema) says what each one means and :func:`check_card` holds every card written to it
   (the tests hold every shipped card in ``zoo/pretrained`` to it too).
3. **The outputs**: :func:`finish` exports the trained network to the numpy format the zoo loads
   (:mod:`.export`) and :func:`write_outputs` writes ``<name>.pt`` (the torch weights, where the
   trainer has them: dqn, ppo), ``<name>.npz`` and the card ``<name>.json`` into the run directory.
"""

from __future__ import annotations

import dataclasses
import json
import tomllib
from collections.abc import Mapping
from functools import lru_cache
from pathlib import Path
from typing import Any, TypeVar

from overtakezoo.envs.config import ConfigError
from overtakezoo.envs.io import atomic_write_bytes, atomic_write_json
from overtakezoo.envs.suites import merged, resolve_base
from overtakezoo.zoo.members.features import FEATURES_VERSION
from overtakezoo.zoo.members.learned import MASK_VERSION, MLPDecider, sha256_bytes
from overtakezoo.zoo.members.mlp import NumpyMLP
from overtakezoo.zoo.train.typed import HyperparameterError, as_dict, build

HYPERPARAMS = Path(__file__).resolve().parents[1] / "hyperparams"
CARD_SCHEMA = Path(__file__).resolve().with_name("card.schema.json")
T = TypeVar("T")


class TrainError(ConfigError):
    """Bad training input (an unusable checkpoint or dataset, a member that is not trained): one line."""


# What each trainer (its module under zoo/train) writes into the run directory beside the outputs of
# write_outputs (the trainers use these names; `overtakezoo train --help` lists them).
RUN_FILES = {
    "dqn": ("log.csv", "checkpoint.pt"),
    "ppo": ("train_log.csv", "checkpoints/ppo_<iteration>.pt"),
    "bc": (),
    "cql": (),
    "dagger": ("log.csv",),
    "fastppo": ("train_log.csv",),
}
TORCH_WEIGHTS = ("dqn", "ppo")  # trainers whose member is exported from torch weights, <name>.pt
# Trainers with a name of their own, which `overtakezoo train NAME` runs beside the learned members:
# not members (the registry does not list them, nothing ships under the name) and never posing as
# one: the run's files and card are named after the trainer (NAME.npz, NAME.json). NAME -> (its
# module under zoo/train, what it is). One PPO trainer per name: ppo is rsl-rl's, ppo-numpy this one.
TRAINERS: dict[str, tuple[str, str]] = {
    "ppo-numpy": ("fastppo", "PPO in numpy without torch, a policy network like ppo's but not the ppo member"),
}


def run_files(trainer: str, name: str) -> list[str]:
    """Every file trainer module ``trainer`` writes into its run directory for member ``name``: its
    log and checkpoints, then :func:`write_outputs`'s (``<name>.pt`` where it has torch weights,
    ``<name>.npz``, the card ``<name>.json``)."""
    torch = [f"{name}.pt"] if trainer in TORCH_WEIGHTS else []
    return [*RUN_FILES[trainer], *torch, f"{name}.npz", f"{name}.json"]


# ----------------------------------------------------------------------------- hyperparameters
def hyperparams_file(member: str) -> Path:
    """The shipped hyperparameter file of ``member`` (``zoo/hyperparams/<member>.toml``)."""
    return HYPERPARAMS / f"{member}.toml"


def load_hyperparams(schema: type[T], path: str | Path, overrides: Mapping[str, Any] | None = None) -> tuple[T, str]:
    """Schema ``schema`` from the TOML file ``path`` with ``overrides`` merged (tables key by key),
    and the file's name. Errors name ``path: key``."""
    path, overrides = Path(path), overrides or {}
    data = read_hyperparams(path)
    reject_reward_keys(data, f"hyperparameter file {path}")
    reject_reward_keys(overrides, "hyperparameter overrides")
    hp = build(schema, merged(data, overrides), str(path))
    check = getattr(schema, "check", None)
    if check is not None:
        check(hp, str(path))
    return hp, path.name


def read_toml(path: str | Path) -> dict[str, Any]:
    """A TOML file as a dict; one-line :class:`HyperparameterError` when missing or malformed."""
    path = Path(path)
    try:
        return tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise HyperparameterError(f"hyperparameter file {path} not found") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise HyperparameterError(f"{path}: {exc}") from None


def read_hyperparams(path: str | Path) -> dict[str, Any]:
    """A hyperparameter file as a dict, its ``base`` resolved: a file may name another file of
    ``zoo/hyperparams`` (``base = "dqn"``, without ``.toml``) and give only the keys it changes; the
    base's keys come first, its own over them (tables key by key), as a suite's tables over its
    base's (:func:`overtakezoo.envs.suites.resolve_base`)."""
    data = read_toml(path)
    if "base" not in data:
        return data
    data, _ = resolve_base(
        data, str(path), HYPERPARAMS, error=HyperparameterError, what="hyperparameter file of zoo/hyperparams"
    )
    del data["base"]
    return data


def refuse_other_trainers(path: str | Path, name: str, others: Mapping[str, tuple[str, ...]]) -> None:
    """A hyperparameter file of another trainer given to ``overtakezoo train name`` is one
    :class:`TrainError` naming the command that reads it, never a switch of trainer. ``others``: each
    such trainer and the top-level keys only its files have (ppo's [runner], ppo-numpy's [ppo])."""
    data = read_hyperparams(path)
    for other, keys in others.items():
        found = [key for key in keys if key in data]
        if found:
            raise TrainError(
                f"{path} is a hyperparameter file of {other} (its key {found[0]!r}), not of {name}: "
                f"train it with `overtakezoo train {other} --hyperparams {path}`"
            )


def reject_reward_keys(hp: Mapping[str, Any], where: str) -> None:
    """Every trainer learns from the env's reward (``RewardConfig``, set in a suite's ``[sim.reward]``
    table): a hyperparameter that would change it for training only is refused, not ignored."""
    for key in ("reward", "time_penalty"):
        if key in hp:
            raise HyperparameterError(
                f"{where}: {key!r} is not a training setting: every trainer uses the env's "
                "reward (RewardConfig); change it in the suite's [sim.reward] table"
            )


def parse_overrides(items: list[str] | tuple[str, ...], where: str = "--set") -> dict[str, Any]:
    """``["gamma=0.95", "train.steps=1000"]`` -> a nested mapping; each value is read as a TOML value
    (``0.95``, ``[64, 64]``, ``true``, ``"adaptive"``; a bare word is taken as a string)."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise HyperparameterError(f"{where} {item!r}: expected KEY=VALUE")
        try:
            value = tomllib.loads(f"v = {text.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            value = text.strip()
        node = out
        *parents, last = key.split(".")
        for p in parents:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise HyperparameterError(f"{where} {item!r}: {p} is set both as a value and as a table")
        node[last] = value
    return out


# ----------------------------------------------------------------------------- the model card
def suite_source(suites: list[Any], name: str | None = None) -> dict[str, Any]:
    """The card's record of training suites (``name``: the spec they were loaded from)."""
    return {
        "train_suite": {"name": name or "+".join(s.name for s in suites), "suites": {s.name: s.hash for s in suites}},
        "training_reward": dataclasses.asdict(suites[0].config.reward),
    }


def dataset_source(identity: dict[str, Any], config: Any) -> dict[str, Any]:
    """The card's record of a training dataset (its identity, :func:`.offline.Dataset`) and the reward
    of the configuration it was recorded with."""
    return {"dataset": identity, "training_reward": dataclasses.asdict(config.reward)}


def reproduce(name: str, source: dict[str, Any], steps: int, seed: int) -> str:
    """The ``overtakezoo train`` command line that trains the same weights."""
    what = (
        f"--suite {source['train_suite']['name']}"
        if "train_suite" in source
        else f"--dataset {source['dataset']['name']}"
    )
    return f"overtakezoo train {name} {what} --steps {steps} --seed {seed}"


def set_flags(hp: Any, hp_file: str) -> list[str]:
    """The ``--set KEY=VALUE`` flags (shell-quoted, TOML values) that turn the shipped file ``hp_file``
    into ``hp``: what a card's ``reproduce`` line needs besides ``--steps`` and ``--seed``, so that a
    run trained with overrides (e.g. the shipped ppo's ``train.overtake_bias=0``) says so. None for a
    file that is not one of the zoo's (its values are in the card's ``hyperparameters``)."""
    import shlex

    path = HYPERPARAMS / hp_file
    if not path.is_file():
        return []
    try:
        base, _ = load_hyperparams(type(hp), path)
    except (HyperparameterError, ConfigError):
        return []

    def leaves(d: Any, prefix: str = "") -> dict[str, Any]:
        if isinstance(d, dict):
            return {k: v for key, sub in d.items() for k, v in leaves(sub, f"{prefix}{key}.").items()}
        return {prefix[:-1]: d}

    now, was = leaves(as_dict(hp)), leaves(as_dict(base))
    return [
        shlex.quote(f"{key}={json.dumps(value, separators=(',', ':'))}")
        for key, value in sorted(now.items())
        if key.rsplit(".", 1)[-1] not in ("steps", "seed") and was.get(key) != value
    ]


def model_card(
    name: str,
    *,
    algorithm: str,
    architecture: dict[str, Any],
    hp: Any,
    hp_file: str,
    action_repeat: int,
    action_mask: bool,
    source: dict[str, Any],
    steps: int,
    steps_unit: str,
    seed: int,
    wall_time_s: float,
    training: dict[str, Any],
    reproduce: str,
    versions: dict[str, str] | None = None,
    torch: bool = True,
) -> dict[str, Any]:
    """The keys every model card has (``card.schema.json`` says what each means). ``architecture``
    holds ``kind`` (and ``dueling``: how to read a dqn's torch weights); :func:`finish` adds the rest,
    read from the network, and the weights' names and hashes. ``torch``: the trainer trained with
    torch, whose version the card records (all but the numpy ppo, :mod:`.fastppo`)."""
    used = {}
    if torch:
        import torch as _torch

        used["torch"] = _torch.__version__
    if hp_file != f"{name}.toml" and (HYPERPARAMS / hp_file).is_file() and "--hyperparams" not in reproduce:
        reproduce += f" --hyperparams zoo/hyperparams/{hp_file}"
    reproduce += "".join(f" --set {flag}" for flag in set_flags(hp, hp_file) if f" --set {flag}" not in reproduce)
    return {
        "name": name,
        "version": "1",
        "algorithm": algorithm,
        "architecture": dict(architecture),
        "features": FEATURES_VERSION,
        "action_repeat": int(action_repeat),
        "action_mask": bool(action_mask),
        **({"action_mask_version": MASK_VERSION} if action_mask else {}),
        "hyperparameters": {"file": hp_file, **as_dict(hp)},
        **source,
        "steps": int(steps),
        "steps_unit": steps_unit,
        "seed": int(seed),
        "wall_time_s": round(float(wall_time_s), 1),
        "training": training,
        "versions": {**used, **(versions or {})},
        "results": {},
        "reproduce": reproduce,
    }


@lru_cache(maxsize=1)
def _validator() -> Any:
    import jsonschema

    schema = json.loads(CARD_SCHEMA.read_text())
    jsonschema.Draft202012Validator.check_schema(schema)
    return jsonschema.Draft202012Validator(schema)


def card_errors(card: Any) -> list[str]:
    """Where ``card`` departs from ``card.schema.json`` (``path: message``), in a stable order."""

    def message(e: Any) -> str:
        if e.validator == "oneOf" and not e.absolute_path:  # the message would quote the whole card
            return "needs exactly one of train_suite (with training_reward) and dataset"
        return e.message if len(e.message) <= 300 else e.message[:300] + "..."

    errors = sorted(_validator().iter_errors(card), key=lambda e: (list(map(str, e.absolute_path)), e.message))
    return [f"{'.'.join(map(str, e.absolute_path)) or '(card)'}: {message(e)}" for e in errors]


def check_card(card: Any, who: str = "model card") -> None:
    """:class:`ValueError` naming the first departure of ``card`` from ``card.schema.json``."""
    errors = card_errors(card)
    if errors:
        raise ValueError(f"{who}: {errors[0]}" + (f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""))


# ----------------------------------------------------------------------------- outputs
@dataclasses.dataclass
class Trained:
    """What a trainer returns: the model card (naming the ``.npz``), the ``.npz`` bytes, the numpy
    network read from them (what ships and what the benchmark evaluates), the torch weights file
    (``.pt`` bytes; None where the trainer exports the network directly: bc, cql) and the torch
    network itself (in-process callers, tests)."""

    card: dict[str, Any]
    npz: bytes
    net: NumpyMLP
    weights: bytes | None = None
    module: Any = None

    @property
    def name(self) -> str:
        return str(self.card["name"])

    def decider(self, config: Any = None) -> MLPDecider:
        """The member as it ships: the numpy network acting through the card."""
        from overtakezoo.zoo.members.learned import StackedMLPDecider

        cls = StackedMLPDecider if int(self.card.get("frame_stack", 1)) > 1 else MLPDecider
        return cls(self.net, self.name, config, self.card)


def finish(
    card: dict[str, Any], *, weights: bytes | None = None, module: Any = None, out: str | Path | None = None
) -> Trained:
    """The trained network as the zoo loads it: from the torch weights file ``weights`` (dqn, ppo:
    converted by :func:`.export.convert`, the card keeping their sha256 as provenance) or from a
    torch ``module`` of ``nn.Linear`` layers with ReLU between (bc, cql); written into ``out``
    (:func:`write_outputs`) when given."""
    from overtakezoo.zoo.train.export import convert, npz_card

    name = str(card["name"])
    if weights is not None:
        card = {**card, "weights_file": f"{name}.pt", "weights_sha256": sha256_bytes(weights)}
        exported, npz, net = convert(card, weights, name)
    else:
        from overtakezoo.zoo.members.mlp import npz_bytes, read_npz

        linears = [m for m in module.modules() if type(m).__name__ == "Linear"]
        npz = npz_bytes(NumpyMLP.from_linears(linears).arrays())
        net = NumpyMLP.from_arrays(read_npz(npz))  # exactly what the file holds
        exported = npz_card(card, net, npz, name)
    trained = Trained(exported, npz, net, weights, module)
    if out is not None:
        write_outputs(out, trained)
    return trained


def write_outputs(out: str | Path, trained: Trained) -> Path:
    """Write ``<name>.pt`` (if any), ``<name>.npz`` and the card ``<name>.json`` into ``out``, the card
    checked against ``card.schema.json`` first; returns the card's path."""
    out, card = Path(out), trained.card
    check_card(card, f"{trained.name}: model card")
    if trained.weights is not None:
        atomic_write_bytes(out / card["trained_weights_file"], trained.weights)
    atomic_write_bytes(out / card["weights_file"], trained.npz)
    return atomic_write_json(out / f"{trained.name}.json", card)
