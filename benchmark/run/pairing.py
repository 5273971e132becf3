"""A pairing: several deciders on one multi-AV batch, decider ``e`` driving AV ``e`` of every road.

The core lays out AV rows AV-major (``OvertakeCore``: AV e of road n is row ``e * N + n``), so AV e's
rows are the contiguous block ``e * N .. (e + 1) * N - 1``: :meth:`Pairing.act` hands each decider
its block. Deciders may hold their decisions for different numbers of steps (dqn 10, rule-fsm 1):
the pairing is held for the greatest common divisor of their holds, and each decider re-decides
only on its own schedule (every ``hold / gcd`` calls) and repeats its last modes in between, so it
acts at exactly the steps it would act at alone.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from overtakezoo.benchmark.errors import UserError
from overtakezoo.envs import observation_layout
from overtakezoo.envs.hold import hold_steps
from overtakezoo.zoo.members.learned import read_parts


class Pairing:
    """Decider ``by_av[e]`` drives AV ``e`` (a runner decider: ``act``, ``reset``, ``action_repeat``)."""

    privileged = False
    weights_sha256 = None

    def __init__(self, by_av: Sequence[Any], decision_interval: int) -> None:
        if len(by_av) < 2:
            raise UserError("a pairing needs one decider per AV (at least two)")
        for d in by_av:
            if getattr(d, "privileged", False):
                raise UserError(
                    f"{d.name}: privileged deciders bind the whole core; they cannot share a road in a pairing"
                )
        if len({id(d) for d in by_av}) != len(by_av):
            raise UserError(
                "a pairing needs its own decider object per AV (deciders keep per-row state): load "
                "the same member once per AV"
            )
        self.by_av = list(by_av)
        holds = [hold_steps(decision_interval, int(getattr(d, "action_repeat", 1))) for d in self.by_av]
        self.action_repeat = math.gcd(*holds)  # a multiple of decision_interval: the runner holds exactly this
        self.every = [h // self.action_repeat for h in holds]
        self.name = "+".join(str(d.name) for d in self.by_av)
        self.version = "+".join(str(d.version) for d in self.by_av)
        self._calls = 0
        self._last: list[np.ndarray | None] = [None] * len(self.by_av)
        # The runner turns on for the road every opt-in observation part a decider reads: the others
        # read their own parts of it (None: the whole observation).
        self._columns = [_own_columns(d, read_parts(self)) for d in self.by_av]

    def reset(self, mask: np.ndarray | None = None) -> None:
        if mask is None:
            self._calls, self._last = 0, [None] * len(self.by_av)
        for e, d in enumerate(self.by_av):
            d.reset(None if mask is None else self._block(np.asarray(mask), e))

    def _block(self, rows: np.ndarray, e: int) -> np.ndarray:
        k = len(self.by_av)
        if rows.shape[0] % k:
            raise ValueError(f"{rows.shape[0]} rows are not {k} AVs per road (a pairing needs the core's AV rows)")
        n = rows.shape[0] // k
        return rows[e * n : (e + 1) * n]

    def act(self, obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs)
        for e, d in enumerate(self.by_av):
            if self._calls % self.every[e] == 0 or self._last[e] is None:
                block = self._block(obs, e)
                if self._columns[e] is not None:
                    block = block[:, self._columns[e]]
                self._last[e] = np.asarray(d.act(block), np.int64)
        self._calls += 1
        return np.concatenate(self._last)


def _own_columns(decider: Any, road_parts: dict[str, bool]) -> np.ndarray | None:
    """The columns of a road observation (with the opt-in parts ``road_parts`` on) that make up
    ``decider``'s own observation; None when they are all of them (or it names no config)."""
    config = getattr(decider, "config", None)
    if config is None or not road_parts:
        return None
    own, road = observation_layout(config), observation_layout(config.with_observation(**road_parts))
    if own == road:
        return None
    return np.concatenate([np.arange(road[part].start, road[part].stop) for part in own])
