"""The paper's losses, one function per equation (Sec. IV-B, IV-C).

Norms are squared L2 over the whole chunk (H × d), averaged over the batch.
"""

from __future__ import annotations

import torch

from accrue.learner.distributional import categorical_cross_entropy, expected_value, project_target


def chunk_sq_dist(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """‖a − b‖²₂ per sample over the flattened chunk → (B,)."""
    return (a - b).flatten(1).square().sum(-1)


def actor_loss_current(
    q: torch.Tensor,
    action: torch.Tensor,
    ref: torch.Tensor,
    beta: float,
    log_prob: torch.Tensor | None = None,
    alpha: torch.Tensor | float = 0.0,
) -> torch.Tensor:
    """Eq. 1:  L_cur(θ; B^k) = E[ −Q_ψ(s, a, ã) + β‖a − ã‖² ]   (a ~ π_θ(s, ã)).

    FastSAC adds its entropy term α·log π(a|s, ã) to the same expectation.
    """
    loss = -q + beta * chunk_sq_dist(action, ref)
    if log_prob is not None:
        loss = loss + alpha * log_prob
    return loss.mean()


def distill_loss_prior(student: torch.Tensor, teacher: torch.Tensor) -> torch.Tensor:
    """Eq. 4:  L_prior(θ; B^{<k}) = E_j[ ‖π_θ(s_j, ã_j) − â_j^{k−1}‖² ]."""
    return chunk_sq_dist(student, teacher).mean()


def actor_loss_total(loss_cur: torch.Tensor, loss_prior: torch.Tensor | None, lam: float) -> torch.Tensor:
    """Eq. 5:  L_π(θ; k) = L_cur + λ · L_prior."""
    return loss_cur if loss_prior is None else loss_cur + lam * loss_prior


def td_target(
    next_logits: torch.Tensor,
    reward: torch.Tensor,
    discount: torch.Tensor,
    support: torch.Tensor,
    use_cdq: bool,
    entropy_bonus: torch.Tensor | None = None,
) -> torch.Tensor:
    """Eq. 2 as a distribution: R^(H) + γ^H · Z_ψ'(s_{t+H}, a_{t+H}, ã_{t+H}), projected on the support.

    next_logits (heads, B, N) from the target critic. With clipped double-Q (FastTD3) each sample uses the
    head whose expected value is smaller; otherwise the heads' distributions are averaged. FastSAC folds
    its entropy term into the reward: R − γ^H α log π(a_{t+H}) (pass it as `entropy_bonus` = −α log π).
    """
    probs = torch.softmax(next_logits, -1)
    if use_cdq:
        q = expected_value(probs, support)  # (heads, B)
        pick = q.argmin(0)  # (B,)
        probs = probs.gather(0, pick.view(1, -1, 1).expand(1, -1, probs.shape[-1])).squeeze(0)
    else:
        probs = probs.mean(0)
    if entropy_bonus is not None:
        reward = reward + discount * entropy_bonus
    return project_target(probs, reward, discount, support)


def critic_loss(logits: torch.Tensor, target_probs: torch.Tensor) -> torch.Tensor:
    """Cross-entropy of every head (heads, B, N) to the projected target (B, N), summed over heads."""
    return sum(categorical_cross_entropy(logits[h], target_probs) for h in range(logits.shape[0]))


def ewc_penalty(
    params: dict[str, torch.Tensor], anchor: dict[str, torch.Tensor], fisher: dict[str, torch.Tensor]
) -> torch.Tensor:
    """EWC: Σ_i F_i (θ_i − θ*_i)², over the actor parameters that have a Fisher estimate."""
    return sum((fisher[k] * (params[k] - anchor[k]).square()).sum() for k in fisher)
