"""Recording datasets: a decider's transitions on a suite (with epsilon-random exploration), as Minari episodes."""

from __future__ import annotations

from typing import Any

import numpy as np

from overtakezoo.benchmark.datasets.store import check_name, datasets_dir, load, minari_module, write_dataset
from overtakezoo.benchmark.errors import UserError
from overtakezoo.envs.io import check_writable_dir


# ---------------------------------------------------------------------------- build
class EpsilonRandom:
    """Wraps a decider: each decision is replaced by a uniformly random mode with probability
    ``epsilon`` (seeded), for datasets with some exploration."""

    def __init__(self, decider: Any, epsilon: float, seed: int) -> None:
        self.inner, self.epsilon, self.rng = decider, epsilon, np.random.default_rng(seed)
        self.name, self.version = decider.name, decider.version
        self.privileged = getattr(decider, "privileged", False)
        self.weights_sha256 = getattr(decider, "weights_sha256", None)
        # The runner holds each decision this long: without it a learned member (trained with a
        # repeat) would be recorded deciding every step, unlike its evaluation.
        self.action_repeat = getattr(decider, "action_repeat", 1)

    def bind(self, core: Any) -> None:
        self.inner.bind(core)

    def reset(self, mask: Any = None) -> None:
        self.inner.reset(mask)

    def act(self, obs: np.ndarray) -> np.ndarray:
        modes = np.asarray(self.inner.act(obs), dtype=np.int64)
        explore = self.rng.random(modes.shape[0]) < self.epsilon
        return np.where(explore, self.rng.integers(0, 3, modes.shape[0]), modes)


class TransitionRecorder:
    """A runner recorder (see benchmark/run/runner.py) that keeps every transition of every episode:
    per step only the rows still running are kept; one lexsort per chunk groups them by episode."""

    def __init__(self) -> None:
        self.episodes: list[dict[str, np.ndarray]] = []

    def begin_chunk(self, core: Any, scenario_index: np.ndarray) -> None:
        n = core.num
        self.index, self.k = scenario_index, 0
        self.obs_parts = [(np.arange(n), np.zeros(n, np.int64), core.observe(), core.outcome.copy(), core.t.copy())]
        self.step_parts: list[tuple[np.ndarray, ...]] = []

    def record_step(self, core: Any, modes: np.ndarray, res: Any) -> None:
        active = np.flatnonzero(~core.done | res.finished)  # the rows this step advanced
        self.k += 1
        steps = np.full(active.size, self.k)
        self.obs_parts.append((active, steps, res.obs[active], core.outcome[active].copy(), core.t[active].copy()))
        self.step_parts.append(
            (active, steps, modes[active], res.reward[active], res.terminated[active], res.truncated[active])
        )

    def end_chunk(self, core: Any) -> None:
        n = core.num
        o_rows, o_steps, o_obs, o_out, o_t = (np.concatenate(c) for c in zip(*self.obs_parts, strict=True))
        s_rows, s_steps, act, rew, term, trunc = (np.concatenate(c) for c in zip(*self.step_parts, strict=True))
        o_ord, s_ord = np.lexsort((o_steps, o_rows)), np.lexsort((s_steps, s_rows))
        o_b = np.searchsorted(o_rows[o_ord], np.arange(n + 1))
        s_b = np.searchsorted(s_rows[s_ord], np.arange(n + 1))
        o_obs, o_out, o_t = o_obs[o_ord], o_out[o_ord], o_t[o_ord]
        act, rew, term, trunc = act[s_ord], rew[s_ord], term[s_ord], trunc[s_ord]
        for r in range(n):  # Minari takes one buffer per episode; slicing, not simulation
            oa, ob, sa, sb = o_b[r], o_b[r + 1], s_b[r], s_b[r + 1]
            self.episodes.append(
                {
                    "observations": o_obs[oa:ob].astype(np.float32),
                    "actions": act[sa:sb].astype(np.int64),
                    "rewards": rew[sa:sb].astype(np.float64),
                    "terminations": term[sa:sb].astype(bool),
                    "truncations": trunc[sa:sb].astype(bool),
                    "infos": {
                        "outcome": o_out[oa:ob].astype(np.int64),
                        "t": o_t[oa:ob].astype(np.float64),
                        "scenario_index": np.full(ob - oa, self.index[r], np.int64),
                    },
                }
            )


def collect(
    suite: Any,
    decider: Any,
    epsilon: float = 0.0,
    seed: int = 0,
    count: int | None = None,
    chunk_size: int = 4096,
    progress: bool = False,
) -> list[dict[str, np.ndarray]]:
    """Run ``decider`` (epsilon-random) on the first ``count`` scenarios of ``suite`` through the
    benchmark runner; one dict of arrays per episode, in scenario order."""
    from overtakezoo.benchmark.run.runner import run_suite

    recorder = TransitionRecorder()
    run_suite(
        suite,
        EpsilonRandom(decider, epsilon, seed),
        chunk_size=chunk_size,
        progress=progress,
        recorder=recorder,
        limit=count,
    )
    return recorder.episodes


def build_dataset(
    name: str,
    suite: Any,
    decider: Any,
    epsilon: float = 0.1,
    count: int | None = None,
    seed: int = 0,
    chunk_size: int = 4096,
    overwrite: bool = False,
) -> Any:
    """Record ``decider`` on ``suite`` (its first ``count`` scenarios) and store a Minari dataset."""
    check_name(name)
    if not 0.0 <= epsilon <= 1.0:
        raise UserError(f"--epsilon {epsilon}: must be in [0, 1]")
    minari_module()
    if count is not None and not 1 <= count <= suite.count:
        raise UserError(f"--count {count}: suite {suite.name} has {suite.count} scenarios")
    target = datasets_dir() / name
    if target.exists() and not overwrite:
        raise UserError(f"dataset {name} already exists in {datasets_dir()} (use --overwrite to replace it)")
    check_writable_dir(target.parent)  # fail before recording, not after
    episodes = collect(suite, decider, epsilon=epsilon, seed=seed, count=count, chunk_size=chunk_size)
    description = (
        f"{decider.name} v{decider.version} on suite {suite.name} v{suite.version} "
        f"({suite.hash[:12]}), first {len(episodes)} scenarios, epsilon-random {epsilon}, "
        f"seed {seed}. One transition per simulator step (dt={suite.config.dt} s)."
    )
    write_dataset(
        name, episodes, suite.config, algorithm=f"{decider.name} (epsilon={epsilon})", description=description
    )
    return load(name)
