"""A categorical action distribution for rsl-rl (which ships only Gaussian and Beta ones).

rsl-rl builds an actor's output distribution from ``actor.distribution_cfg``: it resolves
``distribution_cfg["class_name"]`` (``"module.path:ClassName"``) to any subclass of
``rsl_rl.modules.distribution.Distribution`` and calls it with ``(num_actions, **other_keys)``.
So this class plugs in with::

    "actor": {"class_name": "MLPModel", ...,
              "distribution_cfg": {"class_name": "overtakezoo.zoo.train.categorical:CategoricalDistribution",
                                   "num_categories": 3}}

The MLP emits ``num_categories`` logits; an action is the sampled category index as a float
column ``(N, 1)`` (the env's ``num_actions = 1``), and the deterministic output is the argmax.
"""

from __future__ import annotations

import os

import torch
import torch.nn as nn
from torch.distributions import Categorical

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")  # importing rsl_rl pulls GitPython
from rsl_rl.modules.distribution import Distribution  # noqa: E402


class CategoricalDistribution(Distribution):
    """One categorical variable over ``num_categories`` choices, parameterized by logits."""

    def __init__(self, output_dim: int, num_categories: int = 3, init_logit_scale: float = 0.01) -> None:
        if output_dim != 1:
            raise ValueError(
                f"CategoricalDistribution samples one index per row: num_actions must be 1, got {output_dim}"
            )
        if num_categories < 2:
            raise ValueError(f"num_categories must be >= 2, got {num_categories}")
        super().__init__(output_dim)
        self.num_categories = num_categories
        self.init_logit_scale = init_logit_scale
        self._distribution: Categorical | None = None

    def update(self, mlp_output: torch.Tensor) -> None:
        self._distribution = Categorical(logits=mlp_output, validate_args=False)

    @property
    def _dist(self) -> Categorical:
        """The distribution of the last :meth:`update`."""
        assert self._distribution is not None, "update() first"
        return self._distribution

    def sample(self) -> torch.Tensor:
        return self._dist.sample().unsqueeze(-1).to(self._dist.logits.dtype)

    def deterministic_output(self, mlp_output: torch.Tensor) -> torch.Tensor:
        return torch.argmax(mlp_output, dim=-1, keepdim=True).to(mlp_output.dtype)

    def as_deterministic_output_module(self) -> nn.Module:
        return _ArgmaxOutput()

    @property
    def input_dim(self) -> int:
        return self.num_categories

    @property
    def mean(self) -> torch.Tensor:
        """Expected category index, (N, 1) (only for logging: the index is not ordinal)."""
        return (self._dist.probs * self._index()).sum(-1, keepdim=True)

    @property
    def std(self) -> torch.Tensor:
        """Spread of the category index, (N, 1); the runner logs it as the action std."""
        idx = self._index()
        var = (self._dist.probs * (idx - self.mean) ** 2).sum(-1, keepdim=True)
        return var.clamp_min(0.0).sqrt()

    @property
    def entropy(self) -> torch.Tensor:
        return self._dist.entropy()

    @property
    def params(self) -> tuple[torch.Tensor, ...]:
        """Normalized log-probabilities (logits shifted so they logsumexp to 0)."""
        return (self._dist.logits,)

    def log_prob(self, outputs: torch.Tensor) -> torch.Tensor:
        return self._dist.log_prob(outputs.squeeze(-1).round().long())

    def kl_divergence(self, old_params: tuple[torch.Tensor, ...], new_params: tuple[torch.Tensor, ...]) -> torch.Tensor:
        old = torch.log_softmax(old_params[0], dim=-1)
        new = torch.log_softmax(new_params[0], dim=-1)
        return (old.exp() * (old - new)).sum(dim=-1)

    def init_mlp_weights(self, mlp: nn.Sequential) -> None:  # (rsl-rl's MLP, a Sequential)
        # Small last-layer weights: the initial policy is near uniform over the modes.
        last = mlp[-1]
        if isinstance(last, nn.Linear):
            nn.init.orthogonal_(last.weight, gain=self.init_logit_scale)
            nn.init.zeros_(last.bias)

    def _index(self) -> torch.Tensor:
        logits = self._dist.logits
        return torch.arange(self.num_categories, device=logits.device, dtype=logits.dtype)


class _ArgmaxOutput(nn.Module):
    """Export-friendly (TorchScript / ONNX) deterministic output: the most likely index as a float column."""

    def forward(self, mlp_output: torch.Tensor) -> torch.Tensor:
        return torch.argmax(mlp_output, dim=-1, keepdim=True).to(mlp_output.dtype)
