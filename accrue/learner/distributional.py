"""The categorical (C51) return distribution behind Q_ψ: support, projection of the Eq. 2 target, loss.

Q_ψ(s, a, ã) in the paper is the expectation of a categorical distribution over a fixed support
z_0 < … < z_{N−1} in [v_min, v_max]; the critic is trained by cross-entropy to the H-step target
R^(H) + γ^H · Z'(s_{t+H}, a_{t+H}, ã_{t+H}) projected back onto the support (Eq. 2).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F


def make_support(v_min: float, v_max: float, num_atoms: int, device=None) -> torch.Tensor:
    return torch.linspace(v_min, v_max, num_atoms, device=device)


def expected_value(probs: torch.Tensor, support: torch.Tensor) -> torch.Tensor:
    """Q = Σ_i p_i z_i over the last dim."""
    return (probs * support).sum(-1)


def project_target(
    next_probs: torch.Tensor, reward: torch.Tensor, discount: torch.Tensor, support: torch.Tensor
) -> torch.Tensor:
    """Eq. 2 on distributions: the mass of atom z_i moves to r + discount·z_i, clipped to the support and
    split between its two neighbouring atoms in proportion to distance (the C51 projection).

    next_probs (B, N) · reward (B,) · discount (B,) = γ^H (or γ^{nH}) · (1 − done) → (B, N).
    """
    v_min, v_max = float(support[0]), float(support[-1])
    n = support.numel()
    delta = (v_max - v_min) / (n - 1)
    tz = (reward.unsqueeze(-1) + discount.unsqueeze(-1) * support).clamp(v_min, v_max)
    b = ((tz - v_min) / delta).clamp(0, n - 1)  # fractional atom index of each moved atom
    lower, upper = b.floor().long(), b.ceil().long()
    w_upper = b - lower  # share that goes to the upper neighbour
    w_lower = 1.0 - w_upper  # (exact hits, lower == upper, keep all mass)
    out = torch.zeros_like(next_probs)
    out.scatter_add_(-1, lower, next_probs * w_lower)
    out.scatter_add_(-1, upper, next_probs * w_upper)
    return out


def categorical_cross_entropy(logits: torch.Tensor, target_probs: torch.Tensor) -> torch.Tensor:
    """−Σ_i p̂_i log softmax(logits)_i, averaged over the batch (leading dims are heads/batch)."""
    return -(target_probs * F.log_softmax(logits, dim=-1)).sum(-1).mean()
