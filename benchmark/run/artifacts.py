"""Policy files as data: what each format a user brings becomes before anything acts on it.

Two formats are stored on the leaderboard and run by the verifier, both pure data:

- ``mlp``: the project's ``.npz`` MLP (``np.load(allow_pickle=False)``) with its model card
  (JSON), acted by numpy (:mod:`overtakezoo.zoo.members.learned`);
- ``onnx``: one self-contained ONNX file (no external data), acted by onnxruntime.

Everything else is converted, without unpickling anything:

- weights ``overtakezoo train`` wrote (``<algo>.pt`` + card): ``torch.load(weights_only=True)``,
  then the npz MLP (:mod:`overtakezoo.zoo.train.export`);
- a Stable-Baselines3 ``.zip`` (DQN, PPO, A2C ``MlpPolicy``): ``policy.pth`` read with
  ``weights_only=True``, the architecture from ``data`` read as JSON (the ``:serialized:``
  cloudpickle entries are never decoded), into the npz MLP;
- ONNX with external data (``*.onnx.data``): the tensors are inlined from files beside the model
  (never outside its directory), so one sha256 covers everything that runs;
- TorchScript: exported to ONNX inside the sandbox (:mod:`.sandbox`), since loading it runs code.

:func:`read_policy_file` gives the :class:`Artifact` for a file; ``Artifact.data`` is what acts, and
``Artifact.sha256`` its hash.
"""

from __future__ import annotations

import hashlib
import importlib.util
import io
import json
import re
import zipfile
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any

from overtakezoo.benchmark.errors import UserError

NUM_MODES = 3
SB3_ALGOS = {"dqn": "q-network", "ppo": "policy", "a2c": "policy"}
_SB3_DEFAULT_ACTIVATION = {"dqn": "relu", "ppo": "tanh", "a2c": "tanh"}
_ACTIVATIONS = {"ReLU": "relu", "Tanh": "tanh", "ELU": "elu"}


@dataclass
class Artifact:
    """A policy in a stored format. ``kind``: ``mlp`` or ``onnx`` (stored), ``torchscript`` (acts in
    the sandbox for ``eval`` only); ``source``: the user's file (kind as recorded in results, its sha256)."""

    kind: str
    data: bytes
    card: dict[str, Any] | None = None
    source_kind: str = ""
    source_sha256: str = ""
    notes: list[str] = field(default_factory=list)

    @property
    def sha256(self) -> str:
        return hashlib.sha256(self.data).hexdigest()

    @property
    def card_bytes(self) -> bytes | None:
        return None if self.card is None else (json.dumps(self.card, indent=1, sort_keys=True) + "\n").encode()

    @property
    def ext(self) -> str:
        return {"mlp": ".npz", "onnx": ".onnx", "torchscript": ".pt"}[self.kind]


def read_policy_file(path: Path, data: bytes, config: Any) -> Artifact:
    """The artifact of the policy file ``path`` (holding ``data``); :class:`UserError` when it is none."""
    sha = hashlib.sha256(data).hexdigest()
    card_path = model_card(path)
    if card_path is not None:
        return _trained(path, data, card_path, sha)
    if path.suffix == ".onnx" or _looks_onnx(data):
        need("onnxruntime", "onnx", path)
        model = self_contained_onnx(path, data)  # its sha256 covers the external data too
        return Artifact("onnx", model, None, "onnx", hashlib.sha256(model).hexdigest())
    if zipfile.is_zipfile(io.BytesIO(data)):
        names = _zip_names(data)
        if "data" in names and "policy.pth" in names:
            return sb3_to_mlp(path, data, sha)
        if any(n.endswith("/constants.pkl") or "/code/" in n for n in names):
            need("torch", "train", path)
            return Artifact("torchscript", data, None, "torchscript", sha)
    hint = (f" (a plain state_dict needs its model card {path.with_suffix('.json').name} beside it, as "
            "`overtakezoo train` writes)" if path.suffix in (".pt", ".pth", ".npz") else "")
    raise UserError(f"policy {path}: not a TorchScript, ONNX or Stable-Baselines3 file, nor weights with a "
                    f"model card{hint}")


def need(module: str, extra: str, path: Path) -> None:
    """:class:`UserError` naming the extra when ``module`` (which the sandbox will import) is missing."""
    try:
        found = importlib.util.find_spec(module) is not None
    except (ValueError, ImportError):  # e.g. sys.modules[module] is None
        found = False
    if not found:
        raise UserError(f"policy {path}: needs {module} (pip install 'overtakezoo[{extra}]')")


def model_card(path: Path) -> Path | None:
    """The model card of weights in the format `overtakezoo train` writes (<name>.npz or <name>.pt
    beside <name>.json), or None: the file is a policy on its own."""
    card = path.with_suffix(".json")
    return card if path.suffix in (".npz", ".pt", ".pth") and card.is_file() else None


def policy_kind(card: dict[str, Any]) -> str:
    """The results' ``decider.policy.kind`` of an npz MLP, from its card (derived, never declared)."""
    source = card.get("converted_from") or {}
    if source.get("format") == "stable-baselines3":
        return "sb3"
    arch = card.get("architecture") or {}
    return "overtakezoo-ppo" if arch.get("kind") == "policy" or card.get("name") == "ppo" else "overtakezoo-dqn"


# ------------------------------------------------------------------ overtakezoo train output
def _trained(weights: Path, data: bytes, card_path: Path, sha: str) -> Artifact:
    from overtakezoo.zoo.members.learned import WeightsError, read_card, sha256_bytes

    try:
        card = read_card(card_path, weights.name)
        if not isinstance(card, dict) or not isinstance(card.get("architecture"), dict):
            raise UserError(f"policy {weights}: model card {card_path.name} is not one `overtakezoo train` writes")
        if weights.suffix == ".npz":
            if card.get("weights_sha256") != sha:
                raise WeightsError(f"{weights.name}: weights sha256 {sha[:12]}... does not match the model card's "
                                   f"{str(card.get('weights_sha256'))[:12]}... (file truncated or modified)")
            return Artifact("mlp", data, card, policy_kind(card), sha)
        # The torch file of a training run, converted as `overtakezoo export` does (weights_only load).
        from overtakezoo.zoo.train.export import convert, trained_sha256

        if trained_sha256(card) != sha:
            raise WeightsError(f"{weights.name}: weights sha256 {sha[:12]}... does not match the model card's "
                               f"{str(trained_sha256(card))[:12]}... (file truncated or modified)")
        out, npz, _ = convert(card, data, str(card.get("name", weights.stem)), f"weights {weights.name}")
        assert out["weights_sha256"] == sha256_bytes(npz)
        return Artifact("mlp", npz, out, policy_kind(out), sha)
    except ModuleNotFoundError as exc:
        raise UserError(f"policy {weights}: needs {exc.name} (pip install 'overtakezoo[train]')") from None
    except (WeightsError, KeyError, TypeError, ValueError) as exc:
        raise UserError(f"policy {weights}: {exc}") from None


# ------------------------------------------------------------------ Stable-Baselines3
def sb3_to_mlp(path: Path, data: bytes, sha: str) -> Artifact:
    """A Stable-Baselines3 ``.zip`` as the npz MLP, read as data only (module docstring)."""
    from overtakezoo.zoo.members.mlp import NumpyMLP, npz_bytes

    try:
        with zipfile.ZipFile(io.BytesIO(data)) as z:
            meta = json.loads(z.read("data"))
            state_bytes = z.read("policy.pth")
    except (OSError, KeyError, zipfile.BadZipFile, ValueError, UnicodeDecodeError) as exc:
        raise UserError(f"policy {path}: unreadable Stable-Baselines3 file ({exc})") from None
    if not isinstance(meta, dict):
        raise UserError(f"policy {path}: unreadable Stable-Baselines3 file (data is not a JSON object)")
    found = re.search(r"stable_baselines3\.(\w+)\.policies", json.dumps(meta.get("policy_class", {})))
    algo = found.group(1) if found else None
    if algo not in SB3_ALGOS:
        raise UserError(f"policy {path}: a Stable-Baselines3 {algo or 'policy of unknown algorithm'}: only "
                        f"{', '.join(a.upper() for a in SB3_ALGOS)} with MlpPolicy are read")
    kwargs = meta.get("policy_kwargs") or {}
    kwargs = kwargs if isinstance(kwargs, dict) else {}
    act_name = re.search(r"activation\.(\w+)'", str(kwargs.get("activation_fn", "")))
    activation = _ACTIVATIONS.get(act_name.group(1)) if act_name else _SB3_DEFAULT_ACTIVATION[algo]
    if activation is None:
        raise UserError(f"policy {path}: activation {kwargs.get('activation_fn')}: only "
                        f"{', '.join(_ACTIVATIONS)} are read")
    if "features_extractor_class" in kwargs and "FlattenExtractor" not in str(kwargs["features_extractor_class"]):
        raise UserError(f"policy {path}: a custom features extractor ({kwargs['features_extractor_class']}) "
                        "cannot be read as data; export the policy to ONNX instead")
    from overtakezoo.zoo.train.export import linear_layers

    state = _torch_state(path, state_bytes, "policy.pth")
    try:
        if algo == "dqn":
            layers = linear_layers(state, "q_net.q_net.")
        else:
            layers = linear_layers(state, "mlp_extractor.policy_net.") + [(state["action_net.weight"],
                                                                           state["action_net.bias"])]
    except KeyError:
        layers = []
    if not layers:
        raise UserError(f"policy {path}: policy.pth lacks the {'q_net' if algo == 'dqn' else 'policy'} layers of an "
                        "MlpPolicy")
    try:
        net = NumpyMLP(tuple((w.double().numpy(), b.double().numpy()) for w, b in layers), activation)
    except (ValueError, AttributeError, TypeError, RuntimeError) as exc:
        raise UserError(f"policy {path}: policy.pth: {exc}") from None
    if net.out_features != NUM_MODES:
        raise UserError(f"policy {path}: gives {net.out_features} actions, expected Discrete({NUM_MODES})")
    npz = npz_bytes(net.arrays())
    card = {"name": f"sb3-{algo}", "version": "1", "action_repeat": 1, "action_mask": False,
            "architecture": {"obs_dim": net.in_features, "num_actions": NUM_MODES, "activation": activation,
                             "dueling": False, "kind": SB3_ALGOS[algo],
                             "layers": [list(w.shape) for w, _ in net.layers]},
            "converted_from": {"format": "stable-baselines3", "algorithm": algo.upper(), "sha256": sha},
            "weights_file": "weights.npz", "weights_sha256": hashlib.sha256(npz).hexdigest()}
    return Artifact("mlp", npz, card, "sb3", sha)


def _torch_state(path: Path, data: bytes, what: str) -> dict[str, Any]:
    need("torch", "sb3", path)
    import torch

    try:
        state = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    except Exception as exc:  # weights_only refuses anything but tensors and plain containers
        why = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:200]
        raise UserError(f"policy {path}: {what} is not a plain state dict ({why})") from None
    if not isinstance(state, dict):
        raise UserError(f"policy {path}: {what} is not a state dict")
    return state


def _zip_names(data: bytes) -> list[str]:
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as z:
            return z.namelist()
    except (zipfile.BadZipFile, OSError, ValueError):
        return []


# ------------------------------------------------------------------ ONNX
def _looks_onnx(data: bytes) -> bool:
    return data[:1] == b"\x08" and not zipfile.is_zipfile(io.BytesIO(data))  # ModelProto: field 1 (ir_version)


def self_contained_onnx(path: Path, data: bytes) -> bytes:
    """``data`` with every external tensor inlined from a regular file inside the model's directory;
    ``data`` itself when it has none (or when the ``onnx`` package, needed to tell, is missing: the
    sandbox then finds no external file in its empty directory and the load fails)."""
    try:
        import onnx
        from onnx.external_data_helper import uses_external_data
    except ImportError:
        return data
    try:
        model = onnx.load_model_from_string(data)
    except Exception as exc:
        raise UserError(f"policy {path}: not a readable ONNX model ({type(exc).__name__})") from None
    tensors = [t for t in _all_tensors(model) if uses_external_data(t)]
    if not tensors:
        return data
    base = path.resolve().parent
    for t in tensors:
        info = {e.key: e.value for e in t.external_data}
        loc = PurePosixPath(info.get("location", ""))
        if not loc.parts or loc.is_absolute() or ".." in loc.parts:
            raise UserError(f"policy {path}: external data {str(loc)!r} of tensor {t.name!r} is not a file beside "
                            "the model")
        file = base.joinpath(*loc.parts)
        if file.is_symlink() or not file.is_file() or file.resolve().parent != base.joinpath(*loc.parts[:-1]).resolve():
            raise UserError(f"policy {path}: external data {loc} of tensor {t.name!r} is missing (or not a regular "
                            "file); export with torch.onnx.export(..., external_data=False) or onnx.save_model(..., "
                            "save_as_external_data=False)")
        blob = file.read_bytes()
        offset, length = int(info.get("offset", 0) or 0), info.get("length")
        chunk = blob[offset: offset + int(length)] if length else blob[offset:]
        t.raw_data = chunk
        del t.external_data[:]
        t.data_location = onnx.TensorProto.DEFAULT
    return model.SerializeToString()


def _all_tensors(model: Any) -> list[Any]:
    from onnx.external_data_helper import _get_all_tensors

    return list(_get_all_tensors(model))
