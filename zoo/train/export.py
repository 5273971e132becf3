"""Torch weights -> the inference format: ``<name>.npz`` + model card ``<name>.json``.

The torch trainers hold torch weights (dqn / double-dqn / ps-dqn: ``<algo>.pt``, the Q-network's
``state_dict``; ppo: ``ppo.pt``, rsl-rl's actor with its settings) with a model card.
:func:`convert` turns such a pair into what the zoo loads without torch (:mod:`..members.learned`):
the layers as a content-deterministic ``.npz`` (:func:`..members.mlp.npz_bytes`) and the card,
copied, with ``weights_file`` / ``weights_sha256`` now naming the ``.npz`` and the torch file kept
as provenance (``trained_weights_file``, ``trained_weights_sha256``). The trainers call it through
:func:`.contract.finish`, ``overtakezoo eval --policy run/dqn.pt`` on a run's output, and
:func:`export` (``overtakezoo seeds --ship``) on a run directory to publish it into
``zoo/pretrained``. Torch is imported here only to read the ``.pt``.
"""

from __future__ import annotations

import copy
import io
from pathlib import Path
from typing import Any

from overtakezoo.envs.io import atomic_write_bytes, atomic_write_json
from overtakezoo.zoo.members.learned import WeightsError, read_card, read_verified, sha256_bytes
from overtakezoo.zoo.members.mlp import NumpyMLP, npz_bytes

PPO_FORMAT = "overtakezoo-ppo/1"


def trained_sha256(card: dict[str, Any]) -> str | None:
    """The sha256 of the torch weights a card describes (a training card, or one already exported)."""
    return card.get("trained_weights_sha256", card.get("weights_sha256"))


def torch_to_numpy(data: bytes, card: dict[str, Any], who: str = "weights") -> NumpyMLP:
    """The network in torch weights ``data`` (a trainer's ``.pt``) as a :class:`NumpyMLP`."""
    import torch

    try:
        blob = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
        if card.get("name") == "ppo" or (isinstance(blob, dict) and "format" in blob):
            return _ppo_net(blob)
        return dqn_net(blob, card["architecture"].get("dueling", False))
    except WeightsError:
        raise
    except Exception as exc:  # a hash-matching but unusable file: one line, not a traceback
        raise WeightsError(f"{who}: cannot load ({type(exc).__name__}: {exc})") from None


def linear_layers(state: dict[str, Any], prefix: str) -> list[tuple[Any, Any]]:
    """``prefix<i>.weight`` / ``.bias`` in the order of i (an ``nn.Sequential``'s Linear layers);
    KeyError for a weight without its bias."""
    idx = sorted(
        int(k[len(prefix) : -len(".weight")])
        for k in state
        if k.startswith(prefix) and k.endswith(".weight") and k[len(prefix) : -len(".weight")].isdigit()
    )
    return [(state[f"{prefix}{i}.weight"], state[f"{prefix}{i}.bias"]) for i in idx]


def _arrays(layers: list[tuple[Any, Any]]) -> tuple[tuple[Any, Any], ...]:
    return tuple((w.detach().cpu().double().numpy(), b.detach().cpu().double().numpy()) for w, b in layers)


def dqn_net(state: dict[str, Any], dueling: bool) -> NumpyMLP:
    """A ``qlearning.QNetwork`` state_dict: body = [Linear, ReLU]*, head = Linear (value +
    advantages when dueling)."""
    layers = linear_layers(state, "body.") + [(state["head.weight"], state["head.bias"])]
    return NumpyMLP(_arrays(layers), "relu", bool(dueling))


def _ppo_net(blob: dict[str, Any]) -> NumpyMLP:
    # rsl-rl's MLPModel: obs_normalizer, then mlp = [Linear, activation]*, Linear (the logits).
    if blob.get("format") != PPO_FORMAT:
        raise ValueError(f"format {blob.get('format')!r}, expected {PPO_FORMAT!r}")
    cfg = blob["actor_cfg"]
    if cfg.get("obs_normalization"):
        raise WeightsError(
            "ppo: an actor with obs_normalization cannot be exported (the numpy MLP has no "
            "normalizer); train with [actor] obs_normalization = false"
        )
    return NumpyMLP(_arrays(linear_layers(blob["state_dict"], "mlp.")), str(cfg.get("activation", "elu")), False)


def npz_card(card: dict[str, Any], net: NumpyMLP, npz: bytes, name: str) -> dict[str, Any]:
    """``card`` with the architecture read from ``net`` and its weights fields naming the ``.npz``."""
    out = copy.deepcopy(card)
    arch = out.setdefault("architecture", {})
    arch.setdefault("kind", "policy" if name == "ppo" or card.get("name") == "ppo" else "q-network")
    arch.update(
        {
            "obs_dim": net.in_features,
            "num_actions": net.out_features,
            "activation": net.activation,
            "dueling": net.dueling,
            "layers": [list(w.shape) for w, _ in net.layers],
        }
    )
    arch.setdefault("hidden", [int(w.shape[0]) for w, _ in net.layers[:-1]])
    out.update(
        {
            "weights_file": f"{name}.npz",
            "weights_format": "npz (overtakezoo.zoo.members.mlp, float64)",
            "weights_sha256": sha256_bytes(npz),
            "weights_bytes": len(npz),
        }
    )
    return out


def exported_card(card: dict[str, Any], net: NumpyMLP, npz: bytes, name: str) -> dict[str, Any]:
    """``card`` (a training card, naming the torch weights) with its weights fields naming the
    ``.npz`` and the torch file's kept as ``trained_weights_file`` / ``trained_weights_sha256``."""
    out = npz_card(card, net, npz, name)
    out.setdefault("trained_weights_file", card.get("weights_file") or f"{name}.pt")
    out.setdefault("trained_weights_sha256", card.get("weights_sha256"))
    return out


def convert(
    card: dict[str, Any], data: bytes, name: str, who: str | None = None
) -> tuple[dict[str, Any], bytes, NumpyMLP]:
    """Torch weights ``data`` with their training ``card`` -> (the card naming the .npz, the .npz
    bytes, the network): what :func:`export` writes, for a trainer that holds them in memory."""
    net = torch_to_numpy(data, card, who or f"{name}: weights")
    npz = npz_bytes(net.arrays())
    return exported_card(card, net, npz, name), npz, net


def find_card(source: Path, name: str | None = None) -> Path:
    """The model card in a training output directory (``<name>.json`` beside ``<name>.pt``)."""
    if source.is_file():
        return source if source.suffix == ".json" else source.with_suffix(".json")
    if name:
        return source / f"{name}.json"
    cards = sorted(p for p in source.glob("*.json") if p.with_suffix(".pt").is_file())
    if len(cards) != 1:
        raise WeightsError(
            f"{source}: expected one <name>.pt beside its <name>.json, found "
            f"{', '.join(p.stem for p in cards) or 'none'}"
        )
    return cards[0]


def export(
    source: str | Path,
    dest: str | Path | None = None,
    name: str | None = None,
    card_updates: dict[str, Any] | None = None,
) -> Path:
    """Write ``<name>.npz`` + ``<name>.json`` into ``dest`` (default: beside the source) from a
    training output (a directory, its ``<name>.pt`` or its ``<name>.json``); ``card_updates`` are
    set in the card (e.g. a seed selection note). The torch file's sha256 is checked against the
    card first. Returns the path of the card written."""
    card_path = find_card(Path(source), name)
    name = name or card_path.stem
    card = read_card(card_path, name)
    pt = card_path.parent / Path(card.get("trained_weights_file") or f"{name}.pt").name
    data = read_verified(pt, {"weights_sha256": trained_sha256(card)}, name)
    out, npz, _ = convert(card, data, name, f"{name}: weights {pt.name}")
    out.update(card_updates or {})
    dest = Path(dest) if dest is not None else card_path.parent
    atomic_write_bytes(dest / f"{name}.npz", npz)
    atomic_write_json(dest / f"{name}.json", out)
    return dest / f"{name}.json"
