"""The method as the paper writes it (issue 10): H-step bootstrap, Polyak, reference dropout in both networks,
the no-reference ablation, Eq. 3 at the stored inputs, the distillation-input switch, the normaliser across
stages, RETAIN scored as deployed, and one table of method rules."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from accrue import rl_loop
from accrue.learner import (
    Batch,
    LearnerConfig,
    ReplayBuffer,
    begin_stage,
    end_stage,
    load_learner,
    make_learner,
    save_learner,
)
from accrue.learner.distributional import expected_value
from accrue.methods import ABLATIONS, METHOD_RULES, METHODS, rules
from accrue.stage_rl import cache_teacher, hand_over

D, H, A = 4, 4, 2
SMALL = dict(
    actor_hidden=[32, 32],
    critic_hidden=[64, 64],
    projector_dim=16,
    batch_size=64,
    num_atoms=51,
    utd=1,
    policy_frequency=1,
)

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def random_buffer(n=256, seed=0, task=0, state_dim=D, shift=0.0):
    g = torch.Generator().manual_seed(seed)
    buf = ReplayBuffer(state_dim, H, A)
    buf.add(
        torch.randn(n, state_dim, generator=g) + shift,
        torch.rand(n, H, A, generator=g) * 2 - 1,
        torch.rand(n, H, A, generator=g) * 1.6 - 0.8,
        torch.zeros(n),
        torch.randn(n, state_dim, generator=g),
        torch.rand(n, H, A, generator=g) * 1.6 - 0.8,
        torch.zeros(n, dtype=torch.bool),
        task,
        torch.arange(n) // 8,
        ended=(torch.arange(n) % 8) == 7,
    )
    return buf


def q_value(learner, s, a, ref):
    with torch.no_grad():
        logits = learner.critic(learner.actor.obs_norm(s), a, ref)
        return expected_value(torch.softmax(logits, -1), learner.support).mean(0)


# ---------------------------------------------------------------------------------------- the rules table
def test_one_row_per_method_and_the_ablations_change_one_rule_of_accrue():
    assert set(METHODS) == set(METHOD_RULES)
    accrue = rules("accrue")
    assert accrue.distill and accrue.uses_prior_memory and not accrue.critic_on_prior
    changed = {
        a: {f for f in accrue.__dataclass_fields__ if getattr(rules("accrue", a), f) != getattr(accrue, f)}
        for a in ABLATIONS
    }
    assert changed == {
        "none": set(),
        "no-reference": {"use_reference"},
        "beta0": {"zero_beta"},
        "reset-critic": {"inherit_critic"},
        "critic-all-replay": {"critic_on_prior"},
    }
    with pytest.raises(ValueError):
        rules("er", "beta0")


# ---------------------------------------------------------------------------------------- Eq. 2 and Polyak
def two_chunk_chain(n: int) -> ReplayBuffer:
    """State A -> (reward 0, not done) -> state B -> (reward 1, done). Rewards do not depend on the action."""
    a_state, b_state = torch.tensor([1.0, 0, 0, 0]), torch.tensor([0, 1.0, 0, 0])
    buf = ReplayBuffer(D, H, A)
    g = torch.Generator().manual_seed(0)
    half = n // 2
    chunk = lambda m: torch.rand(m, H, A, generator=g) * 1.6 - 0.8  # noqa: E731
    buf.add(
        a_state.repeat(half, 1),
        chunk(half),
        chunk(half),
        torch.zeros(half),
        b_state.repeat(half, 1),
        chunk(half),
        torch.zeros(half, dtype=torch.bool),
        0,
        torch.arange(half),
    )
    buf.add(
        b_state.repeat(half, 1),
        chunk(half),
        chunk(half),
        torch.ones(half),
        a_state.repeat(half, 1),
        chunk(half),
        torch.ones(half, dtype=torch.bool),
        0,
        torch.arange(half),
    )
    return buf


def test_h_step_backup_bootstraps_with_gamma_to_the_h_when_not_done():
    gamma = 0.9
    cfg = LearnerConfig(
        **SMALL, gamma=gamma, v_min=-0.5, v_max=1.5, obs_normalization=False, tau=0.2, critic_lr=3e-3, ref_dropout=0.0
    )
    learner = make_learner(cfg, D, H, A)
    buf = two_chunk_chain(512)
    for _ in range(600):
        learner.train_step(buf)
    probe = buf.gather(torch.arange(0, 512, 37))
    q = q_value(learner, probe.state, probe.action, probe.ref)
    is_a = probe.state[:, 0] == 1
    assert q[~is_a].mean().item() == pytest.approx(1.0, abs=0.08)  # terminal: no bootstrap
    assert q[is_a].mean().item() == pytest.approx(gamma**H, abs=0.08)  # 0.656: γ^H, not γ (0.9)


def test_target_critic_moves_by_polyak_after_each_update():
    cfg = LearnerConfig(**SMALL, tau=0.25)
    learner = make_learner(cfg, D, H, A)
    buf = random_buffer()
    before = [p.detach().clone() for p in learner.critic_target.parameters()]
    learner.train_step(buf)
    for t, b, c in zip(learner.critic_target.parameters(), before, learner.critic.parameters()):
        assert torch.allclose(t, 0.75 * b + 0.25 * c, atol=1e-6)
    assert not all(torch.equal(t, b) for t, b in zip(learner.critic_target.parameters(), before))


# ------------------------------------------------------------------------------- what ã the networks see
def record_refs(learner) -> dict[str, list[torch.Tensor]]:
    seen: dict[str, list[torch.Tensor]] = {"critic": [], "target": [], "actor": []}
    for name, net in (("critic", learner.critic), ("target", learner.critic_target)):
        net.register_forward_hook(lambda mod, args, out, name=name: seen[name].append(args[2].detach().clone()))
    learner.actor.register_forward_hook(lambda mod, args, out: seen["actor"].append(args[1].detach().clone()))
    return seen


def zero_rows(refs: torch.Tensor) -> torch.Tensor:
    return (refs.flatten(1) == 0).all(1)


@pytest.mark.parametrize("p", [0.0, 0.5, 1.0])
def test_reference_dropout_reaches_critic_target_and_actor_alike(p):
    learner = make_learner(LearnerConfig(**SMALL, ref_dropout=p), D, H, A)
    seen = record_refs(learner)
    learner.train_step(random_buffer())
    critic, target, actor = seen["critic"][0], seen["target"][0], seen["actor"]
    dropped = zero_rows(critic)
    assert torch.equal(dropped, zero_rows(target))  # same rows in Q_ψ and Q_ψ'
    assert dropped.float().mean().item() == pytest.approx(p, abs=0.15)
    assert zero_rows(actor[-1]).float().mean().item() == pytest.approx(p, abs=0.15)  # and in the actor loss


def test_no_reference_ablation_hides_the_reference_from_actor_and_critic():
    learner = make_learner(LearnerConfig(**SMALL, ablation="no-reference", ref_dropout=0.0), D, H, A)
    seen = record_refs(learner)
    learner.train_step(random_buffer())
    assert all(zero_rows(r).all() for name in seen for r in seen[name])
    plain = make_learner(LearnerConfig(**SMALL, ref_dropout=0.0), D, H, A)
    seen = record_refs(plain)
    plain.train_step(random_buffer())
    assert not zero_rows(seen["critic"][0]).any()


# ---------------------------------------------------------------------------------- Eq. 3-5, distillation
def stage_two(method="accrue", **over):
    cfg = LearnerConfig(**SMALL, method=method, **over)
    prev = make_learner(cfg, D, H, A)
    prev.train_step(random_buffer(seed=1))
    end_stage(prev)
    return cfg, prev


def test_teacher_targets_are_the_previous_actor_at_the_stored_inputs():
    cfg, prev = stage_two()
    memory = random_buffer(64, seed=2)
    fresh = lambda states, task: np.full((len(states), H, A), 0.3, dtype=np.float32)  # noqa: E731
    cache = cache_teacher(prev, memory, fresh)
    stored = prev.act(memory.column("state"), memory.column("ref"), explore=False)
    assert torch.allclose(cache.targets, stored, atol=1e-6)
    assert torch.equal(cache.fresh_ref, torch.full((64, H, A), 0.3))
    assert cache_teacher(prev, memory).fresh_ref is None


@pytest.mark.parametrize("mode", ["stored", "fresh", "both"])
def test_distillation_inputs_switch(mode):
    cfg, prev = stage_two(distill_inputs=mode)
    learner = begin_stage(prev, cfg, D, H, A)
    memory = random_buffer(64, seed=2)
    cache = cache_teacher(prev, memory, lambda st, task: np.full((len(st), H, A), 0.3, dtype=np.float32))
    batch = memory.gather(torch.arange(8)).with_teacher(cache.targets, cache.fresh_ref)
    s, ref, target = learner._distill_inputs(batch)
    expected_refs = {"stored": [batch.ref], "fresh": [batch.fresh_ref], "both": [batch.ref, batch.fresh_ref]}[mode]
    assert torch.equal(ref, torch.cat(expected_refs))
    assert torch.equal(target, torch.cat([batch.teacher] * len(expected_refs)))
    assert torch.equal(s, torch.cat([batch.state] * len(expected_refs)))


def test_fresh_distillation_without_fresh_chunks_is_a_clear_error():
    from accrue.errors import AccrueError

    cfg, prev = stage_two(distill_inputs="fresh")
    learner = begin_stage(prev, cfg, D, H, A)
    memory = random_buffer(64, seed=2)
    with pytest.raises(AccrueError, match="fresh reference"):
        learner.train_step(random_buffer(seed=3), memory, cache_teacher(prev, memory).targets)


# ----------------------------------------------------------------------------- the normaliser across stages
def task_code_buffer(code: np.ndarray, seed: int, n=256) -> ReplayBuffer:
    g = torch.Generator().manual_seed(seed)
    states = torch.cat([torch.randn(n, D, generator=g), torch.as_tensor(code).expand(n, -1)], 1)
    buf = ReplayBuffer(D + len(code), H, A)
    buf.add(
        states,
        torch.rand(n, H, A, generator=g) * 2 - 1,
        torch.rand(n, H, A, generator=g) * 1.6 - 0.8,
        torch.zeros(n),
        states,
        torch.rand(n, H, A, generator=g) * 1.6 - 0.8,
        torch.zeros(n, dtype=torch.bool),
        0,
        torch.arange(n) // 8,
    )
    return buf


@pytest.mark.parametrize("min_std, bounded", [(0.1, True), (0.0, False)])
def test_a_new_task_code_stays_bounded_at_the_first_update_of_stage_two(min_std, bounded):
    from accrue.policy.instruction_embedding import embed_instructions
    from accrue.sim import get_task

    codes = embed_instructions([get_task(t).instruction for t in ("nist/rect_peg", "nist/gear")], 32)
    cfg = LearnerConfig(**SMALL, obs_norm_min_std=min_std, obs_norm_clip=0.0)  # no clip: the floor alone
    stage1 = make_learner(cfg, D + 32, H, A)
    for _ in range(20):
        stage1.train_step(task_code_buffer(codes[0], 0))
    end_stage(stage1)
    stage2 = begin_stage(stage1, cfg, D + 32, H, A)
    seen = []
    stage2.actor.proj.register_forward_pre_hook(lambda mod, args: seen.append(args[0].detach().clone()))
    stage2.train_step(task_code_buffer(codes[1], 1))
    z_code = seen[0][:, D:].abs().max().item()
    assert (z_code <= 10) == bounded, z_code  # the unfloored rule (before issue 10) gave |z| in the hundreds


def test_normaliser_is_frozen_after_the_first_stage_so_teacher_and_student_read_s_alike(tmp_path):
    cfg, prev = stage_two()
    assert bool(prev.actor.obs_norm.frozen)
    learner = begin_stage(prev, cfg, D, H, A)
    memory = random_buffer(64, seed=2)
    cache = cache_teacher(prev, memory)
    stats = (learner.actor.obs_norm.mean.clone(), learner.actor.obs_norm.var.clone())
    # at the stage start the student *is* the teacher: zero distillation loss on the retained inputs
    assert torch.allclose(learner.act(memory.column("state"), memory.column("ref"), explore=False), cache.targets)
    for _ in range(5):
        learner.train_step(random_buffer(seed=4, shift=3.0), memory, cache.targets)
    assert torch.equal(learner.actor.obs_norm.mean, stats[0]) and torch.equal(learner.actor.obs_norm.var, stats[1])
    # the every-stage rule (before issue 10) keeps moving the statistics under the teacher
    moving = begin_stage(prev, cfg.replace(obs_norm_update="every-stage"), D, H, A)
    moving.actor.obs_norm.frozen.fill_(False)
    moving.train_step(random_buffer(seed=4, shift=3.0), memory, cache.targets)
    assert not torch.equal(moving.actor.obs_norm.mean, stats[0])
    # save -> load keeps the frozen statistics, and continuing is bit-identical
    save_learner(learner, tmp_path / "ck")
    again = load_learner(tmp_path / "ck")
    assert bool(again.actor.obs_norm.frozen)
    current = random_buffer(seed=5, shift=3.0)
    a, b = learner.train_step(current, memory, cache.targets), again.train_step(current, memory, cache.targets)
    assert a == b


# ---------------------------------------------------------------------------------- RETAIN as deployed
class RecordingEvaluator:
    """Scores nothing: records what the act function outputs on a probe at every grid point."""

    def __init__(self, learner, probe_s, probe_ref):
        self.learner, self.s, self.ref, self.seen = learner, probe_s, probe_ref, []

    def success_rate(self, task_id, act):
        merged = self.learner.deployed_actor()
        expected = self.learner.act_with(merged, self.s, self.ref)
        raw = self.learner.act(self.s, self.ref, explore=False)
        self.seen.append((act(self.s, self.ref, None), expected, raw))
        return 0.0


class ChainCollector:
    """A stand-in collector over a fixed buffer: each chunk step adds rows and counts env steps."""

    def __init__(self, buffer):
        self.buffer, self.next_episode = buffer, 0
        self.env = type("E", (), {"episode": np.zeros(1, dtype=np.int64)})()

    def step(self, act):
        return rl_loop.ChunkStats(env_steps=10, episodes=0, successes=0)

    def restart(self):
        pass


def test_retain_grid_points_score_the_merged_actor_it_would_deploy():
    cfg, prev = stage_two("retain", retain_alpha=0.3, actor_lr=5e-3)
    learner = begin_stage(prev, cfg, D, H, A)
    g = torch.Generator().manual_seed(9)
    probe_s, probe_ref = torch.randn(16, D, generator=g).numpy(), (torch.rand(16, H, A, generator=g) - 0.5).numpy()
    evaluator = RecordingEvaluator(learner, probe_s, probe_ref)
    settings = rl_loop.LoopSettings(["t"], env_steps=60, eval_every=20, checkpoint_every=1000)
    rl_loop.train_loop(learner, ChainCollector(random_buffer(seed=3, shift=2.0)), evaluator, settings)
    assert len(evaluator.seen) == 4  # grid 0, 20, 40, 60
    for scored, merged, _raw in evaluator.seen:
        np.testing.assert_allclose(scored, merged, atol=1e-6)
    assert np.abs(evaluator.seen[-1][0] - evaluator.seen[-1][2]).max() > 1e-3  # merged is not the raw actor
    end_stage(learner)  # the handoff is the merge the last grid point scored
    np.testing.assert_allclose(learner.act(probe_s, probe_ref, explore=False), evaluator.seen[-1][0], atol=1e-6)


# ------------------------------------------------------------------------------------------ handoff memory
def test_hand_over_reports_a_stage_with_fewer_than_n_complete_episodes():
    current = random_buffer(64, task=1)  # 8 episodes of 8 chunks, each ending in its last chunk
    memory, report = hand_over(None, current, 20)
    assert len(memory) == 64 and report["short"] == ["1"] and report["kept"] == {"1": 8}
    memory, report = hand_over(None, current, 3)
    assert len(memory) == 24 and report["short"] == [] and report["kept"] == {"1": 3}
    pooled, report = hand_over(memory, random_buffer(64, task=2, seed=1), 3)
    assert report["kept"] == {"1": 3, "2": 3} and len(pooled) == 48


def test_batch_carries_fresh_chunks_by_row():
    memory = random_buffer(16)
    targets, fresh = torch.arange(16.0).view(16, 1, 1).expand(16, H, A), -torch.arange(16.0).view(16, 1, 1)
    b = memory.gather(torch.tensor([3, 7])).with_teacher(targets, fresh.expand(16, H, A))
    assert b.teacher[:, 0, 0].tolist() == [3.0, 7.0] and b.fresh_ref[:, 0, 0].tolist() == [-3.0, -7.0]
    assert Batch.cat(b, b).fresh_ref is None
