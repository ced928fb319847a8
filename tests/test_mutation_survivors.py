"""Tests written to kill mutants that survived the mutmut sweep (docs/MUTATION.md lists each by name).

Stage boundaries (begin_stage at stage 1, Single-task's and reset-critic's seeds, EWC's Fisher bookkeeping),
train_stage's stage-1, resume and callback paths, the fresh-reference distillation inputs, hand_over's
report and fisher_batch's row choice. Tiny networks on the fake env of tests/test_method_wiring.py.
"""

from __future__ import annotations

import copy
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_method_wiring import (  # noqa: E402
    BATCH,
    N_ENVS,
    T1,
    T2,
    A,
    D,
    FakeEnv,
    H,
    Recorder,
    config,
    features,
    memory_buffer,
    reference,
)

from accrue import rl_loop  # noqa: E402
from accrue.errors import AccrueError  # noqa: E402
from accrue.learner import (  # noqa: E402
    ReplayBuffer,
    begin_stage,
    estimate_fisher,
    load_learner,
    make_learner,
    save_learner,
)
from accrue.learner.losses import actor_loss_current  # noqa: E402
from accrue.methods import rules  # noqa: E402
from accrue.stage_rl import TeacherCache, cache_teacher, fisher_batch, hand_over, train_stage  # noqa: E402

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def same_weights(a: torch.nn.Module, b: torch.nn.Module) -> bool:
    sa, sb = a.state_dict(), b.state_dict()
    return sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)


# ------------------------------------------------------------------------------------ begin_stage
def test_stage_one_learner_is_make_learner_of_the_config():
    """Survivors begin_stage 3-10: at stage 1 the learner is exactly make_learner(cfg, dims)."""
    cfg = config("accrue")
    got = begin_stage(None, cfg, D, H, A)
    want = make_learner(cfg, D, H, A)
    assert (got.state_dim, got.horizon, got.action_dim, got.stage) == (D, H, A, 0)
    assert got.cfg is cfg and same_weights(got.actor, want.actor) and same_weights(got.critic, want.critic)
    # the action dimension is passed through (survivor begin_stage 10), and 6 (the arm's Δ-pose) by default
    assert begin_stage(None, cfg, D, H, 3).action_dim == 3
    assert make_learner(cfg, D, H).action_dim == 6


def test_single_task_restarts_from_the_stage_seed_and_counts_the_stage():
    """Survivors begin_stage 26, 29: fresh networks seeded cfg.seed + stage, at the previous stage + 1."""
    cfg = config("single-task", seed=3)
    prev = make_learner(cfg, D, H, A)
    prev.stage = 1
    got = begin_stage(prev, cfg, D, H, A)
    want = make_learner(cfg.replace(seed=3 + 2), D, H, A)
    assert got.stage == 2 and got.action_dim == A
    assert same_weights(got.actor, want.actor) and same_weights(got.critic, want.critic)
    three = make_learner(cfg, D, H, 3)  # survivor begin_stage 26: a non-default action dimension is kept
    three.stage = 1
    assert begin_stage(three, cfg, D, H, 3).action_dim == 3


def test_reset_critic_draws_its_critic_from_the_stage_seed():
    """Survivor begin_stage 46: the re-initialised critic is seeded cfg.seed + stage (not − stage)."""
    cfg = config("accrue", ablation="reset-critic", seed=3)
    prev = make_learner(cfg, D, H, A)
    prev.stage = 1
    got = begin_stage(prev, cfg, D, H, A)
    torch.manual_seed(3 + 2)
    want = got._make_critic()
    assert same_weights(got.critic, want) and same_weights(got.critic_target, want)
    assert same_weights(got.actor, prev.actor)


def test_ewc_fisher_uses_the_learners_generator_and_accumulates_over_stages():
    """Survivors begin_stage 57, 60, 62, 63, 67: F^k = F(θ^{k-1}; the learner's RNG) + F^{k-1}, key by key."""
    cfg = config("ewc")
    prev = make_learner(cfg, D, H, A)
    prev.stage = 1
    batch = memory_buffer().gather(torch.arange(16))
    gen = torch.Generator().manual_seed(0)
    gen.set_state(prev.gen.get_state())
    fresh = estimate_fisher(prev.actor, batch, generator=gen)
    # stage 2 of a run: nothing accumulated yet
    got = begin_stage(prev, cfg, D, H, A, fisher_batch=batch)
    assert got.ewc_fisher.keys() == fresh.keys()
    assert all(torch.equal(got.ewc_fisher[k], fresh[k]) for k in fresh)
    # stage 3: the previous stages' Fisher is added
    prev.ewc_fisher = {k: torch.full_like(v, 2.0) for k, v in fresh.items()}
    got = begin_stage(prev, cfg, D, H, A, fisher_batch=batch)
    assert all(torch.allclose(got.ewc_fisher[k], fresh[k] + 2.0) for k in fresh)
    with pytest.raises(AccrueError, match=r"^method ewc: begin_stage needs fisher_batch \(previous stage's"):
        begin_stage(prev, cfg, D, H, A)


def test_estimate_fisher_accumulates_over_chunks_and_averages_over_samples():
    """Survivors estimate_fisher 64 (= instead of +=) and 73 (÷ max(n, 2)): 40 rows in chunks of 16 and
    a single row each match the last layer's bias by hand, v_o (1 − a_o²) squared and averaged."""
    learner = make_learner(config("ewc", actor_hidden=[8], projector_dim=4), D, H, A)
    actor = learner.actor
    for n, chunk in ((40, 16), (1, 128)):
        batch = memory_buffer().gather(torch.arange(n))
        fisher = estimate_fisher(actor, batch, generator=torch.Generator().manual_seed(5), chunk=chunk)
        g = torch.Generator().manual_seed(5)
        v = torch.cat([torch.randn((min(chunk, n - i), H * A), generator=g) for i in range(0, n, chunk)])
        with torch.no_grad():
            a = actor.deterministic(batch.state, batch.ref).flatten(1)
        torch.testing.assert_close(fisher["head.bias"], (v * (1 - a**2)).square().mean(0))


# ------------------------------------------------------------------------------------ fisher_batch
def test_fisher_batch_is_the_previous_tasks_last_rows():
    """Survivors fisher_batch 7, 9-15: the last `samples` rows of that task; one row is enough; none is
    one clear error naming the setting."""
    memory = memory_buffer()  # 48 rows of task 0
    got = fisher_batch(memory, 0, 5)
    assert got.index.tolist() == list(range(43, 48))
    assert fisher_batch(memory.select(torch.tensor([7])), 0, 5).index.tolist() == [0]
    with pytest.raises(AccrueError) as err:
        fisher_batch(memory, 1, 5)
    assert str(err.value) == (
        "method ewc needs retained transitions of the previous task for its Fisher: set budgets.retained_episodes > 0"
    )


# ------------------------------------------------------------------------------------ train_stage
def stage_parts(seed=5):
    buffer = ReplayBuffer(D, H, A)
    collector = rl_loop.ChunkCollector(FakeEnv(N_ENVS, seed), reference, features, buffer, task_index=0, gamma=0.99)
    collector.restart()
    rl_loop.warmup(collector, 2)
    evaluator = rl_loop.Evaluator(lambda t, n: FakeEnv(n, 100), {T1: reference}, features, 2, N_ENVS, H, 0.99)
    return buffer, collector, evaluator


@pytest.mark.parametrize("method", ["ewc", "accrue"])
def test_stage_one_trains_without_previous_learner_or_memory(method):
    """Survivors train_stage 5, 14: at stage 1 there is no Fisher to estimate (no previous task)."""
    _, collector, evaluator = stage_parts()
    settings = rl_loop.LoopSettings([T1], env_steps=16, eval_every=16, checkpoint_every=0)
    learner, state = train_stage(config(method), None, None, None, collector, evaluator, settings)
    assert learner.stage == 0 and state.updates == 2 and not learner.ewc_fisher


def test_train_stage_checkpoints_and_resumes_to_the_same_learner(tmp_path):
    """Survivors train_stage 29-33, 42, 44-45, 53, 55-56, 61-67: on_checkpoint receives (learner, state)
    at each checkpoint, on_progress is called, and resume=(learner, state) continues from the checkpoint
    (its collector restored) to the same weights as the run that never stopped."""
    cfg = config("sequential")
    settings = rl_loop.LoopSettings([T1], env_steps=48, eval_every=24, checkpoint_every=16)
    saved, progress = [], []

    def on_checkpoint(learner, st):  # as the train step does: the learner saved, the loop state, B^k's rows
        path = tmp_path / f"ck{len(saved)}"
        save_learner(learner, path)
        saved.append((path, copy.deepcopy(st), len(buffer)))

    buffer, collector, evaluator = stage_parts()
    full, full_state = train_stage(
        cfg,
        None,
        None,
        None,
        collector,
        evaluator,
        settings,
        on_checkpoint=on_checkpoint,
        on_progress=lambda st, info: progress.append(st.env_steps),
    )
    assert [s[1].env_steps for s in saved] == [16, 32] and progress
    path, st, rows = saved[0]
    learner = load_learner(path)
    assert st.updates == 2 and learner.counters["updates"] == 2
    # resume from the first checkpoint: B^k as it was then, a fresh env whose counters are restored
    resumed_buffer = buffer.select(torch.arange(rows))
    collector2 = rl_loop.ChunkCollector(
        FakeEnv(N_ENVS, 5), reference, features, resumed_buffer, task_index=0, gamma=0.99
    )
    evaluator2 = rl_loop.Evaluator(lambda t, n: FakeEnv(n, 100), {T1: reference}, features, 2, N_ENVS, H, 0.99)
    again, again_state = train_stage(
        cfg, None, None, None, collector2, evaluator2, settings, resume=(learner, copy.deepcopy(st))
    )
    assert again_state.env_steps == full_state.env_steps and again_state.updates == full_state.updates
    assert again_state.curve == full_state.curve
    assert same_weights(again.actor, full.actor) and same_weights(again.critic, full.critic)


def test_fresh_distillation_inputs_reach_eq4(monkeypatch):
    """Survivors train_stage 41, 52, 59 and cache_teacher 25-38: with distill_inputs "fresh" the prior batch
    carries the current base policy's chunk of its own task (float32), and Eq. 4's student reads it."""
    cfg = config("accrue", distill_inputs="fresh")
    previous = make_learner(cfg.replace(seed=11), D, H, A)
    memory = ReplayBuffer.concat([memory_buffer(), relabel_task(memory_buffer(), 1)])
    per_task = {0: 0.3, 1: -0.4}
    teacher = cache_teacher(previous, memory, lambda s, task: np.full((len(s), H, A), per_task[task], np.float32))
    assert teacher.fresh_ref.dtype == torch.float32
    tasks = memory.column("task")
    for t, value in per_task.items():
        assert bool((teacher.fresh_ref[tasks == t] == value).all())
    rec = Recorder(monkeypatch)
    buffer, collector, evaluator = stage_parts()
    evaluator = rl_loop.Evaluator(
        lambda t, n: FakeEnv(n, 100), {T1: reference, T2: reference}, features, 2, N_ENVS, H, 0.99
    )
    settings = rl_loop.LoopSettings([T1, T2], env_steps=16, eval_every=16, checkpoint_every=0)
    train_stage(cfg, previous, memory, teacher, collector, evaluator, settings)
    assert rec.updates
    for u in rec.updates:
        prior = u["prior"]
        assert prior.fresh_ref is not None and torch.equal(prior.fresh_ref, teacher.fresh_ref[prior.index])
    # the student's inputs are (s_j, ã'_j): its output at the fresh chunk, not at the stored ã_j
    assert len(rec.eq4) == len(rec.updates)
    for u, e in zip(rec.updates, rec.eq4):
        assert e["student"].shape[0] == BATCH
        assert torch.equal(e["teacher"], u["prior"].teacher)
        torch.testing.assert_close(e["student"], u["student_fresh"])
        assert not torch.allclose(e["student"], u["student"])
    assert isinstance(teacher, TeacherCache)


def relabel_task(buf: ReplayBuffer, task: int) -> ReplayBuffer:
    out = ReplayBuffer(D, H, A)
    c = buf.column
    out.add(
        c("state"),
        c("action"),
        c("ref"),
        c("reward"),
        c("next_state"),
        c("next_ref"),
        c("done"),
        task,
        c("episode"),
        ended=c("ended"),
    )
    return out


# ------------------------------------------------------------------------------------ hand_over, rules
def test_hand_over_report_by_hand():
    """Survivors hand_over 17-31: the report's keys and counts, and `short` only below n (not at n)."""
    current = memory_buffer()  # 12 complete episodes of task 0
    memory, report = hand_over(None, current, 12)
    assert report == {
        "retained_episodes": 12,
        "kept": {"0": 12},
        "current_complete_episodes": {"0": 12},
        "short": [],
    }
    _, report = hand_over(memory, relabel_task(current, 1), 13)
    assert report["short"] == ["1"] and report["current_complete_episodes"] == {"1": 12}


def test_rules_refuses_an_ablation_of_another_method_naming_both():
    """Survivor methods.rules 9: the error names the ablation."""
    with pytest.raises(ValueError, match="^ablation beta0 applies to method 'accrue' only$"):
        rules("er", "beta0")


def test_actor_loss_without_alpha_has_no_entropy_term():
    """Survivor actor_loss_current 1: α defaults to 0, so a log π passed without α changes nothing."""
    q, a, ref = torch.tensor([1.0, 2.0]), torch.zeros(2, 1, 1), torch.ones(2, 1, 1)
    base = actor_loss_current(q, a, ref, 0.5)
    assert float(actor_loss_current(q, a, ref, 0.5, torch.tensor([3.0, 4.0]))) == float(base)


def test_copy_learner_is_an_independent_copy():
    """Survivors (no tests) continual.copy_learner 1-2: Isolated's per-task learner is a deep copy."""
    from accrue.learner import copy_learner

    learner = make_learner(config("isolated"), D, H, A)
    kept = copy_learner(learner)
    assert kept is not learner and same_weights(kept.actor, learner.actor)
    with torch.no_grad():
        next(learner.actor.parameters()).add_(1.0)
    assert not same_weights(kept.actor, learner.actor)


# ------------------------------------------------------------------------------------ metrics
def test_iqm_and_bootstrap_edge_cases_by_hand():
    """Survivors metrics.iqm 4-17 and bootstrap_ci 10: the interquartile mean drops floor(n/4) values at
    each end; one value is its own IQM; no values is one exact error."""
    from accrue.metrics import bootstrap_ci, iqm

    assert iqm([4, 0, 60, 2, 0, 3, 50, 1]) == pytest.approx(2.5)  # cut 2: mean of 1, 2, 3, 4 (cut 1 gives 10)
    assert iqm([1.0, 2.0, 3.0, 10.0, 20.0]) == pytest.approx(5.0)  # cut 1: mean of 2, 3, 10
    assert iqm([5.0]) == 5.0
    with pytest.raises(AccrueError, match="^iqm: no values$"):
        iqm([])
    with pytest.raises(AccrueError, match="^bootstrap_ci: no values$"):
        bootstrap_ci([])
