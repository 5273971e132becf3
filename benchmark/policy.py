"""Any policy as a decider: ``load_policy(spec, config)`` behind ``eval`` / ``decision-map --policy``.

A SPEC is one of:

- a zoo registry name (``rule-fsm``, ``dqn``, ...);
- ``package.module:factory``: ``factory(config)`` returns a :class:`~overtakezoo.zoo.Decider`, or any
  object with ``act(obs)`` on a batch (N, D) (and optionally ``reset(mask)``, ``name``,
  ``action_repeat``);
- a file:
  - ``<name>.npz`` or ``<name>.pt`` with its model card ``<name>.json`` beside it (or the card
    itself, or the directory holding one such pair): what ``overtakezoo train dqn | double-dqn |
    ppo`` writes (sha256 checked against the card, as for the zoo's own weights; the leaderboard
    stores the pair as ``artifacts/<sha256>.npz`` + ``artifacts/<sha256>.json``). The ``.npz`` acts
    through numpy only; a ``.pt`` is read with torch and acts the same way;
  - a TorchScript file (``torch.jit.save``): a module mapping float32 observations (N, D) to
    Q-values or logits (N, 3), argmax taken (or to modes (N,));
  - an ONNX file (extra ``[onnx]``: onnxruntime), the same contract;
  - a Stable-Baselines3 ``.zip`` (extra ``[sb3]``), e.g. trained on ``overtakezoo/Overtake-v0``;
    ``model.predict(obs, deterministic=True)``.

Each decision is held for the policy's ``action_repeat`` (a model card's, a TorchScript module's
``action_repeat`` attribute, an ONNX metadata entry ``action_repeat``; else 1: one env step of the
Gymnasium face) combined with the suite's ``decision_interval`` by the runner. A file policy is named
``<file stem>-<first 8 hex of its sha256>`` (never a zoo name), and its results record the kind and
the file's sha256 (``decider.policy``, ``decider.weights_sha256``). Every expected failure (missing
file, corrupted weights, wrong shapes, a missing optional dependency) is one :class:`UserError`.
"""

from __future__ import annotations

import hashlib
import importlib
import json
import re
import zipfile
from pathlib import Path
from typing import Any, Callable

import numpy as np

from overtakezoo import zoo
from overtakezoo.envs import ConfigError, EnvConfig, observation_size

from .errors import UserError

NUM_MODES = 3
FACTORY = re.compile(r"^[A-Za-z_][\w.]*:[A-Za-z_]\w*$")


class PolicyDecider(zoo.Decider):
    """A decider around a batch function ``(N, D) float32 -> (N,) modes`` (a loaded policy)."""

    def __init__(self, act_batch: Callable[[np.ndarray], np.ndarray], name: str, config: EnvConfig | None,
                 policy: dict[str, Any], action_repeat: int = 1, version: str = "1",
                 weights_sha256: str | None = None, inner: Any = None) -> None:
        super().__init__(config)
        self._act_batch, self.name, self.version, self.policy = act_batch, name, version, policy
        self.action_repeat, self.weights_sha256, self.inner = int(action_repeat), weights_sha256, inner

    def act_batch(self, obs: np.ndarray) -> np.ndarray:
        return np.asarray(self._act_batch(np.asarray(obs, np.float32)), dtype=np.int64).reshape(-1)

    def reset(self, mask: np.ndarray | None = None) -> None:
        if hasattr(self.inner, "reset"):
            self.inner.reset(mask)

    def card(self) -> str:
        return f"{self.name}: a {self.policy['kind']} policy loaded from {self.policy['spec']}."


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


def load_zoo(name: str, config: EnvConfig | None = None, hint: str = "") -> zoo.Decider:
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
    dec = PolicyDecider(obj.act, name, config, {"kind": "module", "spec": spec},
                        action_repeat=getattr(obj, "action_repeat", 1), version=str(getattr(obj, "version", "1")),
                        weights_sha256=getattr(obj, "weights_sha256", None), inner=obj)
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
    sha = hashlib.sha256(data).hexdigest()
    card = model_card(path)
    if card is not None:
        dec = _load_trained(path, card, config)
        kind = dec.policy_kind
    elif path.suffix == ".zip" and _is_sb3(path):
        dec, kind = _load_sb3(path, config), "sb3"
    elif path.suffix == ".onnx":
        dec, kind = _load_onnx(path, data, config), "onnx"
    elif zipfile.is_zipfile(path) and _is_torchscript(path):
        dec, kind = _load_torchscript(path, config), "torchscript"
    else:
        hint = (f" (a plain state_dict needs its model card {path.with_suffix('.json').name} beside it, as "
                "`overtakezoo train` writes)"
                if path.suffix in (".pt", ".pth", ".npz") else "")
        raise UserError(f"policy {path}: not a TorchScript, ONNX or Stable-Baselines3 file, nor weights with a "
                        f"model card{hint}")
    dec.name = f"{_slug(path.stem)}-{sha[:8]}"
    dec.weights_sha256 = sha
    dec.policy = {"kind": kind, "file": path.name, "sha256": sha}
    _probe(dec, config, path)
    return dec


def model_card(path: Path) -> Path | None:
    """The model card of weights in the format `overtakezoo train` writes (<name>.npz or <name>.pt
    beside <name>.json), or None: the file is a policy on its own."""
    card = path.with_suffix(".json")
    return card if path.suffix in (".npz", ".pt", ".pth") and card.is_file() else None


def _trained_weights(path: Path) -> Path:
    """The weights file of a model card, or of the one card with its .npz in a directory."""
    if path.is_dir():
        cards = sorted(p for p in path.glob("*.json") if p.with_suffix(".npz").is_file())
        if len(cards) != 1:
            raise UserError(f"policy {path}: expected one <name>.npz beside its model card <name>.json in the "
                            f"directory, found {', '.join(p.stem for p in cards) or 'none'}")
        return cards[0].with_suffix(".npz")
    try:
        weights = json.loads(path.read_text()).get("weights_file")
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, AttributeError):
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


def _probe(dec: zoo.Decider, config: EnvConfig, path: Path) -> None:
    """Fail at load time, not mid-run, when the policy does not take this suite's observations."""
    d = observation_size(config)
    try:
        modes = dec.act(np.zeros((2, d), np.float32))
    except Exception as exc:
        raise UserError(f"policy {path}: does not accept observations of shape (N, {d}) "
                        f"({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})") from None
    if modes.min() < 0 or modes.max() >= NUM_MODES:
        raise UserError(f"policy {path}: returned mode {int(modes.max())}, expected 0, 1 or 2")


def _argmax(out: Any, path: Path) -> np.ndarray:
    """Q-values or logits (N, 3) -> argmax; modes (N,) as they are."""
    out = np.asarray(out)
    if out.ndim == 2 and out.shape[1] == NUM_MODES:
        return out.argmax(axis=1)
    if out.ndim == 1:
        return out
    raise ValueError(f"output of shape {out.shape}, expected (N, {NUM_MODES}) scores or (N,) modes")


def _load_trained(weights: Path, card_path: Path, config: EnvConfig) -> zoo.Decider:
    """``overtakezoo train`` output: <algo>.npz (numpy) or <algo>.pt (torch) with the model card <algo>.json."""
    from overtakezoo.zoo.common import WeightsError, read_card, read_verified
    from overtakezoo.zoo.learned import MLPDecider, load_weights

    try:
        card = read_card(card_path, weights.name)
        if not isinstance(card.get("architecture"), dict):
            raise UserError(f"policy {weights}: model card {card_path.name} is not one `overtakezoo train` writes")
        name = str(card.get("name", "dqn"))
        if weights.suffix == ".npz":
            net = load_weights(weights, card, weights.name)
        else:  # the torch file of a training run: converted as `export` does (torch needed)
            from overtakezoo.zoo.export import torch_to_numpy, trained_sha256

            data = read_verified(weights, {"weights_sha256": trained_sha256(card)}, weights.name)
            net = torch_to_numpy(data, card, f"weights {weights.name}")
        dec = MLPDecider(net, name, config, card)
        dec.policy_kind = "overtakezoo-ppo" if name == "ppo" else "overtakezoo-dqn"
    except ModuleNotFoundError as exc:
        raise UserError(f"policy {weights}: needs {exc.name} (pip install 'overtakezoo[train]')") from None
    except (WeightsError, KeyError, TypeError) as exc:
        raise UserError(f"policy {weights}: {exc}") from None
    return dec


def _is_torchscript(path: Path) -> bool:
    with zipfile.ZipFile(path) as z:
        return any(n.endswith("/constants.pkl") or "/code/" in n for n in z.namelist())


def _load_torchscript(path: Path, config: EnvConfig) -> zoo.Decider:
    torch = _need("torch", "train", path)
    try:
        module = torch.jit.load(str(path), map_location="cpu").eval()
    except Exception as exc:
        raise UserError(f"policy {path}: cannot load TorchScript ({type(exc).__name__}: "
                        f"{str(exc).splitlines()[0] if str(exc) else ''})") from None

    def act(obs: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return _argmax(module(torch.from_numpy(obs)).numpy(), path)

    return PolicyDecider(act, path.stem, config, {}, action_repeat=int(getattr(module, "action_repeat", 1)))


def _load_onnx(path: Path, data: bytes, config: EnvConfig) -> zoo.Decider:
    ort = _need("onnxruntime", "onnx", path)
    try:
        session = ort.InferenceSession(data, providers=["CPUExecutionProvider"])
    except Exception as exc:
        raise UserError(f"policy {path}: cannot load ONNX ({type(exc).__name__}: "
                        f"{str(exc).splitlines()[0] if str(exc) else ''})") from None
    inp = session.get_inputs()[0].name
    meta = session.get_modelmeta().custom_metadata_map
    try:
        repeat = int(meta.get("action_repeat", 1))
    except ValueError:
        raise UserError(f"policy {path}: metadata action_repeat {meta['action_repeat']!r} is not an int") from None

    def act(obs: np.ndarray) -> np.ndarray:
        return _argmax(session.run(None, {inp: obs})[0], path)

    return PolicyDecider(act, path.stem, config, {}, action_repeat=repeat)


def _is_sb3(path: Path) -> bool:
    with zipfile.ZipFile(path) as z:
        return "data" in z.namelist() and "policy.pth" in z.namelist()


def _load_sb3(path: Path, config: EnvConfig) -> zoo.Decider:
    sb3 = _need("stable_baselines3", "sb3", path)
    try:
        with zipfile.ZipFile(path) as z:
            policy_class = json.loads(z.read("data")).get("policy_class", {})
    except (OSError, zipfile.BadZipFile, json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise UserError(f"policy {path}: unreadable Stable-Baselines3 file ({exc})") from None
    # The algorithm is named by the pickled policy class's module: stable_baselines3.<algo>.policies.
    algo = re.search(r"stable_baselines3\.(\w+)\.policies", json.dumps(policy_class))
    cls = getattr(sb3, algo.group(1).upper(), None) if algo else None
    if cls is None:
        raise UserError(f"policy {path}: cannot tell which Stable-Baselines3 algorithm saved it")
    try:
        model = cls.load(str(path), device="cpu")
    except Exception as exc:
        raise UserError(f"policy {path}: cannot load with {cls.__name__}.load ({type(exc).__name__}: "
                        f"{str(exc).splitlines()[0] if str(exc) else ''})") from None
    d = observation_size(config)
    space = model.observation_space
    if getattr(space, "shape", None) != (d,) or getattr(model.action_space, "n", None) != NUM_MODES:
        raise UserError(f"policy {path}: trained on observations {getattr(space, 'shape', space)} and actions "
                        f"{model.action_space}; this suite gives ({d},) and Discrete(3)")

    def act(obs: np.ndarray) -> np.ndarray:
        return model.predict(obs, deterministic=True)[0]

    return PolicyDecider(act, path.stem, config, {})


def _need(module: str, extra: str, path: Path) -> Any:
    try:
        return importlib.import_module(module)
    except ImportError:
        raise UserError(f"policy {path}: needs {module} (pip install 'overtakezoo[{extra}]')") from None
