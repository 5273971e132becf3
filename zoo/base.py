"""The decider interface and the registry every face of the project resolves names through.

The registry is the one list of the zoo's members: each name with its kind (rule, learned,
privileged, wrapper; :class:`Member`), the module that provides it and, for a learned member, its
trainer. The leaderboard, the ``train`` command, the shield and the tests ask it (:func:`names`,
:func:`member`) rather than keeping lists of their own.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

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
    - ``action_repeat``: the decider's *decision rate* (its deployed hold): core steps between its
      decisions when deployed; the benchmark runner holds every decision that long
      (``overtakezoo.envs.hold``), so a decider never counts steps. For a learned member it is its
      card's ``decide_every`` (dqn: 1), which may differ from its *training hold*, the core steps each
      decision was held in training (the card's ``action_repeat``, dqn: 10; :mod:`.members.learned`).
    - ``row_state``: the names of the decider's per-row state arrays (``()``: stateless; ``None``,
      the default: undeclared). A decider that declares it lets the runner drop finished rows from
      the batch mid-run (:meth:`keep_rows`); an undeclared one always sees the whole batch.

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
    row_state: tuple[str, ...] | None = None
    _agent_rows: dict[Any, int] | None  # act_agents' row per agent, from its first call of an episode

    def __init__(self, config: EnvConfig | None = None) -> None:
        self.config = config or EnvConfig()

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        own = cls.__dict__.get("act")
        if own is not None and own is not Decider.act:  # act written in batch form: derive the rest
            # (a class's methods rebound on purpose: the subclass's act is its batch form)
            cls.act_batch = own  # type: ignore[method-assign]
            cls.act = Decider.act  # type: ignore[method-assign]

    def bind(self, core: Any) -> None:  # only privileged deciders use the core
        self.core = core

    def reset(self, mask: np.ndarray | None = None) -> None:
        """Forget any per-row state for rows in ``mask`` (all rows when None)."""

    def keep_rows(self, rows: np.ndarray, core: Any = None) -> None:
        """Keep only batch rows ``rows`` (increasing positions) of the per-row state named by
        ``row_state``: the next batch is those rows, in that order. A privileged decider is bound to
        ``core``, the compacted core, without losing its state. Only for a declared ``row_state``."""
        if self.row_state is None:
            raise TypeError(f"{self.name}: declares no row_state, so its rows cannot be dropped")
        for name in self.row_state:
            state = getattr(self, name)
            if state.shape[0]:  # (an empty array: not sized yet, sized at the next act)
                setattr(self, name, state[rows])
        if self.privileged and core is not None:
            self.core = core

    def act(self, obs: np.ndarray) -> Any:
        """One observation (D,) -> int; a batch (N, D) -> (N,) int64."""
        return act_with(self.act_batch, obs, self.name, self.config)

    def act_batch(self, obs: np.ndarray) -> np.ndarray:
        """(N, D) observations -> (N,) modes."""
        raise NotImplementedError

    def card(self) -> str:
        """A one-paragraph model card."""
        return (self.__doc__ or self.name).strip().splitlines()[0]

    # ------------------------------------------------------- several agents (PettingZoo)
    def act_agents(self, observations: Mapping[Any, Any]) -> dict[Any, int]:
        """One mode per agent, ``{agent: obs}`` -> ``{agent: int}``: how one decider drives several
        agents (the AVs of a PettingZoo road) without mixing their state.

        Each agent is one row of one batch (:meth:`act`), so a stateful decider (rule-fsm counts
        ticks per row) keeps each agent's state in its own row. The rows are fixed by the first call
        of an episode, one per agent in the order given (PettingZoo: every agent, right after
        ``reset``), and stay with their agent while agents leave: a finished agent's row is fed its
        last observation and its mode is not returned (rows never depend on each other). Call
        :meth:`reset_agents` at every new episode (after ``env.reset()``); an agent that left and
        comes back also starts a new episode, and one the episode never had is a ``KeyError``."""
        rows: dict[Any, int] | None = getattr(self, "_agent_rows", None)
        present: set[Any] = getattr(self, "_agents_present", set())
        if rows is not None and any(a in rows and a not in present for a in observations):
            rows = None  # an agent that had left is back: a new episode
        if rows is None:
            self.reset_agents()
            rows = self._agent_rows = {agent: i for i, agent in enumerate(observations)}
            if not rows:
                return {}
            first = np.asarray(next(iter(observations.values())))
            self._agent_obs = np.zeros((len(rows), *first.shape), first.dtype)
        for agent, obs in observations.items():
            if agent not in rows:
                raise KeyError(
                    f"{self.name}: act_agents: agent {agent!r} is not one of this episode's agents "
                    f"({', '.join(map(str, rows))}); call reset_agents() when a new episode starts"
                )
            self._agent_obs[rows[agent]] = obs
        self._agents_present = set(observations)
        modes = self.act(self._agent_obs)
        return {agent: int(modes[rows[agent]]) for agent in observations}

    def reset_agents(self) -> None:
        """Start a new episode of :meth:`act_agents`: forget the agents' rows and every row's state."""
        self._agent_rows, self._agents_present = None, set()
        self.reset()


def act_with(
    act_batch: Callable[[np.ndarray], Any], obs: Any, who: str = "decider", config: EnvConfig | None = None
) -> Any:
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
        raise ValueError(
            f"{who}: act returned shape {modes.shape} for {batch.shape[0]} observation(s); expected ({batch.shape[0]},)"
        )
    modes = modes.astype(np.int64, copy=False)
    return int(modes[0]) if obs.ndim == 1 else modes


def check_observations(batch: np.ndarray, config: EnvConfig, who: str = "decider") -> None:
    """:class:`ObservationError` unless ``batch`` (N, D) has the config's width and finite values.
    One vectorised pass: NaN or inf in a feature would otherwise pass every comparison a rule makes
    (or none), and a network's argmax over NaN scores is mode 0 or worse."""
    width = observation_size(config)
    if batch.shape[1] != width:
        raise ObservationError(
            f"{who}: observations have {batch.shape[1]} features, expected {width} "
            "(observation_size of the decider's config)"
        )
    try:
        finite = np.isfinite(batch)
    except TypeError:
        raise ObservationError(f"{who}: observations must be numbers, got dtype {batch.dtype}") from None
    if not finite.all():
        row, col = (int(i[0]) for i in np.nonzero(~finite))
        raise ObservationError(
            f"{who}: observation feature {col} ({_feature(config, col)}) is "
            f"{batch[row, col]} in row {row}; observations must be finite"
        )


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

    row_state = ()

    def act_batch(self, obs: np.ndarray) -> np.ndarray:
        return np.full(obs.shape[0], self.mode, dtype=np.int64)

    def card(self) -> str:
        return f"Always {('follow', 'overtake', 'abort')[self.mode]}: a fixed-mode baseline."


class UnknownDecider(KeyError):
    def __str__(self) -> str:  # KeyError quotes its message; keep it readable
        return str(self.args[0])


# ----------------------------------------------------------------------------- the registry
KINDS = ("rule", "learned", "privileged", "wrapper")


@dataclass(frozen=True)
class Member:
    """A name the registry resolves, and its kind:

    - ``rule``: hand-written rules (the fixed-mode baselines among them);
    - ``learned``: shipped weights (``zoo/pretrained/<name>.npz`` + model card) acted by
      :mod:`.members.learned`; ``trainer`` names the module under :mod:`overtakezoo.zoo.train` that
      trains it;
    - ``privileged``: sees the simulation core, not only observations (the oracle);
    - ``wrapper``: the member ``wraps`` behind something (``<name>+shield``: the RSS shield).

    ``module`` is the module under :mod:`overtakezoo.zoo.members` that registers the member when
    imported (None: registered here); ``shieldable`` members are also listed behind the shield
    (every non-privileged member that chooses when to overtake)."""

    name: str
    kind: str
    module: str | None = None
    trainer: str | None = None
    shieldable: bool = False
    wraps: str | None = None


def _builtin() -> dict[str, Member]:
    learned = {
        "dqn": "dqn",
        "double-dqn": "dqn",
        "ps-dqn": "dqn",
        "ps-dqn-multi": "dqn",
        "ppo": "ppo",
        "bc": "bc",
        "cql": "cql",
        "dagger": "dagger",
    }
    own = [
        Member("always-follow", "rule"),
        Member("always-overtake", "rule"),
        Member("always-abort", "rule"),
        Member("rule-fsm", "rule", "rule_fsm", shieldable=True),
        Member("fuzzy", "rule", "fuzzy", shieldable=True),
        Member("oracle", "privileged", "oracle"),
        Member("joint-oracle", "privileged", "joint_oracle"),  # plans every AV of a multi-AV road together
        # ps-dqn: dqn whose one Q-network drove every AV of multi-AV roads in training (parameter sharing);
        # ps-dqn-multi: the same, trained on the multi-AV roads alone (multi-train).
        *(Member(n, "learned", "learned", trainer=t, shieldable=True) for n, t in learned.items()),
    ]
    wrapped = [Member(f"{m.name}+shield", "wrapper", "shield", wraps=m.name) for m in own if m.shieldable]
    return {m.name: m for m in own + wrapped}


# The built-in members (every list of members in the project asks this table) and any registered since.
_MEMBERS: dict[str, Member] = _builtin()
_REGISTRY: dict[str, Callable[..., Decider]] = {}


def register(name: str, factory: Callable[..., Decider], kind: str | None = None) -> None:
    """Register ``factory(config=None, **kwargs) -> Decider`` under ``name``; ``kind`` (one of
    :data:`KINDS`) defaults to the built-in member's, else ``rule``."""
    kind = kind or (_MEMBERS[name].kind if name in _MEMBERS else "rule")
    if kind not in KINDS:
        raise ValueError(f"register({name!r}): kind {kind!r} is not one of {', '.join(KINDS)}")
    if name not in _MEMBERS or _MEMBERS[name].kind != kind:
        _MEMBERS[name] = Member(name, kind)
    _REGISTRY[name] = factory


def member(name: str) -> Member:
    """The registry's entry for ``name`` (:class:`UnknownDecider` if there is none)."""
    if name not in _MEMBERS:
        raise UnknownDecider(f"unknown decider {name!r} (known: {', '.join(known_names())})")
    return _MEMBERS[name]


def names(kind: str | None = None) -> list[str]:
    """The members' names, wrappers left out; with ``kind``, the members of that kind only."""
    if kind is not None and kind not in KINDS:
        raise ValueError(f"kind {kind!r} is not one of {', '.join(KINDS)}")
    return sorted(n for n, m in _MEMBERS.items() if (m.kind == kind if kind else m.kind != "wrapper"))


def known_names() -> list[str]:
    """Every name :func:`load` takes from the registry: the members and each shieldable member behind
    the RSS shield (``<name>+shield``, :mod:`.members.shield`)."""
    return sorted(_MEMBERS)


def load(name: str, config: EnvConfig | None = None, **kwargs: Any) -> Decider:
    """A ready decider by registry name (pretrained weights included, checked by sha256);
    ``shielded:<name>`` or ``<name>+shield`` puts it behind the RSS shield (:mod:`.members.shield`).
    Only the member's own module is imported (numpy only: no member needs torch to act)."""
    if name.startswith("shielded:") or name.endswith("+shield"):
        from overtakezoo.zoo.members.shield import load_shielded

        return load_shielded(name, config, **kwargs)
    if name not in _REGISTRY and name in _MEMBERS and _MEMBERS[name].module:
        importlib.import_module(f"overtakezoo.zoo.members.{_MEMBERS[name].module}")
    if name not in _REGISTRY:
        raise UnknownDecider(f"unknown decider {name!r} (known: {', '.join(names())})")
    return _REGISTRY[name](config=config, **kwargs)


register("always-follow", lambda config=None: ConstantDecider(FOLLOW, "always-follow", config))
register("always-overtake", lambda config=None: ConstantDecider(OVERTAKE, "always-overtake", config))
register("always-abort", lambda config=None: ConstantDecider(ABORT, "always-abort", config))
