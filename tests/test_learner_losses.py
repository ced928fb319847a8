"""Eq. 1–5 and the C51 projection against hand-computed / brute-force values on tiny tensors."""

import math

import pytest
import torch

from accrue.errors import AccrueError
from accrue.learner import LearnerConfig, losses
from accrue.learner.distributional import expected_value, make_support, project_target


def brute_force_projection(probs, reward, discount, support):
    """C51 by hand: move each atom, clip, split its mass between the two neighbouring atoms."""
    v_min, v_max = float(support[0]), float(support[-1])
    n = len(support)
    dz = (v_max - v_min) / (n - 1)
    out = [[0.0] * n for _ in range(len(probs))]
    for b in range(len(probs)):
        for i in range(n):
            tz = min(max(float(reward[b]) + float(discount[b]) * float(support[i]), v_min), v_max)
            pos = (tz - v_min) / dz
            lo = math.floor(pos + 1e-9) if abs(pos - round(pos)) < 1e-6 else math.floor(pos)
            if abs(pos - round(pos)) < 1e-6:  # lands on an atom: all the mass there
                out[b][int(round(pos))] += float(probs[b][i])
                continue
            out[b][lo] += float(probs[b][i]) * (lo + 1 - pos)
            out[b][lo + 1] += float(probs[b][i]) * (pos - lo)
    return torch.tensor(out)


def test_projection_matches_brute_force():
    g = torch.Generator().manual_seed(0)
    support = make_support(-1.0, 4.0, 11)
    probs = torch.softmax(torch.randn(64, 11, generator=g), -1)
    reward = torch.rand(64, generator=g) * 6 - 2  # includes out-of-support targets (clipping)
    discount = (torch.rand(64, generator=g) > 0.2).float() * 0.9
    discount[:3] = 0.0  # terminal: all mass on the reward's atoms
    reward[3] = 0.5  # exact atom hit with discount 1
    discount[3] = 1.0
    got = project_target(probs, reward, discount, support)
    want = brute_force_projection(probs, reward, discount, support)
    assert torch.allclose(got, want, atol=1e-5)
    assert torch.allclose(got.sum(-1), torch.ones(64), atol=1e-5)


def test_projection_terminal_reward_mean():
    support = make_support(0.0, 3.0, 4)  # atoms 0,1,2,3
    probs = torch.tensor([[0.1, 0.2, 0.3, 0.4]])
    got = project_target(probs, torch.tensor([1.25]), torch.tensor([0.0]), support)
    assert torch.allclose(got, torch.tensor([[0.0, 0.75, 0.25, 0.0]]))
    assert expected_value(got, support).item() == pytest.approx(1.25)


def test_eq1_actor_loss_by_hand():
    q = torch.tensor([1.0, 2.0])
    a = torch.zeros(2, 2, 1)
    ref = torch.tensor([[[1.0], [0.0]], [[1.0], [1.0]]])  # ‖a − ã‖² = 1 and 2
    # mean(−1 + 0.5·1, −2 + 0.5·2) = mean(−0.5, −1) = −0.75
    assert losses.actor_loss_current(q, a, ref, beta=0.5).item() == pytest.approx(-0.75)
    # FastSAC adds α log π: α = 0.1, log π = (−2, 4) → −0.75 + 0.1 · 1 = −0.65
    lp = torch.tensor([-2.0, 4.0])
    assert losses.actor_loss_current(q, a, ref, 0.5, lp, 0.1).item() == pytest.approx(-0.65)


def test_eq4_eq5_by_hand():
    student = torch.tensor([[[0.5, 0.0]], [[0.0, 0.0]]])
    teacher = torch.tensor([[[0.0, 0.0]], [[1.0, -1.0]]])  # squared distances 0.25 and 2
    prior = losses.distill_loss_prior(student, teacher)
    assert prior.item() == pytest.approx(1.125)
    total = losses.actor_loss_total(torch.tensor(-0.75), prior, lam=2.0)
    assert total.item() == pytest.approx(-0.75 + 2.25)
    assert losses.actor_loss_total(torch.tensor(3.0), None, lam=2.0).item() == 3.0


def test_eq2_target_uses_cdq_and_entropy():
    support = make_support(0.0, 2.0, 3)  # atoms 0, 1, 2
    # head 0 expects 2, head 1 expects 0 → CDQ takes head 1 (all mass on atom 0)
    logits = torch.log(torch.tensor([[[1e-6, 1e-6, 1.0]], [[1.0, 1e-6, 1e-6]]]))
    t = losses.td_target(logits, torch.tensor([1.0]), torch.tensor([0.5]), support, use_cdq=True)
    assert torch.allclose(t, torch.tensor([[0.0, 1.0, 0.0]]), atol=1e-4)
    # without CDQ the heads are averaged: atoms 0 and 2 half each → r + 0.5·z = 1 or 2
    t = losses.td_target(logits, torch.tensor([1.0]), torch.tensor([0.5]), support, use_cdq=False)
    assert torch.allclose(t, torch.tensor([[0.0, 0.5, 0.5]]), atol=1e-4)
    # entropy folded into the reward: r + γ·(−α log π) = 1 + 0.5·(−2) = 0 with the CDQ head's z = 0
    t = losses.td_target(logits, torch.tensor([1.0]), torch.tensor([0.5]), support, True, torch.tensor([-2.0]))
    assert torch.allclose(t, torch.tensor([[1.0, 0.0, 0.0]]), atol=1e-4)


def test_critic_cross_entropy_by_hand():
    logits = torch.zeros(2, 1, 4)  # uniform: −log(1/4) per head
    target = torch.tensor([[0.0, 1.0, 0.0, 0.0]])
    assert losses.critic_loss(logits, target).item() == pytest.approx(2 * math.log(4))


def test_ewc_penalty_by_hand():
    p = {"w": torch.tensor([1.0, 2.0])}
    anchor = {"w": torch.tensor([0.0, 0.0])}
    fisher = {"w": torch.tensor([2.0, 0.5])}
    assert losses.ewc_penalty(p, anchor, fisher).item() == pytest.approx(2 * 1 + 0.5 * 4)


@pytest.mark.parametrize(
    "field,value",
    [
        ("num_atoms", 1),
        ("gamma", 1.5),
        ("method", "magic"),
        ("actor_hidden", []),
        ("v_max", -5.0),
        ("ref_dropout", 2.0),
        ("batch_size", "big"),
    ],
)
def test_config_rejects_bad_values_naming_field(field, value):
    with pytest.raises(AccrueError, match=f"learner.{field}"):
        LearnerConfig.from_dict({field: value})


def test_config_roundtrip_and_unknown_field():
    cfg = LearnerConfig(algo="fastsac", actor_hidden=[64, 32], method="ewc")
    assert LearnerConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(AccrueError, match="learner.bogus"):
        LearnerConfig.from_dict({"bogus": 1})
    with pytest.raises(AccrueError, match="learner.ablation"):
        LearnerConfig(method="er", ablation="beta0")
    assert LearnerConfig(ablation="beta0").effective_beta == 0.0


def test_running_norm_matches_batch_statistics():
    from accrue.learner.networks import RunningNorm

    g = torch.Generator().manual_seed(0)
    parts = [torch.randn(n, 3, generator=g) * 2 + 1 for n in (5, 17, 40)]
    norm = RunningNorm(3)
    for p in parts:
        norm.update(p)
    x = torch.cat(parts)
    assert torch.allclose(norm.mean, x.mean(0), atol=1e-5)
    assert torch.allclose(norm.var, x.var(0, unbiased=False), atol=1e-4)
    assert torch.allclose(norm(x).mean(0), torch.zeros(3), atol=1e-4)


def test_config_accepts_yaml_style_float_strings():
    assert LearnerConfig.from_dict({"actor_lr": "1e-3"}).actor_lr == 1e-3
    with pytest.raises(AccrueError, match="learner.actor_lr"):
        LearnerConfig.from_dict({"actor_lr": "fast"})
