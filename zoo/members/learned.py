"""The learned members at inference (dqn, double-dqn, ps-dqn, ppo, bc, cql, dagger): a numpy MLP over the observation.

One decider for every learned member: the network's scores (Q-values for dqn / double-dqn / ps-dqn
/ cql, policy logits for ppo, class logits for bc and dagger) over follow / overtake / abort, argmax over the
modes the action mask allows. No torch here (it is for training only, :mod:`overtakezoo.zoo.train`):
the weights are a ``.npz`` (:mod:`.mlp`) beside a model card ``<name>.json`` that holds the
architecture, the input features, the training hold (``action_repeat``) and the mask, the
provenance and the sha256 of the ``.npz`` (the card's schema: ``zoo/train/card.schema.json``);
loading refuses a file whose hash differs (truncated, modified) with :class:`WeightsError`. Loading
reads local files only. Inference is in float64: float32 scores move by ~1e-6 with the batch's
composition, enough to flip a near-tie argmax; in float64 a result does not depend on how rows happen to be batched.

Two holds, two names. The *training hold* is the core steps each decision was held in training, the
card's ``action_repeat`` (10 for dqn, double-dqn, ps-dqn, ppo and dagger, 1 for bc and cql, whose
datasets hold one transition per step). The *decision rate* (deployed hold) is the core steps between
the member's decisions when deployed, the card's ``decide_every`` where it has one (chosen after
training on the training splits, ``overtakezoo decision-rate``: a value learned for a 1 s hold,
re-read more often, is a receding horizon; dqn's is 1), else its training hold. The decider's
``action_repeat`` attribute is the decision rate (:func:`deployed_repeat`), not the card's
``action_repeat``. The decider only declares it, whoever steps the core
applies the hold (``overtakezoo.envs.hold``: the benchmark runner, the trainers), combined with the
configuration's ``decision_interval``. A card's ``overtake_offset`` is added to the OVERTAKE score
before the argmax: a decision threshold (cost-sensitive classification, Elkan 2001) that makes the
member start an overtake, and keep one going, only with a margin. It is chosen after training on the
training splits (``overtakezoo decision-rate --overtake-offsets``), as dagger's logit offset is.

**Action mask** (a mode-transition rule of the DQN members, the same in training and evaluation):
ABORT is only offered while the current mode is OVERTAKE or ABORT (from follow there is nothing to
abort), and FOLLOW only while the mode is FOLLOW or the ego is back inside its own lane. Out in the
opposite lane the way back is ABORT, which merges only once the lane beside the ego is clear;
FOLLOW there forces the centre rollout at once and cuts into the lead (what the unmasked network
learned to do in its few crashes). Version 3 also carries an abort through: while aborting outside
its lane the ego may not resume the overtake (abort / overtake flip-flops were the next crash cause).
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

import numpy as np

from overtakezoo.envs import ABORT, FOLLOW, OVERTAKE, EnvConfig, observation_layout, observation_size, safe_json
from overtakezoo.envs.model.observation import OPTIONAL_PARTS
from overtakezoo.zoo.base import Decider, member, names, register
from overtakezoo.zoo.members.features import FEATURES_VERSION, speed_relative
from overtakezoo.zoo.members.mlp import NumpyMLP, read_npz

PRETRAINED = Path(__file__).resolve().parents[1] / "pretrained"
NUM_MODES = 3
# The ego is inside its own lane while |y| / lane width is below this (car 1.82 m in a 3.5 m lane).
IN_LANE = 0.25
MASK_VERSION = 3


class WeightsError(ValueError):
    """Pretrained weights are missing, truncated, modified or do not fit the configuration."""


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def declared_config(card: dict[str, Any] | None, config: EnvConfig) -> EnvConfig:
    """``config`` with the opt-in observation parts the card's policy reads on (``OPTIONAL_PARTS``:
    ``v2v``, ``time_left``): a model card's ``"observation": {"v2v": true}`` (``overtakezoo train
    ... --set v2v=true``) or a part of that name in a policy card's ``observation_layout``. The runner
    then turns them on for the road (:func:`read_parts`); the suite's own settings are unchanged."""
    card = card if isinstance(card, dict) else {}
    observation, layout = card.get("observation"), card.get("observation_layout")
    on = {
        part: True
        for part in OPTIONAL_PARTS
        if (isinstance(observation, dict) and observation.get(part) is True)
        or (isinstance(layout, dict) and part in layout)
    }
    return config.with_observation(**on) if on else config


def read_parts(decider: Any) -> dict[str, bool]:
    """The opt-in observation parts ``decider`` (or any decider of a pairing, ``by_av``) reads, as
    ``with_observation`` keywords (``{}``: none)."""
    deciders = getattr(decider, "by_av", None) or [decider]
    observations = [getattr(getattr(d, "config", None), "observation", None) for d in deciders]
    return {part: True for part in OPTIONAL_PARTS if any(getattr(o, part, False) for o in observations)}


def read_card(path: str | Path, who: str) -> dict[str, Any]:
    """A model card (JSON); one-line :class:`WeightsError` when missing or unreadable."""
    path = Path(path)
    try:
        return safe_json.load_file(path, f"model card {path}")  # (bounded: a card may come from outside)
    except FileNotFoundError:
        raise WeightsError(f"{who}: model card {path} not found (no pretrained weights for this decider)") from None
    except safe_json.JSONInputError as exc:
        raise WeightsError(f"{who}: {exc}") from None
    except OSError as exc:
        raise WeightsError(f"{who}: model card {path}: unreadable ({exc})") from None


def read_verified(weights: str | Path, card: dict[str, Any], who: str) -> bytes:
    """The bytes of ``weights`` once their sha256 equals the model card's; else :class:`WeightsError`."""
    weights = Path(weights)
    try:
        data = weights.read_bytes()
    except OSError as exc:
        raise WeightsError(f"{who}: cannot read weights {weights}: {exc.strerror or exc}") from None
    expected, actual = card.get("weights_sha256"), sha256_bytes(data)
    if expected != actual:
        raise WeightsError(
            f"{who}: weights {weights.name} sha256 {actual[:12]}... does not match the model card's "
            f"{str(expected)[:12]}... ({len(data)} bytes; file truncated or modified)"
        )
    return data


def action_mask(obs: np.ndarray, config: EnvConfig, version: int = MASK_VERSION) -> np.ndarray:
    """(N, 3) bool: which modes a row may choose. ABORT only while overtaking or aborting; FOLLOW
    only from FOLLOW or with the ego inside its own lane; (version >= 3) OVERTAKE not while an
    abort is still bringing the ego back to its lane. Reads the observation's (or the
    speed-relative features', which keep these columns) mode one-hot and lateral offset."""
    obs = np.asarray(obs)
    layout = observation_layout(config)
    mode = obs[:, layout["mode"]]
    in_follow, in_abort = mode[:, FOLLOW] > 0.5, mode[:, ABORT] > 0.5
    in_lane = np.abs(obs[:, layout["ego"]][:, 2]) < IN_LANE  # y / lane width
    mask = np.ones((obs.shape[0], NUM_MODES), bool)
    mask[:, ABORT] = ~in_follow
    mask[:, FOLLOW] = in_follow | in_lane
    if version >= 3:
        mask[:, OVERTAKE] = ~in_abort | in_lane
    return mask


def masked_argmax(scores: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    """Row-wise argmax over the allowed modes (the first on ties, as torch's and numpy's argmax)."""
    if mask is not None:
        scores = np.where(mask, scores, -np.inf)
    return np.argmax(scores, axis=1).astype(np.int64)


def load_weights(weights: str | Path, card: dict[str, Any], who: str | None = None) -> NumpyMLP:
    """The network in ``weights`` (.npz) described by ``card``, after checking its sha256."""
    weights, who = Path(weights), who or str(card.get("name", "decider"))
    data = read_verified(weights, card, who)
    arch = card.get("architecture") or {}
    try:
        net = NumpyMLP.from_arrays(read_npz(data), arch.get("activation", "relu"), bool(arch.get("dueling", False)))
    except Exception as exc:  # a hash-matching but unusable file: one line, not a traceback
        raise WeightsError(f"{who}: weights {weights.name}: cannot load ({type(exc).__name__}: {exc})") from None
    if "obs_dim" in arch and net.in_features != arch["obs_dim"]:
        raise WeightsError(
            f"{who}: weights {weights.name} take {net.in_features} features, the model card says {arch['obs_dim']}"
        )
    return net


class MLPDecider(Decider):
    """A learned member: argmax of the network's scores over the allowed modes (each decision held
    ``self.action_repeat`` core steps by the runner: the decision rate, :func:`deployed_repeat`)."""

    privileged = False
    row_state: tuple[str, ...] = ()

    def __init__(
        self, net: NumpyMLP, name: str, config: EnvConfig | None = None, card: dict[str, Any] | None = None
    ) -> None:
        super().__init__(declared_config(card, config or EnvConfig()))
        self.stack = int((card or {}).get("frame_stack", 1))  # decisions of input (StackedMLPDecider)
        if net.in_features != self.stack * observation_size(self.config):
            raise WeightsError(
                f"{name}: network expects {net.in_features} observation features, the configuration "
                f"gives {self.stack} x {observation_size(self.config)} (different planner/observation "
                "settings)"
            )
        if net.out_features != NUM_MODES:
            raise WeightsError(f"{name}: network gives {net.out_features} scores, expected {NUM_MODES}")
        self.net, self.name = net, name
        self.model_card = card = card or {}
        self.weights_sha256 = card.get("weights_sha256")
        self.action_repeat = deployed_repeat(name, card)  # the decision rate, not the card's training hold
        self.overtake_offset = deployed_offset(name, card)
        # The decision rate and threshold are part of the behaviour: results and cross-play tables name them.
        every = "" if self.action_repeat == card.get("action_repeat", 1) else f".every{self.action_repeat}"
        offset = f".overtake{self.overtake_offset:+g}" if self.overtake_offset else ""
        self.version = str(card.get("version", "1")) + every + offset
        self.use_mask = bool(card.get("action_mask", False))
        self.mask_version = int(card.get("action_mask_version", MASK_VERSION))
        self.features = card.get("features")  # None: the raw observation (weights from before the features)
        if self.features not in (None, FEATURES_VERSION):
            raise WeightsError(
                f"{name}: unknown input features {self.features!r} (this version has {FEATURES_VERSION!r})"
            )

    def scores(self, obs: np.ndarray) -> np.ndarray:
        """(N, D) observations -> (N, 3) float64 Q-values (dqn) or logits (ppo)."""
        x = np.asarray(obs, np.float64)
        return self.net(speed_relative(x, self.config) if self.features else x)

    q_values = logits = scores

    def act_batch(self, obs: np.ndarray) -> np.ndarray:
        """Argmax over the allowed modes (stateless: the hold is the runner's)."""
        return self.choose(self.scores(obs), obs)

    def choose(self, scores: np.ndarray, obs: np.ndarray) -> np.ndarray:
        """The mode per row: argmax of ``scores`` with the card's OVERTAKE offset, among the allowed modes."""
        if self.overtake_offset:
            scores = scores.copy()
            scores[:, OVERTAKE] += self.overtake_offset
        mask = action_mask(obs, self.config, self.mask_version) if self.use_mask else None
        return masked_argmax(scores, mask)

    def card(self) -> str:
        return describe(self.name, self.model_card)


def deployed_repeat(name: str, card: dict[str, Any]) -> int:
    """The decision rate (deployed hold), the member's ``action_repeat``: core steps between its
    decisions when deployed, the card's ``decide_every`` (chosen after training on the training splits,
    ``overtakezoo decision-rate``), else its training hold (the card's ``action_repeat``). A
    network with memory reads one observation per decision, so it keeps the rate it was trained at."""
    held = card.get("action_repeat", 1)
    every = card.get("decide_every", held)
    if isinstance(every, bool) or not isinstance(every, int) or not 1 <= every <= 1000:
        raise WeightsError(f"{name}: model card decide_every must be an integer in [1, 1000], got {every!r}")
    if int(card.get("frame_stack", 1)) > 1 and every != held:
        raise WeightsError(
            f"{name}: a frame-stacked network decides at its training hold ({held} steps), not every {every}"
        )
    return every


def deployed_offset(name: str, card: dict[str, Any]) -> float:
    """What the member adds to its OVERTAKE score before the argmax: the card's ``overtake_offset``
    (chosen after training on the training splits), else 0."""
    offset = card.get("overtake_offset", 0.0)
    if isinstance(offset, bool) or not isinstance(offset, (int, float)) or not -50.0 <= offset <= 50.0:
        raise WeightsError(f"{name}: model card overtake_offset must be a number in [-50, 50], got {offset!r}")
    return float(offset)


class StackedMLPDecider(MLPDecider):
    """A learned member with memory: its input is the features of its last ``frame_stack``
    decisions' observations, newest first (zeros before a row's episode began), as it was trained
    (``train dagger --set frame_stack=K``). Each call of :meth:`act_batch` is one decision."""

    row_state = ("history",)

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.history = np.zeros((0, self.stack, observation_size(self.config)))

    def reset(self, mask: np.ndarray | None = None) -> None:
        if mask is None or self.history.shape[0] != len(mask):
            self.history = np.zeros((0 if mask is None else len(mask), *self.history.shape[1:]))
        else:
            self.history[np.asarray(mask, bool)] = 0.0

    def act_batch(self, obs: np.ndarray) -> np.ndarray:
        x = np.asarray(obs, np.float64)
        if self.history.shape[0] != x.shape[0]:
            self.history = np.zeros((x.shape[0], *self.history.shape[1:]))
        self.history = np.concatenate([speed_relative(x, self.config)[:, None], self.history[:, :-1]], axis=1)
        return self.choose(self.net(self.history.reshape(x.shape[0], -1)), obs)


def describe(name: str, c: dict[str, Any]) -> str:
    """The model card (``zoo/train/card.schema.json``) in a few lines."""
    if not c:
        return f"{name}: an untrained network."
    a, hp = c.get("architecture", {}), c.get("hyperparameters", {})
    hidden = a.get("hidden")
    if a.get("kind") == "policy":
        version = (c.get("versions") or {}).get("rsl-rl-lib")
        what = (
            f"{name} ({c.get('algorithm', 'PPO')}{f', rsl-rl-lib {version}' if version else ''}): MLP {hidden} "
            f"{a.get('activation')} actor over the {a.get('obs_dim')}-feature input, categorical over the 3 "
            "modes (argmax at test time)"
        )
    elif a.get("kind") == "classifier":  # bc: a classifier of the recorded modes
        what = (
            f"{name} ({c.get('algorithm', '?')}): MLP {hidden} classifier over the {a.get('obs_dim')}-feature "
            f"input, the most likely mode among those the action mask allows"
        )
    else:
        version = int(c.get("action_mask_version", MASK_VERSION))
        what = (
            f"{name} ({c.get('algorithm', '?')}): MLP {hidden}{' dueling' if a.get('dueling') else ''} "
            f"Q-network over the {a.get('obs_dim')}-feature input"
            + (
                f"; mode-transition mask v{version} (abort only from overtake, follow only from follow or "
                f"in lane{', aborts carried through' if version >= 3 else ''})"
                if c.get("action_mask")
                else ""
            )
        )
    suite = (c.get("train_suite") or {}).get("name", "?")
    if c.get("dataset"):  # offline members (bc, cql) learn from a recorded dataset, not a suite
        ds = c["dataset"]
        trained = (
            f"  trained offline on dataset {ds.get('name', '?')} (content sha256 "
            f"{str(ds.get('content_sha256'))[:12]}), {c.get('steps', '?')} {c.get('steps_unit', 'steps')}, "
            f"seed {c.get('seed', '?')}, {c.get('wall_time_s', 0):.0f} s."
        )
    else:
        trained = (
            f"  trained on {suite}, {c.get('steps', '?')} {c.get('steps_unit', 'steps')}, seed "
            f"{c.get('seed', '?')}, {c.get('wall_time_s', 0):.0f} s wall ({hp.get('file', '?')})."
        )
    held = c.get("action_repeat", 1)
    every = c.get("decide_every", held)
    rate = (
        f"decision held {held} steps"
        if every == held
        else f"decision held {held} steps in training, re-decided every {every} when deployed (chosen on the "
        "training splits)"
    )
    if c.get("overtake_offset"):
        rate += f", {c['overtake_offset']:+g} on the OVERTAKE score (a threshold chosen on the training splits)"
    lines = [f"{what}, {rate}.", trained]
    res = c.get("results", {}).get("table1") or {}
    if res:
        lines.append(
            f"  table1: success {100 * res['success_rate']:.1f} % "
            f"[{100 * res['success_ci'][0]:.1f}, {100 * res['success_ci'][1]:.1f}], crash "
            f"{100 * res['crash_rate']:.1f} % [{100 * res['crash_ci'][0]:.1f}, "
            f"{100 * res['crash_ci'][1]:.1f}] ({res['success']} successes, {res['crash']} crashes "
            f"of {res['count']})."
        )
    lines.append(f"  weights sha256 {str(c.get('weights_sha256'))[:16]}...; reproduce: {c.get('reproduce', '?')}")
    if c.get("selection_note"):
        lines.append(f"  {c['selection_note']}")
    return "\n".join(lines)


def from_card(name: str, card: dict[str, Any], weights: str | Path, config: EnvConfig | None = None) -> MLPDecider:
    cls = StackedMLPDecider if int(card.get("frame_stack", 1)) > 1 else MLPDecider
    return cls(load_weights(weights, card, name), name, config, card)


def load_pretrained(name: str, config: EnvConfig | None = None, directory: str | Path | None = None) -> MLPDecider:
    """The committed ``<name>.json`` and the ``.npz`` it names, from ``zoo/pretrained`` (or ``directory``)."""
    directory = Path(directory) if directory else PRETRAINED
    card = read_card(directory / f"{name}.json", name)
    return from_card(name, card, directory / Path(card.get("weights_file") or f"{name}.npz").name, config)


def _pretrained(name: str) -> Any:
    return lambda config=None, **kw: load_pretrained(name, config, **kw)


for _name in names("learned"):  # the registry lists the learned members; each loads its shipped weights
    if member(_name).module == "learned":  # (a learned decider registered by a plugin keeps its own factory)
        register(_name, _pretrained(_name))
