"""The numpy PPO's recipe (:mod:`.fastppo`) in torch, on a device: ``overtakezoo train ppo-numpy
--device cuda``. The same hyperparameter file, the same algorithm (clipped surrogate, GAE, minibatch
advantage normalisation, entropy bonus, one global gradient-norm clip, Adam) and the same output
files, but the rollout, the advantages and the update stay on the device: the cores are the
sync-free torch core auto-resetting from a bank of the training suites' scenarios (envs/core.py),
the action hold runs as masked steps, and the host reads one iteration's episode counts once per
iteration (never per step). Model selection scores the greedy policy on the host as the numpy
trainer does.

Differences from the numpy trainer, by design: the core runs in float32 (the GPU's fast path), each
suite's rows restart from a seeded permutation of its scenarios in turn (the numpy trainer draws
them uniformly), and the draws come from a seeded torch generator. The same seed on the same device
gives the same weights; on a CPU the numpy trainer is the default (``--device cpu``) and this path
runs there only with ``--backend torch`` (how it is tested).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from overtakezoo.envs import CRASH, FOLLOW, SUCCESS, TIMEOUT, OvertakeCore
from overtakezoo.envs.io import check_writable_dir
from overtakezoo.zoo.members.features import speed_relative
from overtakezoo.zoo.train.fastppo import MLP, FastPPOHyperparams, Run


def train_on_device(
    suites: list[Any],
    hp: FastPPOHyperparams,
    hp_file: str,
    *,
    suite_name: str | None,
    steps: int | None,
    seed: int,
    out: Path,
    progress: bool,
    device: str,
) -> Any:
    import torch

    from overtakezoo.envs.mixture import split_rows

    check_writable_dir(out)
    run = Run(suites, hp, suite_name=suite_name, steps=steps, seed=seed)
    p, n, repeat, dim, config = run.p, run.n, run.repeat, run.dim, run.config
    gen = torch.Generator(device=device).manual_seed(seed)  # the policy's draws and the minibatches
    actor_init, critic_init = run.networks()  # (first from the generator: the numpy run's first weights)
    actor, critic = _net(actor_init, device), _net(critic_init, device)
    cores = []
    for s, pool, rows in zip(suites, run.pools, split_rows(n, len(run.pools)), strict=True):
        bank = pool.take(run.rng.permutation(pool.num))
        core = OvertakeCore(
            s.config, auto_reset=True, bank=bank, backend="torch", device=device, dtype=torch.float32, sync_free=True
        )
        cores.append((core, rows))
    obs = _features(torch.cat([core.reset_from_bank(rows) for core, rows in cores]), config)
    params = [*actor.parameters(), *critic.parameters()]
    opt = torch.optim.Adam(params, lr=p.learning_rate, eps=1e-8)

    T = p.num_steps_per_env
    b_obs = torch.empty((T, n, dim), device=device)
    b_act = torch.empty((T, n), dtype=torch.int64, device=device)
    b_logp, b_val, b_rew, b_done = (torch.empty((T, n), device=device) for _ in range(4))
    clock = time.process_time
    for it in range(run.iterations):
        counts = torch.zeros(4, dtype=torch.int64, device=device)  # episodes, successes, crashes, timeouts
        c0 = clock()
        with torch.no_grad():
            for t in range(T):
                logp = torch.log_softmax(actor(obs), dim=1)
                act = torch.multinomial(logp.exp(), 1, generator=gen)[:, 0]
                b_obs[t], b_act[t], b_logp[t] = obs, act, logp.gather(1, act[:, None])[:, 0]
                b_val[t] = critic(obs)[:, 0]
                reward, ended, obs_raw = _hold(cores, act, repeat, counts)
                b_rew[t], b_done[t] = reward, ended.float()
                obs = _features(obs_raw, config)
            adv, ret = _gae(b_rew, b_val, b_done, critic(obs)[:, 0], p.gamma, p.lam)
        c1 = clock()
        flat = (b_obs.reshape(-1, dim), b_act.reshape(-1), b_logp.reshape(-1), adv.reshape(-1), ret.reshape(-1))
        _update(actor, critic, opt, params, *flat, p, gen)
        run.cpu["rollout"] += c1 - c0
        run.cpu["update"] += clock() - c1
        score = run.select(it, lambda: _layers(actor))
        run.log(it, counts.tolist(), score, progress, f" ({device})")  # (the iteration's one read on the host)
    return run.finish(hp_file, out, device=device)


def _features(obs: Any, config: Any) -> Any:
    """The policy's input (features.speed_relative, in torch) as float32."""
    return speed_relative(obs, config).float()


def _net(init: MLP, device: str) -> Any:
    """A torch tanh MLP holding ``init``'s parameters (the numpy trainer's initialisation)."""
    import torch

    layers: list[Any] = []
    for i in range(0, len(init.params), 2):
        w, b = init.params[i], init.params[i + 1]
        linear = torch.nn.Linear(w.shape[1], w.shape[0])
        with torch.no_grad():
            linear.weight.copy_(torch.as_tensor(w))
            linear.bias.copy_(torch.as_tensor(b))
        layers += [linear, torch.nn.Tanh()]
    return torch.nn.Sequential(*layers[:-1]).to(device)


def _layers(net: Any) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
    """The actor's layers as float64 host arrays (what NumpyMLP and the npz hold)."""
    linears = [m for m in net if hasattr(m, "weight")]
    return tuple((m.weight.detach().cpu().double().numpy(), m.bias.detach().cpu().double().numpy()) for m in linears)


def _hold(cores: list[tuple[OvertakeCore, int]], act: Any, repeat: int, counts: Any) -> tuple[Any, Any, Any]:
    """``act`` held ``repeat`` core steps (envs/hold.py's rule, as masks): a row that ends stops
    counting and follows until the hold ends; ``counts`` += the ended episodes' outcomes."""
    import torch

    reward = torch.zeros(act.shape[0], device=act.device)
    ended = torch.zeros(act.shape[0], dtype=torch.bool, device=act.device)
    obs: Any = None
    for _ in range(repeat):
        modes = torch.where(ended, FOLLOW, act)
        parts: list[Any] = [
            core.step(m) for (core, _), m in zip(cores, torch.split(modes, [r for _, r in cores]), strict=True)
        ]
        step_reward = torch.cat([r.reward for r in parts]).float()
        finished = torch.cat([r.finished for r in parts])
        outcome = torch.cat([r.info["outcome"] for r in parts])
        reward += torch.where(ended, 0.0, step_reward)
        now = ~ended & finished
        counts += torch.stack(
            [
                now.sum(),
                (now & (outcome == SUCCESS)).sum(),
                (now & (outcome == CRASH)).sum(),
                (now & (outcome == TIMEOUT)).sum(),
            ]
        )
        ended |= now
        obs = torch.cat([r.obs for r in parts])
    return reward, ended, obs


def _gae(reward: Any, value: Any, done: Any, last: Any, gamma: float, lam: float) -> tuple[Any, Any]:
    """fastppo.gae in torch: (T, N) advantages and returns; a finished row does not bootstrap."""
    import torch

    adv = torch.zeros_like(reward)
    running = torch.zeros_like(last)
    nxt = last
    for t in range(reward.shape[0] - 1, -1, -1):
        live = 1.0 - done[t]
        delta = reward[t] + gamma * nxt * live - value[t]
        running = delta + gamma * lam * live * running
        adv[t], nxt = running, value[t]
    return adv, adv + value


def _update(
    actor: Any,
    critic: Any,
    opt: Any,
    params: list[Any],
    obs: Any,
    act: Any,
    old: Any,
    adv_all: Any,
    ret_all: Any,
    p: Any,
    gen: Any,
) -> None:
    """fastppo.update's minibatch epochs with autograd: the same loss (clipped surrogate, entropy
    bonus, value error) and one gradient-norm clip over both networks."""
    import torch

    b = obs.shape[0]
    size = max(1, b // p.minibatches)
    for _ in range(p.epochs):
        order = torch.randperm(b, generator=gen, device=obs.device)
        for k in range(p.minibatches):
            idx = order[k * size : (k + 1) * size]
            x, a, lp_old, adv, ret = obs[idx], act[idx], old[idx], adv_all[idx], ret_all[idx]
            adv = (adv - adv.mean()) / (adv.std(correction=0) + 1e-8)
            logp = torch.log_softmax(actor(x), dim=1)
            ratio = torch.exp(logp.gather(1, a[:, None])[:, 0] - lp_old)
            surrogate = torch.minimum(ratio * adv, torch.clamp(ratio, 1.0 - p.clip, 1.0 + p.clip) * adv)
            entropy = -(logp.exp() * logp).sum(dim=1)
            value_error = (critic(x)[:, 0] - ret) ** 2
            loss = -surrogate.mean() - p.entropy_coef * entropy.mean() + p.value_coef * value_error.mean()
            opt.zero_grad(set_to_none=True)
            loss.backward()
            if p.max_grad_norm > 0:
                torch.nn.utils.clip_grad_norm_(params, p.max_grad_norm)  # (scale max / (norm + 1e-6), as fastppo)
            opt.step()
