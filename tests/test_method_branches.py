"""Branches no other test reached (issue 23): EWC's Fisher and penalty against a hand computation, and
the `not-higher` claim verdict. Planted bugs named:
    ewc-fisher-not-squared   the per-sample score is summed without squaring
    ewc-fisher-not-averaged  the Fisher is a sum over samples instead of their mean
    claim-not-higher-flipped the not-higher verdict contradicted when the reference is lower
"""

from __future__ import annotations

import pytest
import torch

from accrue.learner import LearnerConfig, ReplayBuffer, estimate_fisher, make_learner
from accrue.learner.losses import ewc_penalty
from stages.bench.claims import CONTRADICTED, HOLDS, NO_DATA, verdict

pytestmark = pytest.mark.usefixtures("one_torch_thread")

D, H, A, N = 5, 2, 3, 40


def small_learner():
    cfg = LearnerConfig(
        method="ewc", actor_hidden=[8], critic_hidden=[8], projector_dim=4, num_atoms=11, actor_init_scale=1.0
    )
    return make_learner(cfg, D, H, A)


def batch():
    g = torch.Generator().manual_seed(3)
    buf = ReplayBuffer(D, H, A)
    buf.add(
        torch.randn(N, D, generator=g),
        torch.rand(N, H, A, generator=g) * 1.6 - 0.8,
        torch.rand(N, H, A, generator=g) * 1.6 - 0.8,
        torch.zeros(N),
        torch.randn(N, D, generator=g),
        torch.rand(N, H, A, generator=g) * 1.6 - 0.8,
        torch.zeros(N, dtype=torch.bool),
        0,
        torch.arange(N) // 4,
    )
    return buf.gather(torch.arange(N))


def test_ewc_fisher_of_the_last_layer_by_hand_ewc_fisher_not_squared():
    """Mutations ewc-fisher-not-squared / -not-averaged. The actor's output is a = tanh(atanh(ã) + W h + b),
    so the projected score v·∂a/∂b_o = v_o (1 − a_o²) and v·∂a/∂W_oj = v_o (1 − a_o²) h_j. With the same
    draws v ~ N(0, I) as estimate_fisher: F_b = mean_i [v_io (1 − a_io²)]², F_W = mean_i [v_io (1 − a_io²) h_ij]²."""
    learner, b = small_learner(), batch()
    fisher = estimate_fisher(learner, b, generator=torch.Generator().manual_seed(9))
    v = torch.randn((N, H * A), generator=torch.Generator().manual_seed(9))  # one chunk of ≤ 128 rows
    actor = learner.actor
    with torch.no_grad():
        a = actor.deterministic(b.state, b.ref).flatten(1)
        h = actor.act_fn(actor.trunk(torch.cat([actor.proj(actor.obs_norm(b.state)), b.ref.flatten(1)], -1)))
    score = v * (1 - a**2)  # (N, H·A)
    torch.testing.assert_close(fisher["head.bias"], score.square().mean(0))
    torch.testing.assert_close(fisher["head.weight"], (score[:, :, None] * h[:, None, :]).square().mean(0))
    assert all((f >= 0).all() for f in fisher.values())


def test_ewc_penalty_by_hand():
    """Σ_i F_i (θ_i − θ*_i)² over the parameters with a Fisher, nothing else."""
    params = {"w": torch.tensor([1.0, 2.0]), "b": torch.tensor([0.5]), "free": torch.tensor([9.0])}
    anchor = {"w": torch.tensor([0.0, 1.0]), "b": torch.tensor([1.5]), "free": torch.tensor([0.0])}
    fisher = {"w": torch.tensor([2.0, 3.0]), "b": torch.tensor([4.0])}
    assert float(ewc_penalty(params, anchor, fisher)) == pytest.approx(2 * 1 + 3 * 1 + 4 * 1)


@pytest.mark.parametrize(
    "lo, hi, want",
    [
        (-0.2, -0.05, CONTRADICTED),  # d = method − reference < 0 for sure: the reference is higher
        (-0.2, 0.1, HOLDS),  # not shown higher
        (0.05, 0.2, HOLDS),  # the reference is lower: not higher holds
        (None, None, NO_DATA),
    ],
)
def test_not_higher_verdict_claim_not_higher_flipped(lo, hi, want):
    assert verdict("not-higher", lo, hi) == want


def test_not_higher_is_the_mirror_of_not_lower():
    for lo, hi in [(-0.2, -0.05), (-0.2, 0.1), (0.05, 0.2)]:
        assert verdict("not-higher", lo, hi) == verdict("not-lower", -hi, -lo)
