"""The continual rules: ACCRUE's critic never reads B^{<k}; distillation holds retained behaviour; baselines."""

import dataclasses

import pytest
import torch

from accrue.errors import AccrueError
from accrue.learner import (
    Batch,
    LearnerConfig,
    ReplayBuffer,
    begin_stage,
    compute_teacher_targets,
    end_stage,
    estimate_fisher,
    make_learner,
    retain_last_episodes,
)
from accrue.methods import rules

D, H, A = 6, 2, 3
SMALL = dict(
    actor_hidden=[32, 32], critic_hidden=[32], projector_dim=16, batch_size=32, num_atoms=21, utd=1, policy_frequency=1
)

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def make_buffer(task, n=256, seed=0, shift=0.0):
    g = torch.Generator().manual_seed(seed)
    buf = ReplayBuffer(D, H, A)
    buf.add(
        torch.randn(n, D, generator=g) + shift,
        torch.rand(n, H, A, generator=g) * 2 - 1,
        torch.rand(n, H, A, generator=g) * 1.6 - 0.8,
        (torch.rand(n, generator=g) > 0.7).float() * 3,
        torch.randn(n, D, generator=g) + shift,
        torch.rand(n, H, A, generator=g) * 1.6 - 0.8,
        torch.rand(n, generator=g) > 0.9,
        task,
        torch.arange(n) // 8,
    )
    return buf


class RecordingBatch(Batch):
    """A Batch that records which of its fields were read."""

    def __getattribute__(self, name):
        if name in {f.name for f in dataclasses.fields(Batch)}:
            object.__getattribute__(self, "_reads").add(name)
        return object.__getattribute__(self, name)


def recording(batch: Batch) -> RecordingBatch:
    rb = RecordingBatch(**{f.name: getattr(batch, f.name) for f in dataclasses.fields(Batch)})
    object.__setattr__(rb, "_reads", set())
    return rb


@pytest.mark.parametrize("algo", ["fasttd3", "fastsac"])
def test_accrue_critic_never_reads_prior_batch(algo):
    learner = make_learner(LearnerConfig(algo=algo, **SMALL, method="accrue"), D, H, A)
    cur, prior_buf = make_buffer(1, seed=1), make_buffer(0, seed=2)
    teacher = compute_teacher_targets(learner, prior_buf.column("state"), prior_buf.column("ref"), 64)
    g = torch.Generator().manual_seed(0)
    prior = recording(prior_buf.sample(32, g).with_teacher(teacher))
    critic_inputs = []
    learner.critic.register_forward_pre_hook(lambda m, args: critic_inputs.append(args[0].shape[0]))
    learner._critic_update(cur.sample(32, g))
    assert object.__getattribute__(prior, "_reads") == set()  # nothing of B^{<k} touched
    learner._update(cur.sample(32, g), prior)
    reads = object.__getattribute__(prior, "_reads")
    assert reads == {"state", "ref", "teacher"}  # the actor's distillation inputs only
    assert all(n == 32 for n in critic_inputs)  # critic never saw a 64-row batch

    # whereas the critic-all-replay ablation and ER do feed B^{<k} to the critic
    for kw in (dict(method="accrue", ablation="critic-all-replay"), dict(method="er")):
        other = make_learner(LearnerConfig(algo=algo, **SMALL, **kw), D, H, A)
        sizes = []
        other.critic.register_forward_pre_hook(lambda m, args, sizes=sizes: sizes.append(args[0].shape[0]))
        pr = recording(prior_buf.sample(32, g).with_teacher(teacher))
        other._update(cur.sample(32, g), pr)
        assert 64 in sizes and "reward" in object.__getattribute__(pr, "_reads")


def drift_after_new_task(method, algo):
    """Stage 1 → stage 2 on a different task; mean squared distance of the actor's outputs on the retained
    inputs from their stage-start (teacher) values."""
    cfg = LearnerConfig(algo=algo, **SMALL, method=method, lam=10.0, beta=0.0, seed=3)
    first = make_learner(cfg, D, H, A)
    old = make_buffer(0, seed=4)
    for _ in range(30):
        first.train_step(old)
    memory = retain_last_episodes(old, 8)
    learner = begin_stage(first, cfg, D, H, A)
    teacher = compute_teacher_targets(first, memory.column("state"), memory.column("ref"), 64)
    new = make_buffer(1, seed=5, shift=0.5)
    new._data["reward"][: len(new)] = 3.0 * (new.column("action")[:, :, 0].mean(1) > 0.3).float()  # new objective
    for _ in range(150):
        learner.train_step(new, memory, teacher)
    out = compute_teacher_targets(learner, memory.column("state"), memory.column("ref"), 64)
    return (out - teacher).flatten(1).square().sum(1).mean().item()


@pytest.mark.parametrize("algo", ["fasttd3", "fastsac"])
def test_distillation_holds_retained_outputs_while_sequential_drifts(algo):
    accrue = drift_after_new_task("accrue", algo)
    sequential = drift_after_new_task("sequential", algo)
    assert sequential > 0.05  # the new task really moves the actor
    assert accrue < 0.25 * sequential, (accrue, sequential)


def test_stage_start_rules():
    cfg = LearnerConfig(**SMALL, method="sequential")
    prev = make_learner(cfg, D, H, A)
    prev.train_step(make_buffer(0))
    prev.train_step(make_buffer(0))
    inherit = begin_stage(prev, cfg, D, H, A)
    assert inherit.stage == 1
    assert all(torch.equal(p, q) for p, q in zip(prev.actor.state_dict().values(), inherit.actor.state_dict().values()))
    assert all(torch.equal(p, q) for p, q in zip(prev.critic.parameters(), inherit.critic.parameters()))
    assert inherit.counters["updates"] == 0 and not inherit.actor_opt.state  # optimiser moments reset

    fresh = begin_stage(prev, cfg.replace(method="single-task"), D, H, A)
    assert not torch.equal(next(fresh.actor.parameters()), next(prev.actor.parameters()))
    assert fresh.actor.obs_norm.count.item() == 0

    reset = begin_stage(prev, cfg.replace(method="accrue", ablation="reset-critic"), D, H, A)
    assert all(torch.equal(p, q) for p, q in zip(prev.actor.parameters(), reset.actor.parameters()))
    assert not torch.equal(next(reset.critic.parameters()), next(prev.critic.parameters()))
    with pytest.raises(AccrueError, match="fisher_batch"):
        begin_stage(prev, cfg.replace(method="ewc"), D, H, A)
    with pytest.raises(AccrueError, match="dims"):
        begin_stage(prev, cfg, D + 1, H, A)

    plan = rules("isolated")
    assert plan.checkpoint_per_task and plan.inherit_actor and not plan.uses_prior_memory
    assert rules("er").critic_data == "current+prior" and rules("accrue").critic_data == "current"


def test_ewc_fisher_and_penalty_hold_parameters():
    cfg = LearnerConfig(**SMALL, method="ewc", ewc_lambda=1e4)
    prev = make_learner(cfg, D, H, A)
    old = make_buffer(0)
    batch = old.sample(64, torch.Generator().manual_seed(0))
    fisher = estimate_fisher(prev, batch, torch.Generator().manual_seed(1))
    assert set(fisher) == {k for k, _ in prev.actor.named_parameters()}
    assert all((f >= 0).all() for f in fisher.values())
    # the last layer's bias gets Fisher 1·(dtanh)² per output: clearly positive
    assert fisher["head.bias"].min() > 0

    def drift(method):
        lr = begin_stage(prev, cfg.replace(method=method), D, H, A, fisher_batch=batch)
        new = make_buffer(1, seed=5, shift=0.5)
        for _ in range(40):
            lr.train_step(new)
        return sum((p - q).square().sum().item() for p, q in zip(lr.actor.parameters(), prev.actor.parameters()))

    assert drift("ewc") < 0.5 * drift("sequential")


def test_retain_merges_toward_stage_start():
    cfg = LearnerConfig(**SMALL, method="retain", retain_alpha=0.25)
    prev = make_learner(cfg, D, H, A)
    lr = begin_stage(prev, cfg, D, H, A)
    for _ in range(10):
        lr.train_step(make_buffer(1))
    before = [p.detach().clone() for p in lr.actor.parameters()]
    end_stage(lr)
    for p, b, s in zip(lr.actor.parameters(), before, prev.actor.parameters()):
        assert torch.allclose(p, 0.75 * s + 0.25 * b, atol=1e-6)
    assert lr.counters["merges"] == 1


def test_teacher_targets_are_deterministic_and_batched():
    lr = make_learner(LearnerConfig(algo="fastsac", **SMALL), D, H, A)
    buf = make_buffer(0, n=100)
    t1 = compute_teacher_targets(lr, buf.column("state"), buf.column("ref"), 7)
    t2 = compute_teacher_targets(lr.actor, buf.column("state"), buf.column("ref"), 100)
    assert t1.shape == (100, H, A) and torch.allclose(t1, t2, atol=1e-6)
    assert torch.allclose(t1, lr.act(buf.column("state"), buf.column("ref"), explore=False), atol=1e-6)
