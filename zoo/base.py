"""The decider interface and the registry every face of the project resolves names through."""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from overtakezoo.envs import ABORT, FOLLOW, OVERTAKE, EnvConfig, observation_layout, observation_size


class ObservationError(ValueError):
    """An observation a decider cannot act on: the wrong shape or width, or a NaN / inf value."""


class Decider:
    """Maps observations to modes: 0 follow, 1 overtake, 2 abort.

    The protocol (every zoo member, and what ``overtakezoo.zoo.testing.check_decider`` checks):

    - ``act(obs)``: one observation (D,) -> a Python ``int``; a batch (N, D) -> an (N,) int64 array
      (an empty batch (0, D) -> an empty one). ``D`` must be ``observation_size(config)`` and every
      value finite (the env's observations always are: an empty slot is zeros, not inf), else
      :class:`ObservationError`; the check is here, once, so ``act_batch`` sees valid input only.
    - ``reset(mask)``: forget per-row state for the rows in ``mask`` (all rows when None); the
      runner calls it when episodes (re)start.
    - ``action_repeat``: core steps each decision was made for (from training); the benchmark runner
      holds every decision that long (``overtakezoo.envs.hold``), so a decider never counts steps.

    Subclasses set ``name`` and ``version`` and implement the batch form, :meth:`act_batch`; the
    single-observation form is derived here. (A subclass that overrides ``act`` itself is taken to
    have written the batch form and is wrapped the same way.) Privileged deciders (the oracle) set
    ``privileged = True`` and receive the simulation core through :meth:`bind` before the first
    step; every other decider sees observations only.
    """

    name: str = "decider"
    version: str = "1"
    privileged: bool = False
    weights_sha256: str | None = None
    action_repeat: int = 1

    def __init__(self, config: EnvConfig | None = None) -> None:
        self.config = config or EnvConfig()

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        own = cls.__dict__.get("act")
        if own is not None and own is not Decider.act:  # act written in batch form: derive the rest
            cls.act_batch = own
            cls.act = Decider.act

    def bind(self, core: Any) -> None:  # only privileged deciders use the core
        self.core = core

    def reset(self, mask: np.ndarray | None = None) -> None:
        """Forget any per-row state for rows in ``mask`` (all rows when None)."""

    def act(self, obs: np.ndarray) -> Any:
        """One observation (D,) -> int; a batch (N, D) -> (N,) int64."""
        return act_with(self.act_batch, obs, self.name, self.config)

    def act_batch(self, obs: np.ndarray) -> np.ndarray:
        """(N, D) observations -> (N,) modes."""
        raise NotImplementedError

    def card(self) -> str:
        """A one-paragraph model card."""
        return (self.__doc__ or self.name).strip().splitlines()[0]


def act_with(act_batch: Callable[[np.ndarray], Any], obs: Any, who: str = "decider",
             config: EnvConfig | None = None) -> Any:
    """The decider protocol around a batch function: (D,) -> int through a batch of one, (N, D) ->
    (N,) int64, (0, D) -> an empty (0,) int64 without calling it. Anything else, and with ``config``
    a width other than its observation's or a non-finite value, is an :class:`ObservationError`."""
    obs = np.asarray(obs)
    if obs.ndim not in (1, 2):
        raise ObservationError(f"{who}: act expects one observation (D,) or a batch (N, D), got shape {obs.shape}")
    batch = obs[None] if obs.ndim == 1 else obs
    if config is not None:
        check_observations(batch, config, who)
    if batch.shape[0] == 0:
        return np.zeros(0, np.int64)
    modes = np.asarray(act_batch(batch))
    if modes.shape != (batch.shape[0],):
        raise ValueError(f"{who}: act returned shape {modes.shape} for {batch.shape[0]} observation(s); "
                         f"expected ({batch.shape[0]},)")
    modes = modes.astype(np.int64, copy=False)
    return int(modes[0]) if obs.ndim == 1 else modes


def check_observations(batch: np.ndarray, config: EnvConfig, who: str = "decider") -> None:
    """:class:`ObservationError` unless ``batch`` (N, D) has the config's width and finite values.
    One vectorised pass: NaN or inf in a feature would otherwise pass every comparison a rule makes
    (or none), and a network's argmax over NaN scores is mode 0 or worse."""
    width = observation_size(config)
    if batch.shape[1] != width:
        raise ObservationError(f"{who}: observations have {batch.shape[1]} features, expected {width} "
                               "(observation_size of the decider's config)")
    try:
        finite = np.isfinite(batch)
    except TypeError:
        raise ObservationError(f"{who}: observations must be numbers, got dtype {batch.dtype}") from None
    if not finite.all():
        row, col = (int(i[0]) for i in np.nonzero(~finite))
        raise ObservationError(f"{who}: observation feature {col} ({_feature(config, col)}) is "
                               f"{batch[row, col]} in row {row}; observations must be finite")


def _feature(config: EnvConfig, col: int) -> str:
    """``ego[2]``, ``opposite_lane[3]``: where column ``col`` sits in the observation layout."""
    for part, where in observation_layout(config).items():
        if where.start <= col < where.stop:
            return f"{part}[{col - where.start}]"
    return "?"


class ConstantDecider(Decider):
    """Always the same mode (a baseline and a runner test fixture)."""

    def __init__(self, mode: int, name: str, config: EnvConfig | None = None) -> None:
        super().__init__(config)
        self.mode, self.name = mode, name

    def act_batch(self, obs: np.ndarray) -> np.ndarray:
        return np.full(obs.shape[0], self.mode, dtype=np.int64)

    def card(self) -> str:
        return f"Always {('follow', 'overtake', 'abort')[self.mode]}: a fixed-mode baseline."


class UnknownDecider(KeyError):
    def __str__(self) -> str:  # KeyError quotes its message; keep it readable
        return str(self.args[0])


_REGISTRY: dict[str, Callable[..., Decider]] = {}


def register(name: str, factory: Callable[..., Decider]) -> None:
    """Register ``factory(config=None, **kwargs) -> Decider`` under ``name``."""
    _REGISTRY[name] = factory


def names() -> list[str]:
    return sorted(set(_REGISTRY) | {n for n, mod in _MEMBER_OF.items() if mod not in _UNAVAILABLE})


def known_names() -> list[str]:
    """Every built-in name, members whose optional dependency is missing included (all reserved),
    and each shieldable member behind the RSS shield (``<name>+shield``, :mod:`.shield`)."""
    return sorted(set(_REGISTRY) | set(_MEMBER_OF) | {f"{m}+shield" for m in SHIELDABLE})


def load(name: str, config: EnvConfig | None = None, **kwargs: Any) -> Decider:
    """A ready decider by registry name (pretrained weights included, checked by sha256);
    ``shielded:<name>`` or ``<name>+shield`` puts it behind the RSS shield (:mod:`.shield`)."""
    if name.startswith("shielded:") or name.endswith("+shield"):
        from .shield import load_shielded

        return load_shielded(name, config, **kwargs)
    if name in _MEMBER_OF and name not in _REGISTRY:
        _import_member(_MEMBER_OF[name])  # import only what is asked for: torch loads only for learned members
    if name not in _REGISTRY:
        _load_members()
    if name not in _REGISTRY:
        missing = "".join(f"; {mod} needs {dep!r} (pip install -e '.[train]')" for mod, dep in _UNAVAILABLE.items())
        raise UnknownDecider(f"unknown decider {name!r} (known: {', '.join(sorted(_REGISTRY))}{missing})")
    return _REGISTRY[name](config=config, **kwargs)


register("always-follow", lambda config=None: ConstantDecider(FOLLOW, "always-follow", config))
register("always-overtake", lambda config=None: ConstantDecider(OVERTAKE, "always-overtake", config))
register("always-abort", lambda config=None: ConstantDecider(ABORT, "always-abort", config))

# Registry name -> the member module that registers it, so `load` imports one module, not all.
_MEMBER_OF = {"rule-fsm": "rule_fsm", "fuzzy": "fuzzy", "oracle": "oracle", "dqn": "dqn", "double-dqn": "dqn",
              "ps-dqn": "dqn", "ppo": "ppo", "bc": "offline", "cql": "offline"}
_MEMBERS = tuple(dict.fromkeys(_MEMBER_OF.values()))
# Members the leaderboard shows behind the RSS shield: every non-privileged decider that overtakes.
SHIELDABLE = ("rule-fsm", "fuzzy", "dqn", "double-dqn", "ps-dqn", "ppo", "bc", "cql")
_UNAVAILABLE: dict[str, str] = {}  # member module -> the missing dependency (e.g. torch without [train])
_loaded = False


def _load_members() -> None:
    """Import the zoo members (each registers itself). A member whose optional dependency is not
    installed (torch for dqn / ppo) is skipped and named in unknown-decider errors."""
    global _loaded
    if _loaded:
        return
    _loaded = True
    for mod in _MEMBERS:
        _import_member(mod)


def _import_member(mod: str) -> None:
    import importlib

    try:
        importlib.import_module(f"overtakezoo.zoo.{mod}")
    except ModuleNotFoundError as exc:
        if (exc.name or "").startswith("overtakezoo"):
            raise
        _UNAVAILABLE[mod] = exc.name
