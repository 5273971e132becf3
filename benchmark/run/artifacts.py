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

A file from outside carries a *policy card* (JSON, ``policy_card.schema.json`` beside this module):
its training hold (``action_repeat``) and its observation contract
(``observation_size``, ``observation_layout``), beside a ``.zip`` or TorchScript file
(``<stem>.card.json``) and inside an ONNX file (``metadata_props`` key ``overtakezoo.card``). It is
data, validated when read (:func:`parse_card`), and goes with the converted artifact (the npz's model
card, the ONNX metadata), so that a verifier re-runs with the same hold. :func:`write_card` (and
``overtakezoo card``) writes one.

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
from overtakezoo.benchmark.memory_cap import memory_cap, out_of_memory
from overtakezoo.envs import safe_json

NUM_MODES = 3
SB3_ALGOS = {"dqn": "q-network", "ppo": "policy", "a2c": "policy"}
_SB3_DEFAULT_ACTIVATION = {"dqn": "relu", "ppo": "tanh", "a2c": "tanh"}
_ACTIVATIONS = {"ReLU": "relu", "Tanh": "tanh", "ELU": "elu"}
# An ONNX policy's external data, inlined and stored: this benchmark's networks are KB to a few MB;
# 256 MiB bounds memory.
MAX_ONNX_EXTERNAL_BYTES = 256 << 20
# What a Stable-Baselines3 .zip's members may inflate to (the declared size checked, then enforced while reading).
# policy.pth: an MlpPolicy's float32 weights are ~25 KB at SB3's [64, 64], ~4.5 MB at [1024, 1024];
# 64 MiB bounds memory.
MAX_SB3_STATE_BYTES = 64 << 20
# data: SB3's JSON of hyperparameters with base64 cloudpickles, tens of KB; 16 MiB is far beyond any real one.
MAX_SB3_DATA_BYTES = 16 << 20


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
    policy_card: dict[str, Any] | None = None  # the policy card it came with (parse_card), if any

    @property
    def sha256(self) -> str:
        return hashlib.sha256(self.data).hexdigest()

    @property
    def card_bytes(self) -> bytes | None:
        return None if self.card is None else (json.dumps(self.card, indent=1, sort_keys=True) + "\n").encode()

    @property
    def box_card(self) -> bytes | None:
        """What the sandbox gets beside the bytes: an npz's model card, a TorchScript file's policy card
        (an ONNX file carries its card inside)."""
        if self.kind == "mlp":
            return self.card_bytes
        if self.kind == "torchscript" and self.policy_card is not None:
            return json.dumps(self.policy_card, sort_keys=True).encode()
        return None

    @property
    def ext(self) -> str:
        return {"mlp": ".npz", "onnx": ".onnx", "torchscript": ".pt"}[self.kind]


def read_policy_file(path: Path, data: bytes, config: Any) -> Artifact:
    """The artifact of the policy file ``path`` (holding ``data``); :class:`UserError` when it is none.
    Parsed under a memory cap (benchmark/memory_cap.py): a policy file is an outside file."""
    with memory_cap(f"policy {path}"):
        return _read_policy_file(path, data, config)


def _read_policy_file(path: Path, data: bytes, config: Any) -> Artifact:
    sha = hashlib.sha256(data).hexdigest()
    card_path = model_card(path)
    if card_path is not None:
        return _trained(path, data, card_path, sha)
    beside = card_file(path)
    if path.suffix == ".onnx" or _looks_onnx(data):
        if beside.is_file():
            raise UserError(
                f"policy {path}: the policy card of an ONNX file travels inside it, not beside it "
                f"({beside.name}): run `overtakezoo card {path} --action-repeat N` (and remove "
                f"{beside.name})"
            )
        need("onnxruntime", "onnx", path)
        model = self_contained_onnx(path, data)  # its sha256 covers the external data too
        art = Artifact("onnx", model, None, "onnx", hashlib.sha256(model).hexdigest())
        art.policy_card = onnx_card(model, path)
        check_card(art.policy_card, config, f"policy {path}")
        return art
    if zipfile.is_zipfile(io.BytesIO(data)):
        names = _zip_names(data)
        card = read_card_file(beside, f"policy {path}") if beside.is_file() else None
        check_card(card, config, f"policy {path}")
        if "data" in names and "policy.pth" in names:
            return sb3_to_mlp(path, data, sha, card)
        if any(n.endswith("/constants.pkl") or "/code/" in n for n in names):
            need("torch", "train", path)
            return Artifact("torchscript", data, None, "torchscript", sha, policy_card=card)
    hint = (
        f" (a plain state_dict needs its model card {path.with_suffix('.json').name} beside it, as "
        "`overtakezoo train` writes)"
        if path.suffix in (".pt", ".pth", ".npz")
        else ""
    )
    raise UserError(
        f"policy {path}: not a TorchScript, ONNX or Stable-Baselines3 file, nor weights with a model card{hint}"
    )


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
                raise WeightsError(
                    f"{weights.name}: weights sha256 {sha[:12]}... does not match the model card's "
                    f"{str(card.get('weights_sha256'))[:12]}... (file truncated or modified)"
                )
            return Artifact("mlp", data, card, policy_kind(card), sha)
        # The torch file of a training run, converted as `overtakezoo export` does (weights_only load).
        from overtakezoo.zoo.train.export import convert, trained_sha256

        if trained_sha256(card) != sha:
            raise WeightsError(
                f"{weights.name}: weights sha256 {sha[:12]}... does not match the model card's "
                f"{str(trained_sha256(card))[:12]}... (file truncated or modified)"
            )
        out, npz, _ = convert(card, data, str(card.get("name", weights.stem)), f"weights {weights.name}")
        assert out["weights_sha256"] == sha256_bytes(npz)
        return Artifact("mlp", npz, out, policy_kind(out), sha)
    except ModuleNotFoundError as exc:
        raise UserError(f"policy {weights}: needs {exc.name} (pip install 'overtakezoo[train]')") from None
    except (WeightsError, KeyError, TypeError, ValueError) as exc:
        raise UserError(f"policy {weights}: {exc}") from None


# ------------------------------------------------------------------ Stable-Baselines3
def sb3_to_mlp(path: Path, data: bytes, sha: str, policy_card: dict[str, Any] | None = None) -> Artifact:
    """A Stable-Baselines3 ``.zip`` as the npz MLP, read as data only (module docstring); its policy
    card's hold becomes the npz card's ``action_repeat`` (the card itself is kept as ``policy_card``)."""
    from overtakezoo.zoo.members.mlp import NumpyMLP, npz_bytes

    try:
        with zipfile.ZipFile(io.BytesIO(data)) as z:
            meta = safe_json.loads(zip_member(z, "data", MAX_SB3_DATA_BYTES, f"policy {path}"), "data")
            state_bytes = zip_member(z, "policy.pth", MAX_SB3_STATE_BYTES, f"policy {path}")
    except UserError:
        raise
    except (OSError, KeyError, zipfile.BadZipFile, ValueError, UnicodeDecodeError, EOFError) as exc:
        raise UserError(f"policy {path}: unreadable Stable-Baselines3 file ({exc})") from None
    if not isinstance(meta, dict):
        raise UserError(f"policy {path}: unreadable Stable-Baselines3 file (data is not a JSON object)")
    found = re.search(r"stable_baselines3\.(\w+)\.policies", json.dumps(meta.get("policy_class", {})))
    algo = found.group(1) if found else None
    if algo == "common" and "ActorCriticPolicy.__init__" in json.dumps(meta.get("policy_class", {})):
        algo = "ppo" if "clip_range" in meta else "a2c"  # SB3 >= 2.x: PPO and A2C share common's ActorCriticPolicy
    if algo not in SB3_ALGOS:
        raise UserError(
            f"policy {path}: a Stable-Baselines3 {algo or 'policy of unknown algorithm'}: only "
            f"{', '.join(a.upper() for a in SB3_ALGOS)} with MlpPolicy are read"
        )
    kwargs = meta.get("policy_kwargs") or {}
    kwargs = kwargs if isinstance(kwargs, dict) else {}
    act_name = re.search(r"activation\.(\w+)'", str(kwargs.get("activation_fn", "")))
    activation = _ACTIVATIONS.get(act_name.group(1)) if act_name else _SB3_DEFAULT_ACTIVATION[algo]
    if activation is None:
        raise UserError(
            f"policy {path}: activation {kwargs.get('activation_fn')}: only {', '.join(_ACTIVATIONS)} are read"
        )
    if "features_extractor_class" in kwargs and "FlattenExtractor" not in str(kwargs["features_extractor_class"]):
        raise UserError(
            f"policy {path}: a custom features extractor ({kwargs['features_extractor_class']}) "
            "cannot be read as data; export the policy to ONNX instead"
        )
    from overtakezoo.zoo.train.export import linear_layers

    state = _torch_state(path, state_bytes, "policy.pth")
    try:
        if algo == "dqn":
            layers = linear_layers(state, "q_net.q_net.")
        else:
            layers = linear_layers(state, "mlp_extractor.policy_net.") + [
                (state["action_net.weight"], state["action_net.bias"])
            ]
    except KeyError:
        layers = []
    if not layers:
        raise UserError(
            f"policy {path}: policy.pth lacks the {'q_net' if algo == 'dqn' else 'policy'} layers of an MlpPolicy"
        )
    try:
        net = NumpyMLP(tuple((w.double().numpy(), b.double().numpy()) for w, b in layers), activation)
    except (ValueError, AttributeError, TypeError, RuntimeError) as exc:
        raise UserError(f"policy {path}: policy.pth: {exc}") from None
    if net.out_features != NUM_MODES:
        raise UserError(f"policy {path}: gives {net.out_features} actions, expected Discrete({NUM_MODES})")
    npz = npz_bytes(net.arrays())
    card = {
        "name": f"sb3-{algo}",
        "version": "1",
        "action_repeat": 1,
        "action_mask": False,
        "architecture": {
            "obs_dim": net.in_features,
            "num_actions": NUM_MODES,
            "activation": activation,
            "dueling": False,
            "kind": SB3_ALGOS[algo],
            "layers": [list(w.shape) for w, _ in net.layers],
        },
        "converted_from": {"format": "stable-baselines3", "algorithm": algo.upper(), "sha256": sha},
        "weights_file": "weights.npz",
        "weights_sha256": hashlib.sha256(npz).hexdigest(),
    }
    if policy_card is not None:  # (without one, the card is what it always was: stored rows stay identical)
        card["action_repeat"] = policy_card["action_repeat"]
        card["policy_card"] = policy_card
    return Artifact("mlp", npz, card, "sb3", sha, policy_card=policy_card)


def zip_member(z: zipfile.ZipFile, name: str, cap: int, who: str) -> bytes:
    """The member ``name`` of the zip ``z``, refused (:class:`UserError`) when its declared size is over
    ``cap``, and read through a bounded stream: a member whose data inflates past its declared size (or
    the cap) is refused after ``cap`` + 1 bytes, never inflated whole."""
    info = z.getinfo(name)
    if info.file_size > cap:
        raise UserError(
            f"{who}: {name} declares {info.file_size} bytes uncompressed, at most {cap} are read "
            "(a zip bomb, or not a policy this reads)"
        )
    with z.open(info) as f:
        out = f.read(min(info.file_size, cap) + 1)
    if len(out) > min(info.file_size, cap):
        raise UserError(f"{who}: {name} inflates past its declared {info.file_size} bytes (a zip bomb)")
    return out


def _torch_file_bounded(path: Path, data: bytes, what: str) -> None:
    """:class:`UserError` when ``data`` (a ``torch.save`` file: a zip) holds a compressed record or records
    declaring more than :data:`MAX_SB3_STATE_BYTES` in all: torch's reader would inflate them whole
    (``torch.save`` stores its records uncompressed, so their size is bounded by the file's)."""
    if not zipfile.is_zipfile(io.BytesIO(data)):
        return  # (the legacy pickle format: torch's weights-only reader refuses what is not plain data)
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as z:
            infos = z.infolist()
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
        raise UserError(f"policy {path}: {what} is not a readable torch file ({exc})") from None
    packed = next((i for i in infos if i.compress_type != zipfile.ZIP_STORED), None)
    if packed is not None:
        raise UserError(
            f"policy {path}: {what}: record {packed.filename} is compressed (torch.save stores records "
            "as they are): not a torch.save file"
        )
    if sum(i.file_size for i in infos) > MAX_SB3_STATE_BYTES:
        raise UserError(
            f"policy {path}: {what}: records of {sum(i.file_size for i in infos)} bytes, at most "
            f"{MAX_SB3_STATE_BYTES} are read"
        )


def _torch_why(exc: BaseException) -> str:
    """A one-line reason for a refused torch file, without torch's advice to load it with
    ``weights_only=False`` (which would run the file's code)."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    unpickler = next((ln for ln in lines if ln.startswith("WeightsUnpickler error:")), None)
    if unpickler is not None:
        return unpickler[:200]
    plain = [
        ln for ln in lines if "weights_only" not in ln and "still be loaded" not in ln and "trust the source" not in ln
    ]
    return (plain or [type(exc).__name__])[0][:200]


def _torch_state(path: Path, data: bytes, what: str) -> dict[str, Any]:
    need("torch", "sb3", path)
    _torch_file_bounded(path, data, what)
    import torch

    try:
        state = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    except Exception as exc:  # weights_only refuses anything but tensors and plain containers
        if out_of_memory(exc):
            raise
        raise UserError(f"policy {path}: {what} is not a plain state dict ({_torch_why(exc)})") from None
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
def _check_policy_file(path: Path, data: bytes) -> None:
    """:class:`UserError` when ``data`` cannot be a policy file a card belongs to (an ONNX model, or a
    zip: a Stable-Baselines3 ``.zip``, a TorchScript file): a results file, any other JSON or text."""
    if path.suffix == ".onnx" or _looks_onnx(data) or zipfile.is_zipfile(io.BytesIO(data)):
        return
    doc: Any = None
    if data.lstrip()[:1] == b"{":
        try:
            doc = json.loads(data)
        except (ValueError, RecursionError):
            doc = None
    if isinstance(doc, dict) and (
        str(doc.get("schema", "")).startswith("overtakezoo-results/")
        or {"scenarios", "summary", "decider"} <= doc.keys()
    ):
        raise UserError(
            f"card {path}: a results file (of `overtakezoo eval`), not a policy file: give the policy "
            "file you trained (Stable-Baselines3 .zip, TorchScript .pt, .onnx)"
        )
    what = "a JSON file" if isinstance(doc, (dict, list)) else "not a policy file"
    raise UserError(f"card {path}: {what}: expected a Stable-Baselines3 .zip, a TorchScript file or an ONNX model")


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
        if out_of_memory(exc):
            raise
        raise UserError(f"policy {path}: not a readable ONNX model ({type(exc).__name__})") from None
    unused = _unused_initializers(model)
    if unused:
        raise UserError(
            f"policy {path}: initializer {unused[0]!r} is used by no node ({len(unused)} unused): a "
            "policy file carries only the weights its graph computes with; export it again"
        )
    tensors = [t for t in _all_tensors(model) if uses_external_data(t)]
    if not tensors:
        return data
    base = path.resolve().parent
    total = 0
    for t in tensors:
        info = {e.key: e.value for e in t.external_data}
        loc = PurePosixPath(info.get("location", ""))
        if not loc.parts or loc.is_absolute() or ".." in loc.parts:
            raise UserError(
                f"policy {path}: external data {str(loc)!r} of tensor {t.name!r} is not a file beside the model"
            )
        try:
            offset, length = int(info.get("offset") or 0), int(info["length"]) if info.get("length") else -1
        except ValueError:
            raise UserError(
                f"policy {path}: external data of tensor {t.name!r}: offset/length are not integers"
            ) from None
        chunk = _external_bytes(path, base, loc, t.name, offset, length, MAX_ONNX_EXTERNAL_BYTES - total)
        total += len(chunk)
        t.raw_data = chunk
        del t.external_data[:]
        t.data_location = onnx.TensorProto.DEFAULT
    return model.SerializeToString()


def _external_bytes(
    path: Path, base: Path, loc: PurePosixPath, tensor: str, offset: int, length: int, room: int
) -> bytes:
    """``length`` bytes (-1: to the end) at ``offset`` of the external data file ``loc`` under ``base``:
    a regular file reached from ``base`` without any symlink on the way (each component opened with
    ``O_NOFOLLOW``), inside ``base`` once resolved, and of at most ``room`` bytes; :class:`UserError` otherwise."""
    import os
    import stat

    missing = (
        f"policy {path}: external data {loc} of tensor {tensor!r} is missing, or not a regular file inside "
        "the model's folder reached without a symlink; export with torch.onnx.export(..., external_data=False) "
        "or onnx.save_model(..., save_as_external_data=False)"
    )
    resolved = base.joinpath(*loc.parts).resolve()
    if base.resolve() not in resolved.parents:
        raise UserError(missing)
    fds: list[int] = []
    try:
        fds.append(os.open(base, os.O_RDONLY | os.O_DIRECTORY))
        for part in loc.parts[:-1]:  # a symlinked folder fails here (ELOOP), a file not a folder (ENOTDIR)
            fds.append(os.open(part, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW, dir_fd=fds[-1]))
        fds.append(os.open(loc.parts[-1], os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK, dir_fd=fds[-1]))
        st = os.fstat(fds[-1])
        if not stat.S_ISREG(st.st_mode):  # a FIFO, device or folder
            raise UserError(missing)
        want = st.st_size - offset if length < 0 else length
        if offset < 0 or want < 0 or offset + want > st.st_size:
            raise UserError(
                f"policy {path}: external data {loc} of tensor {tensor!r}: bytes {offset}..{offset + want} "
                f"are not inside the file ({st.st_size} bytes)"
            )
        if want > room:
            raise UserError(
                f"policy {path}: external data of more than {MAX_ONNX_EXTERNAL_BYTES} bytes in all "
                f"(tensor {tensor!r}: {want} bytes): not a policy this reads"
            )
        with os.fdopen(os.dup(fds[-1]), "rb") as f:
            f.seek(offset)
            chunk = f.read(want)
    except OSError:
        raise UserError(missing) from None
    finally:
        for fd in fds:
            os.close(fd)
    if len(chunk) != want:
        raise UserError(f"policy {path}: external data {loc} of tensor {tensor!r}: changed while read")
    return chunk


def _unused_initializers(model: Any) -> list[str]:
    """The initializers (of the graph and its subgraphs) that no node reads and no graph outputs:
    weights the network never computes with have no place in a policy file (they would be stored and
    published with it)."""
    used: set[str] = set()
    inits: list[str] = []
    graphs = [model.graph]
    while graphs:
        g = graphs.pop()
        inits += [t.name for t in g.initializer] + [s.values.name for s in g.sparse_initializer]
        used |= {o.name for o in g.output}
        for node in g.node:
            used |= set(node.input)
            graphs += subgraphs(node)
    return [name for name in inits if name not in used]


def subgraphs(node: Any) -> list[Any]:
    """The graphs an ONNX node carries in its attributes (If branches, Loop and Scan bodies)."""
    import onnx

    out: list[Any] = []
    for attr in node.attribute:
        if attr.type == onnx.AttributeProto.GRAPH:
            out.append(attr.g)
        elif attr.type == onnx.AttributeProto.GRAPHS:
            out.extend(attr.graphs)
    return out


def _all_tensors(model: Any) -> list[Any]:
    from onnx.external_data_helper import _get_all_tensors

    return list(_get_all_tensors(model))


# ------------------------------------------------------------------ policy cards
CARD_KEY = "overtakezoo.card"  # the ONNX metadata_props entry holding the card
CARD_SCHEMA = Path(__file__).with_name("policy_card.schema.json")
MAX_CARD_BYTES = 64 << 10
_CARD_INTS = ("action_repeat", "observation_size")


class CardError(ValueError):
    """A policy card that is not one (``str``: one line)."""


def card_file(path: Path) -> Path:
    """Where the policy card of a ``.zip`` or TorchScript file lies: ``<stem>.card.json`` beside it."""
    return path.with_name(f"{path.stem}.card.json")


def parse_card(raw: bytes | str, where: str = "policy card") -> dict[str, Any]:
    """The policy card in ``raw`` (JSON), validated against ``policy_card.schema.json``; a
    :class:`CardError` (one line naming ``where`` and the key) for anything else. Data only."""
    import jsonschema

    if isinstance(raw, str):
        raw = raw.encode("utf-8", "surrogatepass")
    if len(raw) > MAX_CARD_BYTES:
        raise CardError(f"{where}: {len(raw)} bytes, at most {MAX_CARD_BYTES} (a card is a few lines of JSON)")

    def pairs(items: list[tuple[str, Any]]) -> dict[str, Any]:
        keys = [k for k, _ in items]
        dup = next((k for k in keys if keys.count(k) > 1), None)
        if dup is not None:
            raise CardError(f"{where}: key {dup!r} given twice")
        return dict(items)

    def constant(name: str) -> Any:
        raise CardError(f"{where}: {name} is not a JSON number")

    if safe_json.depth(raw) > safe_json.MAX_JSON_DEPTH:  # before the decoder recurses into it
        raise CardError(
            f"{where}: not JSON (nested {safe_json.depth(raw)} levels deep, at most {safe_json.MAX_JSON_DEPTH})"
        )
    try:
        card = json.loads(raw.decode("utf-8"), object_pairs_hook=pairs, parse_constant=constant)
    except CardError:
        raise
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        why = str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
        raise CardError(f"{where}: not JSON ({why})") from None
    if not isinstance(card, dict):
        raise CardError(f"{where}: expected a JSON object, got {type(card).__name__}")
    errors = sorted(
        jsonschema.Draft202012Validator(_card_schema()).iter_errors(card),
        key=lambda e: (list(e.absolute_path), e.message),
    )
    if errors:
        e = errors[0]
        key = ".".join(str(p) for p in e.absolute_path)
        message = e.message if len(e.message) <= 160 else e.message[:157] + "..."
        if e.validator == "additionalProperties" and not key:
            unknown = sorted(set(card) - set(_card_schema()["properties"]))
            message = f"unknown key {unknown[0]!r} (known: {', '.join(sorted(_card_schema()['properties']))})"
        raise CardError(f"{where}: {key + ': ' if key else ''}{message}")
    for key in _CARD_INTS:  # (JSON Schema counts 10.0 as an integer; a card says 10)
        if key in card and type(card[key]) is not int:
            raise CardError(f"{where}: {key}: {card[key]!r} is not an integer")
    for part, span in (card.get("observation_layout") or {}).items():
        if any(type(v) is not int for v in span) or span[0] > span[1]:
            raise CardError(f"{where}: observation_layout.{part}: {span!r} is not [start, stop] integers")
    return card


_SCHEMA_CACHE: list[dict[str, Any]] = []


def _card_schema() -> dict[str, Any]:
    if not _SCHEMA_CACHE:
        _SCHEMA_CACHE.append(json.loads(CARD_SCHEMA.read_text()))
    return _SCHEMA_CACHE[0]


def read_card_file(path: Path, who: str) -> dict[str, Any]:
    """The policy card in the file ``path`` (:func:`parse_card`); :class:`UserError` otherwise."""
    try:
        if path.is_symlink() or not path.is_file():
            raise UserError(f"{who}: policy card {path.name} is not a regular file")
        with path.open("rb") as f:
            raw = f.read(MAX_CARD_BYTES + 1)
    except OSError as exc:
        raise UserError(f"{who}: cannot read its policy card {path.name} ({exc.strerror or exc})") from None
    try:
        return parse_card(raw, f"policy card {path.name}")
    except CardError as exc:
        raise UserError(f"{who}: {exc}") from None


def card_contract(config: Any) -> dict[str, Any]:
    """The observation contract of ``config`` as a card records it."""
    from overtakezoo.envs import observation_layout, observation_size

    return {
        "observation_size": int(observation_size(config)),
        "observation_layout": {k: [int(s.start), int(s.stop)] for k, s in observation_layout(config).items()},
    }


def check_card(card: dict[str, Any] | None, config: Any, who: str) -> None:
    """:class:`UserError` when ``card``'s observation contract is not ``config``'s."""
    if not card or config is None:
        return
    from overtakezoo.zoo.members.learned import declared_config

    now = card_contract(declared_config(card, config))  # (with the opt-in parts the card says it reads)
    size = card.get("observation_size")
    trained = f" (trained on {card['suite']})" if card.get("suite") else ""
    if size is not None and size != now["observation_size"]:
        raise UserError(
            f"{who}: its policy card's observation_size is {size}{trained}, this suite's observations "
            f"have {now['observation_size']} features (another planner / observation configuration)"
        )
    layout = card.get("observation_layout")
    if layout is not None and layout != now["observation_layout"]:
        part = next(
            (
                k
                for k in [*now["observation_layout"], *sorted(layout)]  # in the observation's order
                if layout.get(k) != now["observation_layout"].get(k)
            ),
            "?",
        )
        raise UserError(
            f"{who}: its policy card's observation_layout.{part} is {layout.get(part)}{trained}, this "
            f"suite's is {now['observation_layout'].get(part)} (another observation layout)"
        )


def onnx_card(model: bytes, path: Path | str) -> dict[str, Any] | None:
    """The policy card inside an ONNX model (``metadata_props`` ``overtakezoo.card``), or None; the
    sandbox reads it again when the ``onnx`` package is missing here."""
    try:
        import onnx
    except ImportError:
        return None
    try:
        props = {p.key: p.value for p in onnx.load_model_from_string(model).metadata_props}
    except Exception as exc:
        if out_of_memory(exc):
            raise
        raise UserError(f"policy {path}: not a readable ONNX model ({type(exc).__name__})") from None
    if CARD_KEY not in props:
        return None
    try:
        card = parse_card(props[CARD_KEY], f"ONNX metadata {CARD_KEY}")
        legacy_repeat(props, card)
    except CardError as exc:
        raise UserError(f"policy {path}: {exc}") from None
    return card


def legacy_repeat(props: dict[str, str], card: dict[str, Any] | None) -> Any:
    """The hold an ONNX model's metadata gives: its card's, else the older entry ``action_repeat``
    (else 1); a :class:`CardError` when both are there and differ."""
    if card is None:
        return props.get("action_repeat", "1")
    old = props.get("action_repeat")
    if old is not None and str(old).strip() != str(card["action_repeat"]):
        raise CardError(
            f"ONNX metadata: action_repeat {old!r} differs from its {CARD_KEY} card's "
            f"{card['action_repeat']} (remove one)"
        )
    return card["action_repeat"]


def write_card(
    path: str | Path,
    action_repeat: int,
    suite: str | None = None,
    *,
    name: str | None = None,
    version: str | None = None,
    observation_size: int | None = None,
) -> Path:
    """Write the policy card of the policy file ``path`` (a Stable-Baselines3 ``.zip``, given with or
    without its suffix as ``model.save`` takes it; a TorchScript file; an ONNX file) and return where it
    went: ``<stem>.card.json`` beside it, or into an ONNX file's metadata (external data untouched).
    ``suite`` (a suite or training mixture): the observation contract is that suite's config's.
    Written atomically; :class:`UserError` for a bad value. E.g. after training with SB3::

        model.save("model")
        write_card("model", action_repeat=10, suite="core-train")
    """
    from overtakezoo.envs.io import atomic_write_bytes

    path = Path(path)
    if not path.exists() and path.with_name(path.name + ".zip").is_file():
        path = path.with_name(path.name + ".zip")  # SB3's model.save("model") writes model.zip
    if not path.is_file():
        raise UserError(f"card {path}: no such policy file")
    if model_card(path) is not None:
        raise UserError(
            f"card {path}: weights of `overtakezoo train`: their model card {model_card(path).name} "
            "already holds the hold and the observation contract"
        )
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise UserError(f"card {path}: cannot read ({exc.strerror or exc})") from None
    _check_policy_file(path, data)
    card: dict[str, Any] = {"card_version": 1, "action_repeat": action_repeat}
    if suite is not None:
        from overtakezoo.benchmark.suite_groups import load_training

        try:
            config = load_training(suite)[0].config
        except Exception as exc:  # SuiteError, ConfigError: one line
            raise UserError(f"card {path}: --suite {suite}: {exc}") from None
        card.update(suite=str(suite), **card_contract(config))
    if observation_size is not None:
        if "observation_size" in card and card["observation_size"] != observation_size:
            raise UserError(
                f"card {path}: observation_size {observation_size} is not suite {suite}'s {card['observation_size']}"
            )
        card["observation_size"] = observation_size
    card.update({k: v for k, v in (("name", name), ("version", version)) if v is not None})
    text = json.dumps(card, indent=1, sort_keys=True) + "\n"
    try:
        parse_card(text, "the card")
    except CardError as exc:
        raise UserError(f"card {path}: {exc}") from None
    if path.suffix == ".onnx" or _looks_onnx(data):
        try:
            import onnx
        except ImportError:
            raise UserError(
                f"card {path}: writing into an ONNX file needs onnx (pip install 'overtakezoo[onnx]')"
            ) from None
        try:
            model = onnx.load_model_from_string(data)  # external data stays where it is (referenced, not read)
        except Exception as exc:
            raise UserError(f"card {path}: not a readable ONNX model ({type(exc).__name__})") from None
        keep = [(p.key, p.value) for p in model.metadata_props if p.key not in (CARD_KEY, "action_repeat")]
        del model.metadata_props[:]
        for key, value in keep + [(CARD_KEY, json.dumps(card, sort_keys=True))]:
            entry = model.metadata_props.add()
            entry.key, entry.value = key, value
        atomic_write_bytes(path, model.SerializeToString())
        return path
    target = card_file(path)
    atomic_write_bytes(target, text.encode())
    return target
