"""Tests written to kill mutants of accrue/learner/agent.py, td3.py and sac.py that survived mutmut's second
sweep (docs/MUTATION.md). Each test's docstring names the mutmut ids it kills.

The expected values are the formulas of the module docstrings written out again, drawing the same random
numbers from a copy of the learner's generator (all of a learner's randomness comes from `learner.gen`).
Tiny networks from tests/test_method_wiring.py's config.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_method_wiring import BATCH, A, D, H, config, memory_buffer  # noqa: E402

from accrue.errors import AccrueError  # noqa: E402
from accrue.learner import ReplayBuffer, losses, make_learner  # noqa: E402
from accrue.learner.distributional import expected_value  # noqa: E402
from accrue.learner.networks import tanh_gaussian_sample  # noqa: E402

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def gen_copy(learner) -> torch.Generator:
    g = torch.Generator()
    g.set_state(learner.gen.get_state())
    return g


def inputs(n: int, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    return torch.randn(n, D, generator=g) * 2, torch.rand(n, H, A, generator=g) * 2 - 1


# ------------------------------------------------------------------------------------------- FastTD3
def test_td3_exploration_std_per_env_redrawn_on_reset_and_clamped_noise_by_hand():
    """Survivors td3._draw_std 6, 9 (the std from the learner's generator), td3._explore 29, 31, 34
    (a + ε·σ_env with ε from the learner's generator), 47-53 (clamped to [-1, 1])."""
    learner = make_learner(config("accrue", std_min=0.3, std_max=0.9), D, H, A)
    s, ref = inputs(3)
    g = gen_copy(learner)
    with torch.no_grad():
        mu = learner.actor(s, ref)
    std = 0.3 + 0.6 * torch.rand(3, generator=g)
    want = (mu + torch.randn(mu.shape, generator=g) * std.view(-1, 1, 1)).clamp(-1, 1)
    got = learner.act(s, ref, explore=True)
    torch.testing.assert_close(learner.noise_std, std)
    torch.testing.assert_close(got, want)
    # the noise is large enough to push some entries past both bounds
    assert (got == 1.0).any() and (got == -1.0).any() and ((got > -1) & (got < 1)).any()
    # env 1 resets: only its std is redrawn (a draw for every env, kept where the mask is set)
    new = 0.3 + 0.6 * torch.rand(3, generator=g)
    std = torch.stack([std[0], new[1], std[2]])
    want = (mu + torch.randn(mu.shape, generator=g) * std.view(-1, 1, 1)).clamp(-1, 1)
    got = learner.act(s, ref, explore=True, reset_mask=[False, True, False])
    torch.testing.assert_close(learner.noise_std, std)
    torch.testing.assert_close(got, want)


def test_td3_target_smoothing_noise_and_next_action_by_hand():
    """Survivors td3._target_noise 3, 10-14 (ε·policy_noise, clipped to ±noise_clip), td3._next_action 1-5,
    10-12 (π_θ(s', ã') + noise, clamped to [-1, 1], no entropy bonus)."""
    learner = make_learner(config("accrue", policy_noise=0.4, noise_clip=0.5), D, H, A)
    g = gen_copy(learner)
    want = (torch.randn(7, H, A, generator=g) * 0.4).clamp(-0.5, 0.5)
    noise = learner._target_noise((7, H, A))
    torch.testing.assert_close(noise, want)
    assert (noise.abs() == 0.5).any() and (noise.abs() < 0.5).any()
    s, ref = inputs(7, seed=1)
    big = torch.linspace(-1.5, 1.5, 7 * H * A).view(7, H, A)  # pushes π_θ + noise past both bounds
    with torch.no_grad():
        a, bonus = learner._next_action(s, ref, big)
        mu = learner.actor(s, ref)
    assert bonus is None
    assert ((mu + big) > 1).any() and ((mu + big) < -1).any()
    torch.testing.assert_close(a, (mu + big).clamp(-1, 1))


def test_td3_actor_q_is_the_min_of_the_heads_with_cdq_else_their_mean():
    """Survivors td3._actor_q 1, 2, 5, 6: min over the two heads with clipped double-Q, else their mean
    (over the heads, per row)."""
    q = torch.tensor([[1.0, -2.0, 3.0], [0.5, 4.0, -1.0]])
    cdq = make_learner(config("accrue", use_cdq=True), D, H, A)
    plain = make_learner(config("accrue", use_cdq=False), D, H, A)
    torch.testing.assert_close(cdq._actor_q(q), torch.tensor([0.5, -2.0, -1.0]))
    torch.testing.assert_close(plain._actor_q(q), torch.tensor([0.75, 1.0, 1.0]))


# ------------------------------------------------------------------------------------------- FastSAC
def sac(**kw):
    return make_learner(config("accrue", algo="fastsac", **kw), D, H, A)


def test_sac_actor_bounds_temperature_and_optimizers_come_from_the_config():
    """Survivors sac._make_actor 5, 6 (log σ bounds), sac.reset_optimizers 13, 15-17 (α's fused Adam at
    alpha_lr), sac.optimizers 1-2 and agent.optimizers 1-4 (the names a checkpoint stores them under)."""
    learner = sac(log_std_min=-3.0, log_std_max=0.5, alpha_init=0.2, alpha_lr=0.05)
    assert (learner.actor.log_std_min, learner.actor.log_std_max) == (-3.0, 0.5)
    assert learner.log_alpha.item() == pytest.approx(math.log(0.2))
    group = learner.alpha_opt.param_groups[0]
    assert group["lr"] == 0.05 and group["params"][0] is learner.log_alpha
    assert learner.alpha_opt.defaults["fused"] is True
    opts = learner.optimizers()
    assert opts == {"actor": learner.actor_opt, "critic": learner.critic_opt, "alpha": learner.alpha_opt}
    td3 = make_learner(config("accrue"), D, H, A)
    assert td3.optimizers() == {"actor": td3.actor_opt, "critic": td3.critic_opt}


def test_sac_exploration_samples_the_tanh_gaussian_with_the_learners_generator():
    """Survivors sac._explore 8, 9 (tanh(μ + σ·ε)), sac._gauss 2, 5 (ε from the learner's generator)."""
    learner = sac(log_std_min=-1.0, log_std_max=0.5)
    s, ref = inputs(4)
    g = gen_copy(learner)
    with torch.no_grad():
        mean, log_std = learner.actor.dist_params(s, ref)
    want = torch.tanh(mean + log_std.exp() * torch.randn(mean.shape, generator=g)).view(-1, H, A)
    torch.testing.assert_close(learner.act(s, ref, explore=True), want)


def test_sac_next_action_carries_the_entropy_bonus_minus_alpha_log_pi():
    """Survivors sac._next_action 13, 14: the bonus folded into Eq. 2's reward is −α·log π(a')."""
    learner = sac(alpha_init=0.5)
    s, ref = inputs(5)
    eps = torch.randn(5, H * A, generator=torch.Generator().manual_seed(3))
    with torch.no_grad():
        a, bonus = learner._next_action(s, ref, eps)
        mean, log_std = learner.actor.dist_params(s, ref)
    want_a, log_prob = tanh_gaussian_sample(mean, log_std, eps)
    torch.testing.assert_close(a, want_a.view(-1, H, A))
    torch.testing.assert_close(bonus, -0.5 * log_prob)


def test_sac_actor_q_is_the_mean_of_the_heads_per_row():
    """Survivor sac._actor_q 1: the mean over the heads (dim 0), one value per row."""
    q = torch.tensor([[1.0, -2.0, 3.0], [0.5, 4.0, -1.0]])
    torch.testing.assert_close(sac()._actor_q(q), torch.tensor([0.75, 1.0, 1.0]))


@pytest.mark.parametrize(
    "log_prob, direction",
    [
        ([30.0, 20.0], +1),  # log π + H̄ = (6, −4): mean +1 -> α grows (1/(log π + H̄) would shrink it)
        ([-10.0, -20.0], -1),  # (−34, −44): α shrinks (log π − H̄ = (14, 4) would grow it)
    ],
)
def test_sac_temperature_step_by_hand(log_prob, direction):
    """Survivors sac._after_actor_step 2-4 (loss −log α·(log π + H̄), H̄ = −1·H·d = −24), 7-11 (the reported
    α and entropy −mean log π). Adam's first step moves log α by lr against the gradient's sign."""
    learner = sac(alpha_init=0.2, alpha_lr=0.01)
    assert learner.target_entropy == -24.0
    before = learner.log_alpha.item()
    info = learner._after_actor_step(torch.tensor(log_prob))
    assert learner.log_alpha.item() == pytest.approx(before + direction * 0.01, abs=1e-6)
    assert set(info) == {"alpha", "entropy"}
    assert info["alpha"].item() == pytest.approx(math.exp(before + direction * 0.01), rel=1e-5)
    assert info["entropy"].item() == pytest.approx(-sum(log_prob) / 2)


# ------------------------------------------------------------------------------------------- ChunkLearner
def test_retain_deploys_its_own_actor_before_a_previous_actor_exists():
    """Survivor agent.deployed_actor 2: RETAIN at stage 1 (no θ_prev) deploys the training actor itself."""
    learner = make_learner(config("retain"), D, H, A)
    assert learner.retain_prev == {} and learner.deployed_actor() is learner.actor


def test_update_is_one_update_of_the_given_batches_as_floats():
    """Survivors agent.update 1-5: update(current, prior) is _update(current, prior) with float values
    (ER's critic reads both batches, so dropping the prior changes the loss)."""
    one, two = make_learner(config("er"), D, H, A), make_learner(config("er"), D, H, A)
    mem = memory_buffer()
    cur = one.sample(mem, BATCH)
    prior = one.sample(mem, BATCH)
    two.gen.set_state(one.gen.get_state())
    got = one.update(cur, prior)
    want = two._update(cur, prior)
    assert set(got) == set(want) and all(type(v) is float for v in got.values())
    assert got == {k: float(v) for k, v in want.items()}
    alone = make_learner(config("er"), D, H, A)._update(cur, None)
    assert float(alone["critic_loss"]) != got["critic_loss"]


def test_sample_uses_the_configured_n_step_return():
    """Survivor agent.sample 7: the learner samples with cfg.n_step and cfg.gamma from its own generator."""
    learner = make_learner(config("accrue", n_step=3, gamma=0.9), D, H, A)
    mem = memory_buffer()
    g = gen_copy(learner)
    got = learner.sample(mem, BATCH)
    want = mem.sample(BATCH, g, 3, 0.9)
    one_step = mem.sample(BATCH, gen_copy(learner), 1, 0.9)
    torch.testing.assert_close(got.next_state, want.next_state)
    torch.testing.assert_close(got.discount, want.discount)  # γ^{(m+1)H} of the last chunk reached
    assert one_step.discount is None and not torch.equal(want.next_state, one_step.next_state)


def rows_buffer(n: int, seed: int) -> ReplayBuffer:
    """n transitions of one task (episodes of 4 rows), rewards in [0, 1]."""
    g = torch.Generator().manual_seed(seed)
    buf = ReplayBuffer(D, H, A)
    chunk = lambda: torch.rand(n, H, A, generator=g) * 1.6 - 0.8  # noqa: E731
    buf.add(
        torch.randn(n, D, generator=g),
        chunk(),
        chunk(),
        torch.rand(n, generator=g),
        torch.randn(n, D, generator=g),
        chunk(),
        torch.zeros(n, dtype=torch.bool),
        0,
        torch.arange(n) // 4,
        ended=(torch.arange(n) % 4) == 3,
    )
    return buf


def test_train_step_starts_at_exactly_learning_starts_transitions():
    """Survivor agent.train_step 1: no update below learning_starts, updates from exactly that many on."""
    buf = rows_buffer(12, seed=0)
    assert make_learner(config("accrue", learning_starts=13), D, H, A).train_step(buf) == {}
    learner = make_learner(config("accrue", learning_starts=12), D, H, A)
    info = learner.train_step(buf)
    assert "critic_loss" in info and learner.counters["updates"] == 1


def test_train_step_uses_a_one_row_prior_memory_and_skips_an_empty_one():
    """Survivors agent.train_step 6, 7: ER replays a prior memory of a single row; an empty one is no prior."""
    buf = rows_buffer(12, seed=0)
    alone = make_learner(config("er"), D, H, A).train_step(buf)
    empty = make_learner(config("er"), D, H, A).train_step(buf, ReplayBuffer(D, H, A))
    assert empty == alone
    one_row = make_learner(config("er"), D, H, A).train_step(buf, rows_buffer(1, seed=5))
    assert one_row["critic_loss"] != alone["critic_loss"]


def test_train_step_without_teacher_targets_names_the_fix():
    """Survivors agent.train_step 26-29: the exact message when ACCRUE's prior memory has no Eq. 3 targets."""
    learner = make_learner(config("accrue"), D, H, A)
    with pytest.raises(AccrueError) as exc:
        learner.train_step(rows_buffer(12, seed=0), rows_buffer(8, seed=1))
    assert str(exc.value) == (
        "ACCRUE needs teacher targets for the prior memory (compute_teacher_targets at stage start)"
    )


def test_train_step_reports_the_mean_of_its_utd_updates():
    """Survivor agent.train_step 40: with utd = 2 each figure is the mean over the two updates, the same
    updates a second learner makes by hand (sample, feed the normaliser, _update)."""
    buf = rows_buffer(12, seed=0)
    learner = make_learner(config("accrue", utd=2), D, H, A)
    twin = make_learner(config("accrue", utd=2), D, H, A)
    got = learner.train_step(buf)
    infos = []
    for _ in range(2):
        cur = twin.sample(buf, BATCH)
        twin.actor.obs_norm.update(cur.state)
        infos.append({k: float(v) for k, v in twin._update(cur, None).items()})
    assert set(got) == set(infos[0])
    for k in got:
        assert got[k] == pytest.approx((infos[0][k] + infos[1][k]) / 2, rel=1e-6)
    assert infos[0]["critic_loss"] > 0 and got["critic_loss"] > 0


# ---------------------------------------------------------------------------- one update, written out
def twin_learners(method, **kw):
    cfg = config(method, **kw)
    return make_learner(cfg, D, H, A), make_learner(cfg, D, H, A)


def same_params(a: torch.nn.Module, b: torch.nn.Module):
    for (na, pa), (nb, pb) in zip(a.named_parameters(), b.named_parameters()):
        assert na == nb
        torch.testing.assert_close(pa, pb, rtol=1e-5, atol=1e-6, msg=na)


def clip_and_step(params, opt, max_norm):
    if max_norm > 0:
        total = torch.sqrt(sum(p.grad.square().sum() for p in params))
        assert float(total) > max_norm  # the clip is active
        scale = min(1.0, max_norm / (float(total) + 1e-6))
        for p in params:
            p.grad.mul_(scale)
    opt.step()


@pytest.mark.parametrize("algo", ["fasttd3", "fastsac"])
@pytest.mark.parametrize("max_grad_norm", [0.0, 0.05])
def test_critic_update_by_hand(algo, max_grad_norm):
    """Survivors of agent._critic_update and agent._critic_loss: reference dropout drawn first from the
    learner's generator and applied to ã and ã' alike, then the target noise; Eq. 2's target from the
    target critic at π(s', ã'·keep) (+ noise, or SAC's −α log π bonus), the critics on normalised states,
    the cross-entropy summed over heads, clipped to max_grad_norm when > 0, one AdamW step, and the
    reported loss and mean Q."""
    learner, twin = twin_learners("accrue", algo=algo, ref_dropout=0.5, max_grad_norm=max_grad_norm, gamma=0.9)
    b = learner.sample(rows_buffer(16, seed=2), BATCH)
    twin.gen.set_state(learner.gen.get_state())
    for one in (learner, twin):
        one.actor.obs_norm.update(b.state * 3 + 1)  # a normaliser that is not the identity
    info = learner._critic_update(b)

    g = gen_copy(twin)
    n = len(b)
    keep = (torch.rand(n, generator=g) >= 0.5).float().view(n, 1, 1)
    assert 0 < keep.sum() < n
    norm = twin.actor.obs_norm
    with torch.no_grad():
        ref_next = b.next_ref * keep
        if algo == "fasttd3":
            noise = (torch.randn(b.action.shape, generator=g) * twin.cfg.policy_noise).clamp(
                -twin.cfg.noise_clip, twin.cfg.noise_clip
            )
            a_next, bonus = (twin.actor(b.next_state, ref_next) + noise).clamp(-1, 1), None
        else:
            eps = torch.randn(n, H * A, generator=g)
            mean, log_std = twin.actor.dist_params(b.next_state, ref_next)
            a_next, log_prob = tanh_gaussian_sample(mean, log_std, eps)
            a_next, bonus = a_next.view(-1, H, A), -twin.alpha * log_prob
        discount = 0.9**H * (1 - b.done)
        target = losses.td_target(
            twin.critic_target(norm(b.next_state), a_next, ref_next), b.reward, discount, twin.support, True, bonus
        )
    logits = twin.critic(norm(b.state), b.action, b.ref * keep)
    loss = losses.critic_loss(logits, target)
    twin.critic_opt.zero_grad()
    loss.backward()
    clip_and_step(list(twin.critic.parameters()), twin.critic_opt, max_grad_norm)

    assert set(info) == {"critic_loss", "q_mean"}
    assert float(info["critic_loss"]) == pytest.approx(loss.item(), rel=1e-5)
    q = expected_value(torch.softmax(logits.detach(), -1), twin.support).mean()
    assert float(info["q_mean"]) == pytest.approx(float(q), rel=1e-5)
    same_params(learner.critic, twin.critic)
    same_params(learner.actor, twin.actor)  # the critic update leaves θ alone
    assert torch.equal(learner.gen.get_state(), g.get_state())  # and draws nothing else


@pytest.mark.parametrize("algo", ["fasttd3", "fastsac"])
@pytest.mark.parametrize("method, max_grad_norm", [("accrue", 0.0), ("accrue", 0.05), ("ewc", 0.0)])
def test_actor_update_by_hand(algo, method, max_grad_norm):
    """Survivors of agent._actor_update, agent._actor_loss and agent._distill_inputs: dropout drawn from the
    learner's generator (then SAC's ε), Eq. 1 at π(s, ã·keep) with the critic frozen and β‖a − ã‖² to the
    stored ã, Eq. 4 of π̄(s_j, ã_j) to the cached â_j weighted by λ (ACCRUE) or EWC's penalty weighted by
    ewc_lambda, clipped to max_grad_norm when > 0, one AdamW step of θ only, SAC's α step after it, and the
    reported figures."""
    learner, twin = twin_learners(method, algo=algo, ref_dropout=0.5, max_grad_norm=max_grad_norm, ewc_lambda=3.0)
    mem = rows_buffer(16, seed=2)
    cur = learner.sample(mem, BATCH)
    prior = None
    if method == "accrue":
        teacher = torch.rand(16, H, A, generator=torch.Generator().manual_seed(9)) * 2 - 1
        prior = learner.sample(rows_buffer(16, seed=4), BATCH).with_teacher(teacher)
    else:
        for one in (learner, twin):
            name, p = next(iter(one.actor.named_parameters()))
            one.ewc_anchor, one.ewc_fisher = {name: p.detach() + 0.1}, {name: torch.full_like(p, 2.0)}
    twin.gen.set_state(learner.gen.get_state())
    for one in (learner, twin):
        one.actor.obs_norm.update(cur.state * 3 + 1)
    critic_before = {k: v.clone() for k, v in learner.critic.state_dict().items()}
    info = learner._actor_update(cur, prior)

    g = gen_copy(twin)
    n = len(cur)
    keep = (torch.rand(n, generator=g) >= 0.5).float().view(n, 1, 1)
    assert 0 < keep.sum() < n
    ref_in = cur.ref * keep
    s_all = cur.state if prior is None else torch.cat([cur.state, prior.state])
    ref_all = ref_in if prior is None else torch.cat([ref_in, prior.ref])
    if algo == "fasttd3":
        out = twin.actor(s_all, ref_all)
        a, a_det, log_prob = out[:n], out[n:], None
    else:
        eps = torch.randn(n, H * A, generator=g)
        mean, log_std = twin.actor.dist_params(s_all, ref_all)
        a, log_prob = tanh_gaussian_sample(mean[:n], log_std[:n], eps)
        a, a_det = a.view(-1, H, A), torch.tanh(mean[n:]).view(-1, H, A)
    q_heads = expected_value(torch.softmax(twin.critic(twin.actor.obs_norm(cur.state), a, ref_in), -1), twin.support)
    q = q_heads.min(0).values if algo == "fasttd3" else q_heads.mean(0)
    loss_cur = -q + 0.23 * (a - cur.ref).flatten(1).square().sum(-1)
    if log_prob is not None:
        loss_cur = loss_cur + twin.alpha.detach() * log_prob
    loss_cur = loss_cur.mean()
    total = loss_cur
    if prior is not None:
        loss_prior = (a_det - prior.teacher).flatten(1).square().sum(-1).mean()
        total = loss_cur + 0.37 * loss_prior
    else:
        (name, p), *_ = twin.actor.named_parameters()
        penalty = (2.0 * (p - twin.ewc_anchor[name]).square()).sum()
        total = loss_cur + 3.0 * penalty
    twin.actor_opt.zero_grad()
    twin.critic.zero_grad()
    total.backward()
    clip_and_step(list(twin.actor.parameters()), twin.actor_opt, max_grad_norm)

    # the reported actor_loss is Eq. 5; EWC's penalty is reported beside it (and moved θ)
    want = {"loss_cur": loss_cur, "actor_loss": total if prior is not None else loss_cur}
    want.update({"loss_prior": loss_prior} if prior is not None else {"ewc_penalty": penalty})
    if log_prob is not None:
        log_alpha = twin.log_alpha
        alpha_loss = -(log_alpha * (log_prob.detach() + twin.target_entropy)).mean()
        twin.alpha_opt.zero_grad()
        alpha_loss.backward()
        twin.alpha_opt.step()
        want.update(alpha=twin.alpha, entropy=-log_prob.mean())
        assert learner.log_alpha.item() == pytest.approx(twin.log_alpha.item(), abs=1e-6)
    assert set(info) == set(want)
    for k, v in want.items():
        assert float(info[k]) == pytest.approx(v.item(), rel=1e-5, abs=1e-7), k
    same_params(learner.actor, twin.actor)
    assert all(torch.equal(v, critic_before[k]) for k, v in learner.critic.state_dict().items())
    assert all(p.requires_grad and p.grad is None for p in learner.critic.parameters())
    assert torch.equal(learner.gen.get_state(), g.get_state())


def test_update_polyak_policy_frequency_and_retain_interval_by_hand():
    """Survivors of agent._update: the target critic moves by τ toward ψ after every update, the actor
    every policy_frequency-th update only, RETAIN merges every retain_interval actor updates, and an
    empty prior batch counts as none."""
    learner = make_learner(config("retain", policy_frequency=2, tau=0.25, retain_interval=2), D, H, A)
    learner.retain_prev = {k: torch.zeros_like(v) for k, v in learner.actor.named_parameters()}
    b = learner.sample(rows_buffer(16, seed=2), BATCH)
    empty = learner.sample(rows_buffer(16, seed=2), BATCH)
    empty = type(empty)(**{k: (v[:0] if torch.is_tensor(v) else v) for k, v in vars(empty).items()})
    for step in range(1, 5):
        target = {k: v.clone() for k, v in learner.critic_target.state_dict().items()}
        actor = {k: v.clone() for k, v in learner.actor.state_dict().items()}
        info = learner._update(b, empty)
        critic = learner.critic.state_dict()
        for k, v in learner.critic_target.state_dict().items():
            if v.is_floating_point():
                torch.testing.assert_close(v, target[k] + 0.25 * (critic[k] - target[k]))
        moved = any(not torch.equal(v, actor[k]) for k, v in learner.actor.state_dict().items())
        assert moved == (step % 2 == 0) and ("actor_loss" in info) == (step % 2 == 0)
        assert learner.counters == {"updates": step, "actor_updates": step // 2, "merges": step // 4}


def test_an_empty_prior_batch_is_no_prior_batch():
    """Survivors agent._update 5, 6: ACCRUE given a prior batch of 0 rows updates exactly as without one
    (Eq. 4 over no rows would be NaN)."""
    learner, twin = twin_learners("accrue")
    b = learner.sample(rows_buffer(16, seed=2), BATCH)
    teacher = torch.zeros(16, H, A)
    empty = learner.sample(rows_buffer(16, seed=3), BATCH).with_teacher(teacher)
    empty = type(empty)(**{k: (v[:0] if torch.is_tensor(v) else v) for k, v in vars(empty).items()})
    twin.gen.set_state(learner.gen.get_state())
    got = {k: float(v) for k, v in learner._update(b, empty).items()}
    want = {k: float(v) for k, v in twin._update(b, None).items()}
    assert got == want and "loss_prior" not in got
    same_params(learner.actor, twin.actor)


def test_actor_update_without_cached_targets_names_the_fix():
    """Survivors agent._actor_update 16-19: the exact message when ACCRUE's prior batch carries no Eq. 3 targets."""
    learner = make_learner(config("accrue"), D, H, A)
    b = learner.sample(rows_buffer(16, seed=2), BATCH)
    with pytest.raises(AccrueError) as exc:
        learner._actor_update(b, learner.sample(rows_buffer(16, seed=3), BATCH))
    assert str(exc.value) == "ACCRUE needs cached teacher targets on the prior batch (Batch.with_teacher)"


def test_amp_on_a_cpu_learner_is_a_silent_no_op():
    """Survivors agent._autocast 1, 2: autocast is entered only for amp on a CUDA device; a CPU learner
    with amp (the GPU presets' setting) acts and updates without torch's 'CUDA is not available' warning."""
    import warnings

    learner = make_learner(config("accrue", amp=True), D, H, A)
    s, ref = inputs(3)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        learner.act(s, ref, explore=False)
        assert "critic_loss" in learner.train_step(rows_buffer(12, seed=0))


def test_ref_dropout_zero_keeps_every_reference_even_for_a_draw_of_exactly_zero():
    """ref_dropout p = 0 means no reference dropout: a row is kept when its uniform draw u ≥ p, so a draw of
    exactly 0.0 (torch.rand's float32 draws are multiples of 2⁻²⁴, 0 included) keeps its ã too. The test
    seeds the learner's generator where the next draws contain a 0.0 (found by search, checked, not assumed).
    Kills agent._dropout_keep 8 (u > p drops that row)."""
    learner = make_learner(config("accrue", ref_dropout=0.0), D, H, A)
    n = 1 << 16
    for seed in range(5000):
        learner.gen.manual_seed(seed)
        if bool((torch.rand(n, generator=learner.gen) == 0).any()):
            break
    else:
        pytest.fail("no float32 draw of exactly 0.0 in 5000 seeds")
    learner.gen.manual_seed(seed)
    keep = learner._dropout_keep(n)
    assert keep.shape == (n, 1, 1) and keep.dtype == torch.float32
    assert bool((keep == 1).all())


# ------------------------------------------------------------------------------------------- train_stage
def test_train_stage_hands_on_update_each_learner_update_with_its_losses():
    """Survivors stage_rl.train_stage 45, 57: on_update (the train step's loss tracking) reaches the loop and
    is called after every learner update, with the loop state and the update's losses."""
    from test_method_wiring import N_ENVS, T1, FakeEnv, features, reference

    from accrue import rl_loop
    from accrue.stage_rl import train_stage

    buffer = ReplayBuffer(D, H, A)
    collector = rl_loop.ChunkCollector(FakeEnv(N_ENVS, 5), reference, features, buffer, task_index=0, gamma=0.99)
    collector.restart()
    rl_loop.warmup(collector, 2)
    evaluator = rl_loop.Evaluator(lambda t, n: FakeEnv(n, 100), {T1: reference}, features, 2, N_ENVS, H, 0.99)
    settings = rl_loop.LoopSettings([T1], env_steps=16, eval_every=16, checkpoint_every=0)
    seen = []
    _, state = train_stage(
        config("sequential"),
        None,
        None,
        None,
        collector,
        evaluator,
        settings,
        on_update=lambda st, info: seen.append((st.updates, st.env_steps, sorted(info))),
    )
    losses_ = ["actor_loss", "critic_loss", "loss_cur", "q_mean"]
    assert seen == [(1, 8, losses_), (2, 16, losses_)] and state.updates == 2


# ------------------------------------------------------------------------------------ device placement
@pytest.mark.parametrize("algo", ["fasttd3", "fastsac"])
def test_a_learner_makes_its_tensors_on_its_own_device_not_torchs_default(algo):
    """A learner on one device while torch's default device is another (a CUDA learner in a process whose
    default is the CPU): every tensor it makes must go to its own device. With the default set to `meta`,
    a tensor made on the default meets the learner's CPU tensors and torch refuses the mix, so this checks
    on a CPU-only machine what a GPU would. Kills sac.reset_optimizers 3, 6 (log α), td3._draw_std 7, 10,
    _explore 11, 14 (the reset mask), 32, 35 (the exploration noise), _target_noise 6, 9; sac._gauss 3,
    networks.GaussianActor.sample 9, 13 (SAC's ε); continual.estimate_fisher 6, 49 (EWC's v ~ N(0, I))."""
    import numpy as np

    from accrue.learner import estimate_fisher

    learner = make_learner(config("accrue", algo=algo), D, H, A)
    buffer = rows_buffer(12, seed=0)
    batch = buffer.sample(8, torch.Generator().manual_seed(0))
    s, ref = inputs(3)
    with torch.device("meta"):
        learner.reset_optimizers()
        info = learner.train_step(buffer)
        learner.act(s, ref, explore=True)  # the first call draws every env's std
        acted = learner.act(s, ref, explore=True, reset_mask=np.array([False, True, False]))
        fisher = estimate_fisher(learner, batch, torch.Generator().manual_seed(1))
    assert acted.device.type == "cpu" and acted.shape == ref.shape
    assert all(math.isfinite(v) for v in info.values())
    assert all(f.device.type == "cpu" and bool((f >= 0).all()) for f in fisher.values())


# ------------------------------------------------------------------------------------ construction
def test_the_config_reaches_the_networks_and_the_optimizers():
    """Kills agent._actor_kwargs 19, 31 (layer_norm), 32 (actor_residual), 34 (obs_normalization),
    36 (obs_norm_clip), 37 (obs_norm_fixed_tail), agent._make_critic 8, 15 (the critic's layer_norm),
    agent._adamw 6, 7 (AdamW's lr and weight decay)."""
    nets = dict(actor_hidden=[16, 16], critic_hidden=[16, 16])
    on = make_learner(config("accrue", layer_norm=True, obs_norm_clip=7.0, obs_norm_fixed_tail=2, **nets), D, H, A)
    off = make_learner(
        config(
            "accrue",
            layer_norm=False,
            actor_residual=False,
            obs_normalization=False,
            actor_lr=0.02,
            critic_lr=0.03,
            weight_decay=0.2,
            **nets,
        ),
        D,
        H,
        A,
    )

    def norms(module):
        return [m for m in module.modules() if "LayerNorm" in type(m).__name__]

    # the projector always normalises (networks.projector); layer_norm adds one per hidden layer but the last
    assert [len(norms(n)) for n in (on.actor, on.critic, on.critic_target)] == [2, 3, 3]
    assert [len(norms(n)) for n in (off.actor, off.critic, off.critic_target)] == [1, 1, 1]
    assert (on.actor.residual, off.actor.residual) == (True, False)
    assert (on.actor.obs_norm.enabled, off.actor.obs_norm.enabled) == (True, False)
    assert (on.actor.obs_norm.clip, on.actor.obs_norm.fixed_tail) == (7.0, 2)
    for opt, lr in ((off.actor_opt, 0.02), (off.critic_opt, 0.03)):
        group = opt.param_groups[0]
        assert (group["lr"], group["weight_decay"]) == (lr, 0.2)


def test_the_default_action_dim_is_six():
    """Kills agent.ChunkLearner.__init__ 1 (the default action dimension of a learner built directly).
    (ChunkLearner.__init__ ids in this file are those of fdd22d3.)"""
    from accrue.learner.td3 import FastTD3Learner

    learner = FastTD3Learner(config("accrue"), D, H)
    assert learner.action_dim == 6
    assert learner.act(torch.zeros(2, D), torch.zeros(2, H, 6)).shape == (2, H, 6)


def test_a_single_env_gets_an_exploration_std_on_its_first_act():
    """Kills agent.ChunkLearner.__init__ 37, 38, 42 (a fresh learner has no per-env std yet: the first act draws
    one for every env, even for a single env)."""
    learner = make_learner(config("accrue", std_min=0.3, std_max=0.9), D, H, A)
    assert learner.noise_std.shape == (0,)
    s, ref = inputs(1)
    g = gen_copy(learner)
    std = 0.3 + 0.6 * torch.rand(1, generator=g)
    learner.act(s, ref, explore=True)
    torch.testing.assert_close(learner.noise_std, std)


def test_compile_compiles_both_loss_functions_with_the_configured_mode(monkeypatch):
    """Kills agent.ChunkLearner.__init__ 60-69 (torch.compile of the critic and the actor loss, with
    cfg.compile_mode). torch.compile is replaced by a recorder so that nothing is compiled."""
    calls = []

    def fake_compile(model=None, *, mode=None, **kw):
        calls.append((model, mode))
        return model

    monkeypatch.setattr(torch, "compile", fake_compile)
    learner = make_learner(config("accrue", compile=True, compile_mode="max-autotune"), D, H, A)
    assert calls == [(learner._critic_loss, "max-autotune"), (learner._actor_loss, "max-autotune")]
    assert learner._critic_loss_fn == learner._critic_loss and learner._actor_loss_fn == learner._actor_loss
    calls.clear()
    make_learner(config("accrue"), D, H, A)
    assert calls == []


def test_a_learner_built_under_another_default_device_keeps_its_own_tensors_on_its_device():
    """A learner built while torch's default device is another one (a CUDA learner in a process whose
    default is the CPU): the support, the generator and the per-env std go to the learner's device. The
    networks are built on the CPU here (a `meta` module cannot be moved), everything else the learner makes
    under the `meta` default. Kills agent.ChunkLearner.__init__ 29, 33 (the support), 39, 41 (the std)."""
    from accrue.learner.td3 import FastTD3Learner

    class NetworksOnTheCpu(FastTD3Learner):
        def _make_actor(self):
            with torch.device("cpu"):
                return super()._make_actor()

        def _make_critic(self):
            with torch.device("cpu"):
                return super()._make_critic()

    with torch.device("meta"):
        learner = NetworksOnTheCpu(config("accrue", v_min=-3.0, v_max=5.0), D, H, A)
    assert learner.support.device.type == "cpu" and learner.noise_std.device.type == "cpu"
    assert learner.gen.device.type == "cpu"
    torch.testing.assert_close(learner.support, torch.linspace(-3.0, 5.0, learner.cfg.num_atoms))
    s, ref = inputs(2)
    assert learner.act(s, ref, explore=True).device.type == "cpu"


@pytest.mark.parametrize("algo", ["fasttd3", "fastsac"])
def test_building_a_learner_leaves_the_callers_torch_generators_as_they_were(monkeypatch, algo):
    """A learner's networks come from cfg.seed alone: building one (and a reset-critic stage's fresh critic)
    must neither advance the caller's CPU stream nor reseed a GPU's. Before the fix the target critic was
    built outside the seeded block (the caller's stream moved on), and torch.manual_seed reseeded every
    GPU, which fork_rng(devices=[]) does not restore."""
    from accrue.learner import begin_stage

    torch.manual_seed(123)
    expected = torch.rand(4)
    torch.manual_seed(123)
    gpu_reseeds = []
    monkeypatch.setattr(torch.cuda, "manual_seed_all", gpu_reseeds.append)
    monkeypatch.setattr(torch.cuda, "manual_seed", gpu_reseeds.append)
    first = make_learner(config("accrue", algo=algo), D, H, A)
    second = begin_stage(first, config("accrue", algo=algo).replace(ablation="reset-critic"), D, H, A)
    assert torch.equal(torch.rand(4), expected)
    assert gpu_reseeds == []
    again = make_learner(config("accrue", algo=algo), D, H, A)  # and the seed alone fixes the weights
    for built, rebuilt in zip(first.actor.parameters(), again.actor.parameters(), strict=True):
        assert torch.equal(built, rebuilt)
    for target, critic in zip(second.critic_target.parameters(), second.critic.parameters(), strict=True):
        assert torch.equal(target, critic)


def test_a_bad_learner_setting_is_one_line_naming_it_what_is_allowed_and_at_most_200_characters_of_it():
    """What a user sees for a wrong workflow value. Kills LearnerConfig.validate 43, 47 (the allowed values),
    56, 61 (ablation with another method), 62 (its message in capitals), 9-14 (the value's repr cut to 199 characters and an ellipsis once it
    is over 200: one of exactly 200 is kept whole, one of 201 is cut)."""
    import reprlib

    from accrue.learner import LearnerConfig

    def error(**settings) -> str:
        with pytest.raises(AccrueError) as raised:
            LearnerConfig(**settings)
        return str(raised.value)

    assert error(algo="td3") == "learner.algo: must be one of fasttd3, fastsac (got 'td3')"
    assert error(method="sequential", ablation="reset-critic") == (
        "learner.ablation: ablations apply to method 'accrue' only (got 'reset-critic')"
    )
    hidden = "learner.actor_hidden: must be a non-empty list of positive integers (got {})"
    exactly_200, over_200 = [["y" * 4] * 6] * 4, [["y" * 6] * 7] * 3
    assert len(reprlib.repr(exactly_200)) == 200 and len(reprlib.repr(over_200)) == 201
    assert error(actor_hidden=exactly_200) == hidden.format(reprlib.repr(exactly_200))
    assert error(actor_hidden=over_200) == hidden.format(reprlib.repr(over_200)[:199] + "…")


# Each rule of LearnerConfig.validate: a value just outside it, the setting the line names, and why.
NON_NEGATIVE = ("weight_decay", "max_grad_norm", "std_min", "policy_noise", "noise_clip", "beta", "lam")
NON_NEGATIVE += ("ewc_lambda", "obs_norm_min_std", "obs_norm_clip")
REFUSED_SETTINGS = [
    ({"actor_hidden": []}, "actor_hidden", "must be a non-empty list of positive integers"),
    ({"critic_hidden": [16, 0]}, "critic_hidden", "must be a non-empty list of positive integers"),
    ({"actor_hidden": [16, True]}, "actor_hidden", "must be a non-empty list of positive integers"),
    ({"actor_hidden": [16.0]}, "actor_hidden", "must be a non-empty list of positive integers"),
    ({"critic_hidden": "16"}, "critic_hidden", "must be a non-empty list of positive integers"),
    ({"num_atoms": 0}, "num_atoms", "must be a positive integer"),
    ({"num_atoms": 1}, "num_atoms", "needs at least 2 atoms"),
    ({"seed": -1}, "seed", "must be a non-negative integer"),
    ({"seed": True}, "seed", "must be a non-negative integer"),
    ({"retain_interval": "3"}, "retain_interval", "must be a non-negative integer"),
    ({"learning_starts": 1.5}, "learning_starts", "must be a non-negative integer"),
    ({"obs_norm_fixed_tail": -2}, "obs_norm_fixed_tail", "must be a non-negative integer"),
    ({"gamma": "fast"}, "gamma", "must be a number"),
    ({"gamma": float("nan")}, "gamma", "must be a finite number"),
    ({"tau": True}, "tau", "must be a finite number"),
    ({"lam": "inf"}, "lam", "must be a finite number"),
    ({"v_min": 2.0, "v_max": 2.0}, "v_max", "must be greater than v_min"),
    ({"gamma": 0.0}, "gamma", "must be in (0, 1]"),
    ({"gamma": 1.01}, "gamma", "must be in (0, 1]"),
    ({"tau": 0.0}, "tau", "must be in (0, 1]"),
    ({"tau": 1.5}, "tau", "must be in (0, 1]"),
    ({"ref_dropout": -0.1}, "ref_dropout", "must be in [0, 1]"),
    ({"ref_dropout": 1.1}, "ref_dropout", "must be in [0, 1]"),
    ({"retain_alpha": -0.1}, "retain_alpha", "must be in [0, 1]"),
    ({"retain_alpha": 1.1}, "retain_alpha", "must be in [0, 1]"),
    *[({name: 0.0}, name, "must be positive") for name in ("actor_lr", "critic_lr", "alpha_lr", "alpha_init")],
    ({"actor_init_scale": -1.0}, "actor_init_scale", "must be positive"),
    *[({name: -0.5}, name, "must be non-negative") for name in NON_NEGATIVE],
    ({"std_min": 0.3, "std_max": 0.2}, "std_max", "must be >= std_min"),
    ({"log_std_min": -1.0, "log_std_max": -1.0}, "log_std_max", "must be greater than log_std_min"),
    *[({name: 1}, name, "must be true or false") for name in ("layer_norm", "actor_residual", "use_cdq")],
    *[({name: "yes"}, name, "must be true or false") for name in ("obs_normalization", "amp", "compile")],
    ({"compile_mode": "fast"}, "compile_mode", "must be one of default, reduce-overhead, max-autotune"),
    ({"device": "mps"}, "device", "must be 'cpu' or 'cuda[:n]'"),
    ({"device": 0}, "device", "must be 'cpu' or 'cuda[:n]'"),
]


@pytest.mark.parametrize(("settings", "name", "why"), REFUSED_SETTINGS, ids=lambda v: str(v)[:40])
def test_every_refused_learner_setting_is_one_line_naming_it_and_the_rule(settings, name, why):
    """A workflow's learner block with one value just past a rule: the line names that setting, the rule
    and the value as given. Kills LearnerConfig.validate's mutants of its bounds, its messages and the
    names they report (round 8: 90-100, 135-165, 225-282 and the like)."""
    import reprlib

    from accrue.learner import LearnerConfig

    with pytest.raises(AccrueError) as raised:
        LearnerConfig(**settings)
    assert str(raised.value) == f"learner.{name}: {why} (got {reprlib.repr(settings[name])})"


def test_learner_settings_on_each_rules_edge_are_accepted_and_normalised():
    """The edges each rule lets through, and what validate stores: hidden sizes as a list (a tuple from
    Python), numbers given as YAML strings as floats. Kills LearnerConfig.validate 72-83 (the tuple made a
    list), 94 (a layer of 1 unit refused), 132, 133 (2 atoms refused), 259-274 (γ, τ of 1 refused), 298,
    299, 363 (α_RETAIN of 0 or 1, std_max = std_min refused), 403, 404 (a compile mode refused) and the
    like."""
    from accrue.learner import LearnerConfig

    cfg = LearnerConfig(
        actor_hidden=(16, 8),
        critic_hidden=(1,),
        num_atoms=2,
        seed=0,
        retain_interval=0,
        gamma=1.0,
        tau="1e0",
        ref_dropout=1.0,
        retain_alpha=0.0,
        std_min=0.2,
        std_max=0.2,
        beta=0,
        v_min=-1e-9,
        v_max=0.0,
    )
    assert cfg.actor_hidden == [16, 8] and cfg.critic_hidden == [1]
    assert cfg.tau == 1.0 and isinstance(cfg.tau, float) and isinstance(cfg.beta, float)
    assert (cfg.num_atoms, cfg.gamma, cfg.ref_dropout, cfg.retain_alpha) == (2, 1.0, 1.0, 0.0)
    edges = LearnerConfig(gamma=1e-9, tau=1e-9, ref_dropout=0.0, retain_alpha=1.0, compile_mode="reduce-overhead")
    assert (edges.gamma, edges.tau, edges.ref_dropout, edges.retain_alpha) == (1e-9, 1e-9, 0.0, 1.0)
    assert LearnerConfig(compile_mode="max-autotune").compile_mode == "max-autotune"
