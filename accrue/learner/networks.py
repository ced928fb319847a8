"""Actor π_θ(s, ã) and critic Q_ψ(s, a, ã) over action chunks (paper Sec. IV-A).

s is the flat state the replay buffer stores (frozen encoder features ‖ proprioception). Each network
has its own small trainable projector of s. The actor owns the running observation normaliser, so a
frozen copy of it (the Eq. 3 teacher) maps raw stored states exactly as the actor did.

Actor parameterisation (our choice): residual in pre-tanh space, a = tanh(atanh(ã) + δ_θ(s, ã)),
with the last layer initialised near zero. At the start of RL the actor therefore executes the base
policy's chunk (a ≈ ã), which is the competent starting point the paper refines, and every output stays
in [-1, 1]. When ã is dropped (reference dropout, or the no-reference ablation) the same formula gives
a = tanh(δ_θ(s, 0)): the actor must act from the state alone, which is what dropout is meant to teach.
The β‖a − ã‖² anchor of Eq. 1 is in the loss regardless (losses.py).
"""

from __future__ import annotations

import math

import torch
from torch import nn

_ATANH_CLIP = 1.0 - 1e-4  # atanh(±1) is infinite; references at the bound map to ≈ ±4.95


class RunningNorm(nn.Module):
    """Running mean/std of s (parallel-variance update). Buffers, so they are part of the saved state.
    ChunkLearner.train_step feeds it the current-task minibatch states before each update.

    Across stages (docs/DEPARTURES.md): the std has a floor `min_std`, so a column that was constant
    so far (every task-feature column during stage 1) maps a new task's value to a bounded z instead
    of ±hundreds of standard deviations; z is clipped to ±clip; and `freeze()` (at the handoff of the
    learner's first stage, by default) stops the statistics, so that the teacher of Eq. 3, the student,
    and EWC's and RETAIN's anchors all read s through the same map for the rest of the sequence.
    The last `fixed_tail` columns (a task descriptor with a fixed known scale) are never normalised: they
    pass through as they are, so a column constant so far cannot arrive as noise later.
    """

    def __init__(
        self,
        dim: int,
        enabled: bool = True,
        eps: float = 1e-6,
        min_std: float = 0.0,
        clip: float = 0.0,
        fixed_tail: int = 0,
    ):
        super().__init__()
        self.enabled, self.eps, self.min_std, self.clip = enabled, eps, min_std, clip
        self.fixed_tail = int(fixed_tail)  # a setting, not state: checkpoints keep their keys
        self.register_buffer("mean", torch.zeros(dim))
        self.register_buffer("var", torch.ones(dim))
        self.register_buffer("count", torch.zeros((), dtype=torch.float64))
        self.register_buffer("frozen", torch.zeros((), dtype=torch.bool))

    @torch.no_grad()
    def update(self, x: torch.Tensor) -> None:
        if not self.enabled or x.shape[0] == 0 or bool(self.frozen):
            return
        x = x.reshape(-1, self.mean.numel()).to(self.mean)
        n = float(x.shape[0])
        bmean, bvar = x.mean(0), x.var(0, unbiased=False)
        total = float(self.count) + n
        delta = bmean - self.mean
        self.mean += delta * (n / total)
        self.var.copy_(
            (self.var * float(self.count) + bvar * n + delta.square() * float(self.count) * n / total) / total
        )
        self.count.fill_(total)

    def freeze(self) -> None:
        self.frozen.fill_(True)

    def std(self) -> torch.Tensor:
        return (self.var + self.eps).sqrt().clamp_min(self.min_std)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not self.enabled:
            return x
        z = (x - self.mean) / self.std()
        z = z.clamp(-self.clip, self.clip) if self.clip > 0 else z
        if self.fixed_tail > 0:
            z = torch.cat([z[..., : -self.fixed_tail], x[..., -self.fixed_tail :]], dim=-1)
        return z


def mlp(sizes: list[int], layer_norm: bool) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            if layer_norm:
                layers.append(nn.LayerNorm(sizes[i + 1]))
            layers.append(nn.SiLU())
    return nn.Sequential(*layers)


def projector(state_dim: int, out_dim: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(state_dim, out_dim), nn.LayerNorm(out_dim), nn.SiLU())


def pre_tanh(ref: torch.Tensor) -> torch.Tensor:
    return torch.atanh(ref.clamp(-_ATANH_CLIP, _ATANH_CLIP))


class Actor(nn.Module):
    """Deterministic chunk actor (FastTD3 style): a = tanh(atanh(ã) + δ) or a = tanh(δ)."""

    def __init__(
        self,
        state_dim: int,
        horizon: int,
        action_dim: int,
        hidden: list[int],
        projector_dim: int,
        layer_norm: bool = True,
        residual: bool = True,
        init_scale: float = 0.01,
        obs_normalization: bool = True,
        out_heads: int = 1,
        obs_norm_min_std: float = 0.0,
        obs_norm_clip: float = 0.0,
        obs_norm_fixed_tail: int = 0,
        delta_bound: float = 0.0,
    ):
        super().__init__()
        self.horizon, self.action_dim, self.residual = horizon, action_dim, residual
        self.delta_bound = delta_bound
        chunk = horizon * action_dim
        self.obs_norm = RunningNorm(
            state_dim,
            enabled=obs_normalization,
            min_std=obs_norm_min_std,
            clip=obs_norm_clip,
            fixed_tail=obs_norm_fixed_tail,
        )
        self.proj = projector(state_dim, projector_dim)
        self.trunk = mlp([projector_dim + chunk, *hidden], layer_norm)
        self.act_fn = nn.SiLU()
        self.head = nn.Linear(hidden[-1], chunk * out_heads)
        with torch.no_grad():  # small last layer: δ ≈ 0, so a ≈ ã at the start (FastTD3 init_scale)
            self.head.weight.mul_(init_scale)
            self.head.bias.zero_()

    def features(self, state: torch.Tensor, ref: torch.Tensor) -> torch.Tensor:
        s = self.proj(self.obs_norm(state))
        return self.head(self.act_fn(self.trunk(torch.cat([s, ref.flatten(1)], -1))))

    def pre_tanh_mean(self, state: torch.Tensor, ref: torch.Tensor, out: torch.Tensor | None = None):
        out = self.features(state, ref) if out is None else out
        delta = out[:, : self.horizon * self.action_dim]
        if self.delta_bound > 0:  # a soft box: with nothing anchoring it (β = 0) δ still cannot run off
            delta = self.delta_bound * torch.tanh(delta / self.delta_bound)
        return pre_tanh(ref.flatten(1)) + delta if self.residual else delta

    def forward(self, state: torch.Tensor, ref: torch.Tensor) -> torch.Tensor:
        """π_θ(s, ã) → chunk (B, H, d) in [-1, 1]."""
        return torch.tanh(self.pre_tanh_mean(state, ref)).view(-1, self.horizon, self.action_dim)

    def deterministic(self, state: torch.Tensor, ref: torch.Tensor) -> torch.Tensor:
        """π̄_θ(s, ã): the noise-free output used for Eq. 3 teacher targets and evaluation."""
        return self.forward(state, ref)


class GaussianActor(Actor):
    """Tanh-Gaussian chunk actor (FastSAC style): a = tanh(μ + σ·ε), μ = atanh(ã) + δ_μ."""

    def __init__(self, *args, log_std_min: float = -5.0, log_std_max: float = 0.0, **kwargs):
        super().__init__(*args, out_heads=2, **kwargs)
        self.log_std_min, self.log_std_max = log_std_min, log_std_max

    def dist_params(self, state: torch.Tensor, ref: torch.Tensor):
        out = self.features(state, ref)
        chunk = self.horizon * self.action_dim
        mean = self.pre_tanh_mean(state, ref, out)
        # FastSAC: log σ squashed by tanh into [log_std_min, log_std_max]
        raw = torch.tanh(out[:, chunk:])
        log_std = self.log_std_min + 0.5 * (self.log_std_max - self.log_std_min) * (raw + 1)
        return mean, log_std

    def forward(self, state: torch.Tensor, ref: torch.Tensor) -> torch.Tensor:
        mean, _ = self.dist_params(state, ref)
        return torch.tanh(mean).view(-1, self.horizon, self.action_dim)


def tanh_gaussian_sample(mean: torch.Tensor, log_std: torch.Tensor, eps: torch.Tensor):
    """a = tanh(μ + σ·ε) and log π(a) with the tanh Jacobian correction (numerically stable form)."""
    u = mean + log_std.exp() * eps
    log_prob = (-0.5 * eps.square() - log_std - 0.5 * math.log(2 * math.pi)).sum(-1)
    log_prob = log_prob - (2 * (math.log(2) - u - nn.functional.softplus(-2 * u))).sum(-1)
    return torch.tanh(u), log_prob


class EnsembleLinear(nn.Module):
    """n independent linear layers evaluated as one batched matmul (both critic heads in one kernel)."""

    def __init__(self, n: int, d_in: int, d_out: int):
        super().__init__()
        self.weight = nn.Parameter(torch.empty(n, d_in, d_out))
        self.bias = nn.Parameter(torch.empty(n, 1, d_out))
        bound = 1.0 / math.sqrt(d_in)  # nn.Linear's default init, per head
        nn.init.uniform_(self.weight, -bound, bound)
        nn.init.uniform_(self.bias, -bound, bound)

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # (n, B, d_in) → (n, B, d_out)
        return torch.baddbmm(self.bias, x, self.weight)


class EnsembleLayerNorm(nn.Module):
    def __init__(self, n: int, d: int):
        super().__init__()
        self.weight = nn.Parameter(torch.ones(n, 1, d))
        self.bias = nn.Parameter(torch.zeros(n, 1, d))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.addcmul(self.bias, nn.functional.layer_norm(x, x.shape[-1:]), self.weight)


class Critic(nn.Module):
    """Q_ψ(s, a, ã): a projector of s, then `num_heads` categorical heads over [proj(s) ‖ a ‖ ã].

    Returns logits (heads, B, atoms); Q is the expectation of softmax(logits) over the support.
    """

    def __init__(
        self,
        state_dim: int,
        horizon: int,
        action_dim: int,
        hidden: list[int],
        projector_dim: int,
        num_atoms: int,
        layer_norm: bool = True,
        num_heads: int = 2,
    ):
        super().__init__()
        self.num_heads = num_heads
        self.proj = projector(state_dim, projector_dim)
        sizes = [projector_dim + 2 * horizon * action_dim, *hidden, num_atoms]
        layers: list[nn.Module] = []
        for i in range(len(sizes) - 1):
            layers.append(EnsembleLinear(num_heads, sizes[i], sizes[i + 1]))
            if i < len(sizes) - 2:
                if layer_norm:
                    layers.append(EnsembleLayerNorm(num_heads, sizes[i + 1]))
                layers.append(nn.SiLU())
        self.net = nn.Sequential(*layers)

    def forward(self, state_normed: torch.Tensor, action: torch.Tensor, ref: torch.Tensor) -> torch.Tensor:
        x = torch.cat([self.proj(state_normed), action.flatten(1), ref.flatten(1)], -1)
        return self.net(x.unsqueeze(0).expand(self.num_heads, -1, -1))
