"""Exploration noise correlated in time (learner.exploration "ou") and the bounded residual
(learner.delta_bound): what each promises, on the real learner."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from accrue.errors import AccrueError
from accrue.learner import LearnerConfig, load_learner, make_learner, save_learner
from accrue.learner.networks import pre_tanh

S, H, D = 5, 4, 6


def learner(**kw):
    cfg = LearnerConfig(actor_hidden=[16], critic_hidden=[16], projector_dim=8, num_atoms=11, **kw)
    return make_learner(cfg, S, H)


def noise_of(lrn, chunks: int, n: int = 256, reset_every: int | None = None) -> np.ndarray:
    """The exploration noise a − π_θ(s, ã) of `chunks` consecutive chunks, as (n, chunks·H, d), at ã = 0
    where nothing clamps; std fixed at 0.2 for every env."""
    s, ref = np.zeros((n, S), np.float32), np.zeros((n, H, D), np.float32)
    lrn.noise_std = torch.full((n,), 0.2)
    clean = lrn.act(s, ref, explore=False)
    out = []
    for c in range(chunks):
        reset = np.full(n, reset_every is not None and c > 0 and c % reset_every == 0)
        out.append(lrn.act(s, ref, explore=True, reset_mask=reset) - clean)
    return np.concatenate(out, axis=1) / 0.2


def lag_correlation(x: np.ndarray, lag: int) -> float:
    a, b = x[:, :-lag].ravel(), x[:, lag:].ravel()
    return float(np.corrcoef(a, b)[0, 1])


def test_ou_noise_is_unit_variance_and_correlated_across_chunk_boundaries():
    x = noise_of(learner(exploration="ou", noise_steps=16.0), chunks=8)
    assert abs(x.std() - 1.0) < 0.05
    rho = math.exp(-1 / 16)
    for lag in (1, 4, 8):  # lags 4 and 8 cross one and two chunk boundaries
        assert abs(lag_correlation(x, lag) - rho**lag) < 0.05
    white = noise_of(learner(), chunks=8)
    assert abs(lag_correlation(white, 1)) < 0.05  # FastTD3's default is uncorrelated


def test_ou_noise_restarts_when_an_env_resets():
    x = noise_of(learner(exploration="ou", noise_steps=1000.0), chunks=4, reset_every=2)
    # nearly constant within an episode; independent across the reset between chunk 1 and 2
    assert lag_correlation(x[:, : 2 * H], 1) > 0.99
    assert abs(float(np.corrcoef(x[:, 2 * H - 1].ravel(), x[:, 2 * H].ravel())[0, 1])) < 0.1


def test_ou_noise_state_is_saved_with_the_learner(tmp_path):
    a = learner(exploration="ou", noise_steps=8.0)
    noise_of(a, chunks=2)
    save_learner(a, tmp_path / "l")
    b = load_learner(tmp_path / "l")
    assert torch.equal(a.noise_state, b.noise_state)
    np.testing.assert_array_equal(noise_of(a, chunks=2), noise_of(b, chunks=2))


def test_bounded_residual_keeps_the_action_within_the_bound_of_the_reference():
    lrn = learner(delta_bound=0.5)
    with torch.no_grad():  # an actor pushed hard one way: δ_raw ≈ 200 on every output
        lrn.actor.head.bias.fill_(200.0)
    ref = torch.full((3, H, D), 0.3)
    s = torch.zeros(3, S)
    delta = lrn.actor.pre_tanh_mean(s, ref) - pre_tanh(ref.flatten(1))
    assert torch.all(delta <= 0.5) and torch.all(delta > 0.49)
    unbounded = learner()
    with torch.no_grad():
        unbounded.actor.head.bias.fill_(200.0)
    assert torch.all(unbounded.actor.pre_tanh_mean(s, ref) - pre_tanh(ref.flatten(1)) > 100)


@pytest.mark.parametrize(
    "kw, words",
    [
        ({"exploration": "pink"}, "learner.exploration: must be one of white, ou"),
        ({"noise_steps": 0.5}, "learner.noise_steps: must be at least 1"),
        ({"delta_bound": -1.0}, "learner.delta_bound: must be non-negative"),
        ({"exploration": "ou", "algo": "fastsac"}, "learner.exploration: 'ou' is FastTD3's"),
    ],
)
def test_bad_exploration_settings_are_one_line_errors(kw, words):
    with pytest.raises(AccrueError, match=words):
        LearnerConfig(**kw)


def filled_buffer(n: int):
    from accrue.learner.replay import ReplayBuffer

    g = torch.Generator().manual_seed(0)
    buf = ReplayBuffer(S, H, D)
    buf.add(
        torch.randn(n, S, generator=g),
        torch.rand(n, H, D, generator=g) * 2 - 1,
        torch.rand(n, H, D, generator=g) * 1.6 - 0.8,
        (torch.rand(n, generator=g) > 0.7).float(),
        torch.randn(n, S, generator=g),
        torch.rand(n, H, D, generator=g) * 1.6 - 0.8,
        torch.rand(n, generator=g) > 0.9,
        0,
        torch.arange(n) // 8,
    )
    return buf


def params(module) -> list[torch.Tensor]:
    return [p.detach().clone() for p in module.parameters()]


def moved(before, module) -> bool:
    return any(not torch.equal(b, p) for b, p in zip(before, module.parameters(), strict=True))


def test_actor_waits_for_its_own_learning_start_while_the_critic_learns():
    lrn = learner(actor_learning_starts=64, batch_size=16, utd=2, policy_frequency=1)
    actor0, critic0 = params(lrn.actor), params(lrn.critic)
    info = lrn.train_step(filled_buffer(63))
    assert moved(critic0, lrn.critic) and not moved(actor0, lrn.actor)
    assert "actor_loss" not in info and lrn.counters["actor_updates"] == 0
    info = lrn.train_step(filled_buffer(64))  # the boundary: 64 transitions are enough
    assert moved(actor0, lrn.actor) and "actor_loss" in info and lrn.counters["actor_updates"] == 2


def test_bad_actor_learning_start_is_a_one_line_error():
    with pytest.raises(AccrueError, match="learner.actor_learning_starts: must be a non-negative integer"):
        LearnerConfig(actor_learning_starts=-1)


def test_anchor_beta_ramps_from_its_start_to_beta_over_the_stage_first_actor_updates():
    lrn = learner(beta=0.05, beta_start=1.0, beta_anneal_updates=10)
    seen = []
    for done in (0, 5, 10, 40):
        lrn.counters["actor_updates"] = done
        seen.append(float(lrn.anchor_beta()))
    assert seen == pytest.approx([1.0, 0.525, 0.05, 0.05])
    assert learner(beta=0.05, beta_start=1.0).anchor_beta() == 0.05  # no ramp: the paper's constant β
    no_anchor = learner(method="accrue", ablation="beta0", beta_start=1.0, beta_anneal_updates=10)
    assert no_anchor.anchor_beta() == 0.0  # the no-anchor ablation stays at β = 0


def test_the_ramped_anchor_reaches_eq1_and_holds_the_actor_nearer_the_reference():
    def offset_after_updates(**kw) -> float:
        lrn = learner(batch_size=32, utd=4, policy_frequency=1, actor_lr=3e-3, **kw)
        buf = filled_buffer(256)
        for _ in range(10):
            lrn.train_step(buf)
        b = buf.sample(64, torch.Generator().manual_seed(1), 1, 0.99)
        a = lrn.act(b.state.numpy(), b.ref.numpy(), explore=False)
        return float((pre_tanh(torch.as_tensor(a)) - pre_tanh(b.ref)).abs().mean())

    constant = offset_after_updates(beta=0.0)
    ramped = offset_after_updates(beta=0.0, beta_start=10.0, beta_anneal_updates=1000)
    assert ramped < 0.5 * constant  # the same seed and data: only the anchor's weight differs


def test_bad_beta_ramp_is_a_one_line_error():
    with pytest.raises(AccrueError, match="learner.beta_anneal_updates: must be a non-negative integer"):
        LearnerConfig(beta_anneal_updates=-5)
    with pytest.raises(AccrueError, match="learner.beta_start: must be non-negative"):
        LearnerConfig(beta_start=-0.1)
