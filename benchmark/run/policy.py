"""Any policy as a decider: ``load_policy(spec, config)`` behind ``eval`` / ``decision-map --policy``.

A SPEC is one of:

- a zoo registry name (``rule-fsm``, ``dqn``, ...);
- ``package.module:factory``: ``factory(config)`` returns a :class:`~overtakezoo.zoo.Decider`, or any
  object with ``act(obs)`` on a batch (N, D) (and optionally ``reset(mask)``, ``name``,
  ``action_repeat``). This is code you chose to run, in this process; files below are not;
- a file, read as data (:mod:`.artifacts`) and acted in a sandboxed child process (:mod:`.sandbox`):
  - ``<name>.npz`` or ``<name>.pt`` with its model card ``<name>.json`` beside it (or the card
    itself, or the directory holding one such pair): what ``overtakezoo train dqn | double-dqn |
    ppo`` writes (sha256 checked against the card, as for the zoo's own weights; a ``.pt`` is read
    with ``torch.load(weights_only=True)``);
  - an ONNX file (extra ``[onnx]``), external data inlined from beside the model: a network mapping
    float32 observations (N, D) to Q-values or logits (N, 3), argmax taken (or to modes (N,) / (N, 1));
    a model whose batch is fixed to 1 (rsl-rl's ``export_policy_to_onnx``) is run row by row;
  - a Stable-Baselines3 ``.zip`` (DQN, PPO, A2C ``MlpPolicy``; needs torch): its ``policy.pth``
    state dict is read with ``weights_only=True`` and the network acts in numpy; the pickled
    entries of its ``data`` file are never unpickled;
  - a TorchScript file (``torch.jit.save``, the same contract as ONNX; deprecated by torch): it runs
    in the sandbox only.

Each decision is held for the policy's decision rate, its ``action_repeat``: core steps between its
decisions when deployed. For a policy file that is a model card's ``decide_every`` when it has one,
else the *training hold* the file states, the core steps each decision was held in training (a model
card's ``action_repeat``; a file's policy card, beside a ``.zip`` or TorchScript file as
``<stem>.card.json``, inside an ONNX file as metadata ``overtakezoo.card``, :mod:`.artifacts`; else a
TorchScript module's ``action_repeat`` attribute or an ONNX metadata entry ``action_repeat``; else 1:
one env step of a face made from a raw config, not the 10 of ``overtakezoo/Overtake-v1`` and the
suite ids), combined
with the suite's ``decision_interval`` by the runner (:func:`hold_lines` says which, and where it came
from: ``eval`` and ``submit`` print it, and warn about a policy file without a card). A card's
observation contract must be the suite's. A file policy is named
``<file stem>-<first 8 hex of its sha256>`` (never a zoo name), and its results record the kind and
the sha256 of what acts (``decider.policy``, ``decider.weights_sha256``; for ONNX with external data,
of the inlined model). Every expected failure (missing file, corrupted weights, wrong shapes, a
missing optional dependency, a policy that crashes or hangs) is one :class:`UserError`.
"""

from __future__ import annotations

import importlib
import os
import re
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from overtakezoo import zoo
from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.run.artifacts import Artifact, check_card, read_policy_file
from overtakezoo.benchmark.run.sandbox import BadAnswer, PolicyFailure, SandboxedPolicy, check_modes
from overtakezoo.envs import ConfigError, EnvConfig, observation_size, safe_json
from overtakezoo.zoo.members.learned import declared_config

NUM_MODES = 3
FACTORY = re.compile(r"^[A-Za-z_][\w.]*:[A-Za-z_]\w*$")


class PolicyDecider(zoo.Decider):
    """A decider around a batch function ``(N, D) float32 -> (N,) modes`` (a loaded policy)."""

    def __init__(
        self,
        act_batch: Callable[[np.ndarray], np.ndarray],
        name: str,
        config: EnvConfig | None,
        policy: dict[str, Any],
        action_repeat: int = 1,
        version: str = "1",
        weights_sha256: str | None = None,
        inner: Any = None,
    ) -> None:
        super().__init__(config)
        self._act_batch, self.name, self.version, self.policy = act_batch, name, version, policy
        self.action_repeat, self.weights_sha256, self.inner = int(action_repeat), weights_sha256, inner

    def act_batch(self, obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs, np.float32)
        return check_modes(self._act_batch(obs), obs.shape[0])

    def reset(self, mask: np.ndarray | None = None) -> None:
        if hasattr(self.inner, "reset"):
            self.inner.reset(mask)

    def card(self) -> str:
        return (
            f"{self.name}: a {self.policy.get('kind', 'file')} policy loaded from "
            f"{self.policy.get('spec', self.policy.get('file'))}."
        )


def load_policy(spec: str, config: EnvConfig | None = None) -> zoo.Decider:
    """The decider for ``spec`` (module docstring) on ``config``; :class:`UserError` when it cannot be."""
    config = config or EnvConfig()
    spec = str(spec)
    path = Path(spec)
    if path.is_dir() or (path.suffix == ".json" and path.is_file()):
        path = _trained_weights(path)
    if path.is_file():
        return _load_file(path, config)
    if FACTORY.match(spec):
        return _load_factory(spec, config)
    if path.suffix or "/" in spec:
        raise UserError(f"policy {spec}: no such file")
    return load_zoo(spec, config, hint="; or give a policy file (.pt, .onnx, .zip) or package.module:factory")


def load_zoo(
    name: str, config: EnvConfig | None = None, hint: str = "; for a policy file or package.module:factory use --policy"
) -> zoo.Decider:
    """A zoo member by registry name; :class:`UserError` for an unknown name or unusable weights."""
    try:
        return zoo.load(name, config=config)
    except zoo.UnknownDecider as exc:
        raise UserError(f"{exc}{hint}") from None
    except ConfigError as exc:
        raise UserError(f"decider {name!r}: {exc}") from None
    except ValueError as exc:  # WeightsError: the zoo's weights are truncated, modified or unreadable
        raise UserError(str(exc)) from None


# ----------------------------------------------------------------------------- module:factory
def _load_factory(spec: str, config: EnvConfig) -> zoo.Decider:
    module_name, attr = spec.split(":")
    try:
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            # Not installed: resolve it from the current directory, as `python -m` does (cwd first on
            # sys.path, and kept there for the module's own imports).
            if exc.name != module_name.split(".")[0] or os.getcwd() in sys.path:
                raise
            sys.path.insert(0, os.getcwd())
            module = importlib.import_module(module_name)
    except ImportError as exc:
        raise UserError(f"policy {spec}: cannot import {module_name} ({exc})") from None
    factory = getattr(module, attr, None)
    if not callable(factory):
        raise UserError(f"policy {spec}: {module_name} has no callable {attr!r}")
    try:
        obj = factory(config)
    except Exception as exc:  # the author's code: say where it failed, in one line
        raise UserError(f"policy {spec}: {attr}(config) raised {type(exc).__name__}: {exc}") from None
    if isinstance(obj, zoo.Decider):
        obj.policy = {"kind": "module", "spec": spec}
        return obj
    if not callable(getattr(obj, "act", None)):
        raise UserError(f"policy {spec}: {attr}(config) returned {type(obj).__name__}, which has no act(obs)")
    name = str(getattr(obj, "name", "") or attr)
    dec = PolicyDecider(
        obj.act,
        name,
        config,
        {"kind": "module", "spec": spec},
        action_repeat=getattr(obj, "action_repeat", 1),
        version=str(getattr(obj, "version", "1")),
        weights_sha256=getattr(obj, "weights_sha256", None),
        inner=obj,
    )
    dec.hold_from = (
        f"from the action_repeat of {attr}(config)'s {type(obj).__name__}"
        if hasattr(obj, "action_repeat")
        else f"the default: {attr}(config)'s {type(obj).__name__} has no action_repeat"
    )
    dec.privileged = bool(getattr(obj, "privileged", False))
    if dec.privileged:
        dec.bind = obj.bind
    return dec


# ----------------------------------------------------------------------------- files
def _load_file(path: Path, config: EnvConfig) -> zoo.Decider:
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise UserError(f"policy {path}: cannot read ({exc.strerror or exc})") from None
    art = read_policy_file(path, data, config)
    dec = boxed(art, config, str(path), allow_code=True)  # the user's own file, on their request
    # Named and hashed by the user's file (for ONNX with external data: the inlined model, all that runs).
    card = art.policy_card or {}
    dec.name = f"{_slug(card.get('name') or path.stem)}-{art.source_sha256[:8]}"
    dec.version = str(card.get("version", dec.version))
    dec.weights_sha256 = art.source_sha256
    dec.policy = {"kind": art.source_kind, "file": path.name, "sha256": art.source_sha256}
    return dec


def boxed(art: Artifact, config: EnvConfig, who: str, allow_code: bool = False) -> PolicyDecider:
    """The decider acting ``art`` in a sandboxed child (:mod:`.sandbox`), probed on this config's
    observations; :class:`UserError` naming ``who`` when it cannot load or act. ``allow_code``: a
    TorchScript file (the user's own, for ``eval --policy`` or ``submit``'s conversion) may load."""
    config = declared_config(art.card or art.policy_card, config)  # (with the opt-in parts its card reads)
    try:
        box = SandboxedPolicy(art.kind, art.data, config, art.box_card, who, allow_code=allow_code)
    except PolicyFailure as exc:
        raise UserError(f"policy {who}: {exc}") from None
    try:
        repeat = int(box.info.get("action_repeat", 1))
        if repeat < 1:
            raise ValueError
    except (TypeError, ValueError):
        box.close()
        raise UserError(
            f"policy {who}: action_repeat {box.info.get('action_repeat')!r} is not a positive int"
        ) from None
    try:
        check_card(box.info.get("card"), config, f"policy {who}")  # (a stored ONNX file's card is read there)
    except UserError:
        box.close()
        raise
    dec = PolicyDecider(box.act, who, config, {}, action_repeat=repeat, inner=box)
    dec.hold_from, dec.hold_card = _file_hold_from(art, Path(who), repeat)  # (hold_lines says them)
    dec.hold_file = who
    dec.row_state = ()  # a policy file is a function of the observation: the runner may drop finished rows
    _probe(dec, config, who)
    return dec


def _trained_weights(path: Path) -> Path:
    """The weights file of a model card, or of the one card with its .npz in a directory."""
    if path.is_dir():
        cards = sorted(p for p in path.glob("*.json") if p.with_suffix(".npz").is_file())
        if len(cards) != 1:
            raise UserError(
                f"policy {path}: expected one <name>.npz beside its model card <name>.json in the "
                f"directory, found {', '.join(p.stem for p in cards) or 'none'}"
            )
        return cards[0].with_suffix(".npz")
    try:
        weights = safe_json.load_file(path).get("weights_file")
    except (OSError, ValueError, AttributeError):  # (not JSON, too large, nested too deep)
        weights = None
    if not isinstance(weights, str):
        raise UserError(f"policy {path}: not a model card (no weights_file) of `overtakezoo train`")
    target = path.parent / Path(weights).name
    if target.with_suffix(".json") != path:
        raise UserError(f"policy {path}: its weights_file {weights} is not named after the card")
    if not target.is_file():
        raise UserError(f"policy {path}: weights {target.name} not found beside the card")
    return target


def _slug(stem: str) -> str:
    return (re.sub(r"[^A-Za-z0-9._+-]", "-", stem).lstrip("._+-") or "policy")[:48]


def _probe(dec: zoo.Decider, config: EnvConfig, who: str) -> None:
    """Fail at load time, not mid-run, when the policy does not take this suite's observations."""
    d = observation_size(config)
    try:
        dec.act(np.zeros((2, d), np.float32))
    except BadAnswer as exc:  # it took the observations: its output is wrong, not this suite's observations
        dec.inner.close()
        raise UserError(
            f"policy {who}: its output does not give modes: on observations of shape (2, {d}) it {exc}"
        ) from None
    except PolicyFailure as exc:
        dec.inner.close()
        raise UserError(f"policy {who}: does not accept observations of shape (N, {d}): {exc}") from None


# ----------------------------------------------------------------------------- the hold, stated
def _file_hold_from(art: Artifact, path: Path, repeat: int) -> tuple[str, bool]:
    """Where a policy file's hold comes from, in words (``from the policy card model.card.json``),
    and whether a card (a model card or a policy card) states it."""
    from overtakezoo.benchmark.run.artifacts import CARD_KEY, card_file, model_card

    card = art.card or {}
    trained = model_card(path)
    if trained is not None:
        held = card.get("action_repeat", 1)
        every = card.get("decide_every", held)
        rate = f": decide_every {every}, trained at a hold of {held}" if every != held else ""
        return f"from the model card {trained.name}{rate}", True
    if art.policy_card or card.get("policy_card"):
        if art.source_kind == "onnx":
            return f"from the policy card in {path.name} (ONNX metadata {CARD_KEY})", True
        return f"from the policy card {card_file(path).name}", True
    if art.source_kind == "torchscript":
        if repeat != 1:
            return f"from the action_repeat attribute of the TorchScript module {path.name}", False
    elif art.kind == "onnx" and "action_repeat" in _onnx_metadata(art.data):
        return f"from the ONNX metadata entry action_repeat of {path.name}", False
    return f"the default: {path.name} has no policy card", False


def _onnx_metadata(model: bytes) -> dict[str, str]:
    try:
        import onnx

        return {p.key: p.value for p in onnx.load_model_from_string(model).metadata_props}
    except Exception:  # no onnx package here (the sandbox read it), or not readable: nothing said
        return {}


def _decider_hold_from(decider: Any) -> str:
    """Where a zoo decider's (or a wrapper's) decision rate comes from, in words."""
    for d in (decider, getattr(decider, "inner", None)):
        if getattr(d, "hold_from", None):
            return d.hold_from
        card = getattr(d, "model_card", None)
        if isinstance(card, dict) and card:
            name = card.get("name", d.name)
            held = card.get("action_repeat", 1)
            if "decide_every" in card:
                return (
                    f"from {name}'s model card: decide_every {card['decide_every']}, its decision rate when "
                    f"deployed; trained at a hold of {held}"
                )
            return f"from {name}'s model card: action_repeat {held}, its training hold"
    if "action_repeat" in vars(decider) or type(decider).action_repeat != zoo.Decider.action_repeat:
        return f"from {decider.name}'s own action_repeat"
    return f"the default: {decider.name} declares no action_repeat, so it decides every step"


def hold_lines(decider: Any, config: EnvConfig, suite: str | None = None) -> list[str]:
    """What ``eval`` and ``submit`` print on stderr about the hold: ``hold: 10 core steps per decision
    (from the policy card model.card.json)``, and for a policy file without a card a warning (an
    SB3 model trained at the zoo's 1 s scored 81.3 % without its card, 81.8 % with it, silently).
    ``suite``: named in the warning's ``overtakezoo card`` command."""
    from overtakezoo.envs.hold import hold_steps

    repeat = int(getattr(decider, "action_repeat", 1))
    steps = hold_steps(config.decision_interval, repeat)
    how = "" if steps == repeat else f"action_repeat {repeat} at decision_interval {config.decision_interval}, "
    src = _decider_hold_from(decider)
    lines = [f"hold: {steps} core step{'s' if steps != 1 else ''} per decision ({how}{src})"]
    filed = next(
        (d for d in (decider, getattr(decider, "inner", None)) if getattr(d, "hold_card", None) is False), None
    )
    if filed is not None:  # a policy file (or shielded:file) without a card
        file = getattr(filed, "hold_file", None) or filed.name
        lines.append(
            f"warning: policy {file} has no policy card: nothing says how long its decisions were held in "
            f"training, so each is held {steps} core step{'s' if steps != 1 else ''}. If it was trained at "
            'another hold (gymnasium.make("overtakezoo/Overtake-v1") and the suite ids hold 10, the zoo\'s '
            f"1 s), write its card: overtakezoo card {file} --action-repeat 10 --suite {suite or 'SUITE'}"
        )
    return lines
