"""Acting: shapes and bounds, residual start at the reference, per-env noise, no-reference ablation, dropout."""

import numpy as np
import pytest
import torch

from accrue.learner import LearnerConfig, make_learner

D, H, A = 5, 4, 6
SMALL = dict(actor_hidden=[32], critic_hidden=[32], projector_dim=8, num_atoms=11, batch_size=8)


@pytest.mark.parametrize("algo", ["fasttd3", "fastsac"])
def test_act_starts_at_reference_and_stays_in_bounds(algo):
    lr = make_learner(LearnerConfig(algo=algo, **SMALL), D, H, A)
    g = torch.Generator().manual_seed(0)
    s, ref = torch.randn(16, D, generator=g), torch.rand(16, H, A, generator=g) * 1.8 - 0.9
    greedy = lr.act(s, ref, explore=False)
    assert greedy.shape == (16, H, A)
    assert (greedy - ref).abs().max() < 0.05  # residual actor: a ≈ ã before any training
    explore = lr.act(s.numpy(), ref.numpy(), explore=True)
    assert isinstance(explore, np.ndarray) and explore.dtype == np.float32
    assert np.abs(explore).max() <= 1.0 and not np.allclose(explore, greedy.numpy())


def test_fasttd3_noise_std_per_env_redrawn_on_reset():
    lr = make_learner(LearnerConfig(**SMALL, std_min=0.05, std_max=0.3), D, H, A)
    s, ref = torch.zeros(6, D), torch.zeros(6, H, A)
    lr.act(s, ref)
    first = lr.noise_std.clone()
    assert first.shape == (6,) and ((first >= 0.05) & (first <= 0.3)).all() and first.unique().numel() == 6
    lr.act(s, ref, reset_mask=np.array([True, False, False, False, False, True]))
    assert torch.equal(lr.noise_std[1:5], first[1:5])
    assert lr.noise_std[0] != first[0] and lr.noise_std[5] != first[5]


def test_no_reference_ablation_actor_ignores_reference():
    lr = make_learner(LearnerConfig(**SMALL, ablation="no-reference"), D, H, A)
    s = torch.randn(4, D)
    a1 = lr.act(s, torch.full((4, H, A), 0.5), explore=False)
    a2 = lr.act(s, torch.full((4, H, A), -0.5), explore=False)
    assert torch.equal(a1, a2)
    normal = make_learner(LearnerConfig(**SMALL), D, H, A)
    assert not torch.equal(
        normal.act(s, torch.full((4, H, A), 0.5), explore=False),
        normal.act(s, torch.full((4, H, A), -0.5), explore=False),
    )


def test_reference_dropout_fraction():
    lr = make_learner(LearnerConfig(**SMALL, ref_dropout=0.3), D, H, A)
    keep = lr._dropout_keep(20000)
    assert keep.shape == (20000, 1, 1)
    assert abs(1 - keep.mean().item() - 0.3) < 0.02
    assert make_learner(LearnerConfig(**SMALL, ref_dropout=0.0), D, H, A)._dropout_keep(100).min() == 1.0
