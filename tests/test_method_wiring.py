"""What the learner receives, per method row, when a stage runs through `stage_rl.train_stage` (issue 23).

The loss functions have their own tests; these check the wiring one level up, where a method can
silently turn into another: every gradient update of a stage-2 run is recorded (the current and prior
minibatches, the critic's batch, Eq. 1's arguments, Eq. 4's arguments, the update's info) and compared
with what the method's row of `accrue.methods` says it must read. Tiny networks on a scripted fake
environment (no simulator): the whole file runs in a few seconds.

Planted bugs these tests name (scripts/mutation_critical.py applies them one at a time):
    accrue-becomes-sequential   rl_loop.train_loop no longer passes B^{<k} / the cached targets
    lambda-hardcoded-1          λ replaced by 1.0 in Eq. 5
    beta-hardcoded-0            β replaced by 0 in the Eq. 1 call
    beta-term-dropped           Eq. 1 without its β‖a − ã‖² term
    critic-reads-prior          ACCRUE's critic trained on B^k ∪ B^{<k}
    er-actor-current-only       ER's Eq. 1 no longer on B^{<k}
    teacher-rows-misaligned     cached targets not indexed like the sampled prior rows
    isolated-frozen-ignored     Isolated's per-task actors not used for their tasks' evaluation
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from accrue import rl_loop
from accrue.learner import LearnerConfig, ReplayBuffer, agent, losses, make_learner
from accrue.stage_rl import cache_teacher, train_stage

pytestmark = pytest.mark.usefixtures("one_torch_thread")

D, H, A, N_ENVS, LENGTH = 5, 4, 6, 2, 3  # state dim, chunk, action dim, envs, chunks per episode
T1, T2 = "fake/one", "fake/two"
BATCH = 8
MEMORY_ROWS = 48
MEMORY_OFFSET = 1000.0  # memory rows carry state[:, 0] = 1000 + row: a prior row is recognisable


class FakeEnv:
    """A scripted vectorised env: an episode is LENGTH chunks; it succeeds when the last chunk's mean
    z-action exceeds 0.5 (so lifting the plug succeeds and the near-zero reference does not)."""

    def __init__(self, n: int, seed: int):
        self.num_envs, self.seed = n, seed
        self.episode = np.full(n, -1, dtype=np.int64)
        self.t = np.zeros(n, dtype=np.int64)
        self.s = np.zeros((n, D), dtype=np.float32)

    def reset(self, mask=None):
        rows = np.arange(self.num_envs) if mask is None else np.flatnonzero(mask)
        self.episode[rows] += 1
        self.t[rows] = 0
        for i in rows:
            g = np.random.default_rng([self.seed, i, int(self.episode[i])])
            self.s[i] = g.normal(size=D).astype(np.float32)
        return {"state": self.s.copy()}

    def step_chunk(self, a, gamma):
        a = np.asarray(a, dtype=np.float32)
        self.t += 1
        self.s = self.s + 0.1 * a.mean(axis=(1, 2))[:, None]
        last = self.t >= LENGTH
        success = last & (a[..., 2].mean(axis=1) > 0.5)
        return SimpleNamespace(
            obs={"state": self.s.copy()},
            reward=success.astype(np.float32),
            terminated=success,
            truncated=last & ~success,
            steps=np.full(self.num_envs, H),
            success=success,
        )

    def close(self):
        pass


def reference(obs):
    return np.full((len(obs["state"]), H, A), 0.1, dtype=np.float32)


def features(obs):
    return np.asarray(obs["state"], dtype=np.float32)


def config(method="accrue", **kw) -> LearnerConfig:
    small = dict(
        actor_hidden=[16],
        critic_hidden=[16],
        projector_dim=8,
        batch_size=BATCH,
        num_atoms=11,
        utd=1,
        policy_frequency=1,
        ewc_samples=16,
        beta=0.23,
        lam=0.37,
        actor_init_scale=1.0,  # δ well away from 0: a ≠ ã, so the β term is not negligible
    )
    return LearnerConfig(method=method, **{**small, **kw})


def memory_buffer() -> ReplayBuffer:
    """B^{<2}: task 0's retained episodes of 4 rows each; state[:, 0] = 1000 + row index."""
    g = torch.Generator().manual_seed(7)
    n = MEMORY_ROWS
    state = torch.randn(n, D, generator=g)
    state[:, 0] = MEMORY_OFFSET + torch.arange(n, dtype=torch.float32)
    buf = ReplayBuffer(D, H, A)
    buf.add(
        state,
        torch.rand(n, H, A, generator=g) * 1.6 - 0.8,
        torch.rand(n, H, A, generator=g) * 1.6 - 0.8,
        torch.zeros(n),
        torch.randn(n, D, generator=g),
        torch.rand(n, H, A, generator=g) * 1.6 - 0.8,
        torch.zeros(n, dtype=torch.bool),
        0,
        torch.arange(n) // 4,
        ended=(torch.arange(n) % 4) == 3,
    )
    return buf


class Recorder:
    """Records every gradient update of the learner (class-level wrappers, so the stage's own learner)."""

    def __init__(self, monkeypatch):
        self.updates, self.critic_batches, self.eq1, self.eq4 = [], [], [], []
        rec = self
        update, critic_update = agent.ChunkLearner._update, agent.ChunkLearner._critic_update
        eq1, eq4 = losses.actor_loss_current, losses.distill_loss_prior

        def spy_update(self, current, prior, actor_on=True):
            entry = {"current": current, "prior": prior, "learner": self, "actor_on": actor_on}
            entry["actor_before"] = {k: v.detach().clone() for k, v in self.actor.state_dict().items()}
            entry["critic_before"] = {k: v.detach().clone() for k, v in self.critic.state_dict().items()}
            if prior is not None:
                with torch.no_grad():  # Eq. 4's student output, before the update moves θ
                    entry["student"] = self.actor.deterministic(prior.state, self._ref_in(prior.ref))
                    if prior.fresh_ref is not None:
                        entry["student_fresh"] = self.actor.deterministic(prior.state, self._ref_in(prior.fresh_ref))
            rec.updates.append(entry)
            entry["info"] = update(self, current, prior, actor_on)
            return entry["info"]

        def spy_critic(self, b):
            rec.critic_batches.append(b)
            return critic_update(self, b)

        def spy_eq1(q, action, ref, beta, log_prob=None, alpha=0.0):
            out = eq1(q, action, ref, beta, log_prob, alpha)
            rec.eq1.append(dict(q=q.detach(), action=action.detach(), ref=ref.detach(), beta=beta, out=out.detach()))
            return out

        def spy_eq4(student, teacher):
            out = eq4(student, teacher)
            rec.eq4.append(dict(student=student.detach(), teacher=teacher.detach(), out=out.detach()))
            return out

        monkeypatch.setattr(agent.ChunkLearner, "_update", spy_update)
        monkeypatch.setattr(agent.ChunkLearner, "_critic_update", spy_critic)
        monkeypatch.setattr(losses, "actor_loss_current", spy_eq1)
        monkeypatch.setattr(losses, "distill_loss_prior", spy_eq4)


def run_stage2(cfg: LearnerConfig, *, teacher="cached", frozen_acts=None, env_steps=24):
    """Stage 2 of a two-task run: a stage-1 learner, B^{<2}, the cached Eq. 3 targets, warmup, train_stage."""
    previous = make_learner(cfg.replace(seed=11), D, H, A)
    previous.stage = 1
    memory = memory_buffer()
    if teacher == "cached":
        teacher = cache_teacher(previous, memory) if cfg.rules.distill else None
    buffer = ReplayBuffer(D, H, A)
    collector = rl_loop.ChunkCollector(FakeEnv(N_ENVS, 5), reference, features, buffer, task_index=1, gamma=0.99)
    collector.restart()
    rl_loop.warmup(collector, 2)
    evaluator = rl_loop.Evaluator(
        lambda t, n: FakeEnv(n, 100 + [T1, T2].index(t)), {T1: reference, T2: reference}, features, 2, N_ENVS, H, 0.99
    )
    settings = rl_loop.LoopSettings([T1, T2], env_steps=env_steps, eval_every=env_steps, checkpoint_every=0)
    learner, state = train_stage(cfg, previous, memory, teacher, collector, evaluator, settings, frozen_acts)
    return SimpleNamespace(previous=previous, memory=memory, teacher=teacher, learner=learner, state=state)


def is_memory_row(batch) -> torch.Tensor:
    return batch.state[:, 0] >= MEMORY_OFFSET


# ------------------------------------------------------------------------------------------- ACCRUE
def test_accrue_learner_receives_prior_memory_and_cached_targets_accrue_becomes_sequential(monkeypatch):
    """Mutation accrue-becomes-sequential: every update gets a minibatch of B^{<k} carrying the cached
    Eq. 3 targets of exactly its rows (teacher-rows-misaligned), and Eq. 4 reads them."""
    rec = Recorder(monkeypatch)
    run = run_stage2(config("accrue"))
    assert run.state.updates == len(rec.updates) > 0
    memory_state = run.memory.column("state")
    for u in rec.updates:
        prior, cur = u["prior"], u["current"]
        assert prior is not None and len(prior) == BATCH, "ACCRUE's update got no B^{<k} minibatch"
        assert bool(is_memory_row(prior).all()) and not bool(is_memory_row(cur).any())
        assert torch.equal(prior.state, memory_state[prior.index])
        assert prior.teacher is not None
        assert torch.equal(prior.teacher, run.teacher.targets[prior.index])
    # Eq. 4 reads the student's output at the stored (s_j, ã_j) and the cached â_j, once per actor update
    assert len(rec.eq4) == len(rec.updates)
    for u, e in zip(rec.updates, rec.eq4):
        assert torch.equal(e["teacher"], u["prior"].teacher)
        torch.testing.assert_close(e["student"], u["student"])
        hand = ((e["student"] - e["teacher"]) ** 2).flatten(1).sum(1).mean()
        torch.testing.assert_close(e["out"], hand)
        assert float(e["out"]) > 0


def test_accrue_teacher_targets_are_the_previous_actor_at_the_stored_inputs():
    """Eq. 3 as cached by stage_rl.cache_teacher: â_j = π̄_{θ^{k-1}}(s_j, ã_j), row for row."""
    cfg = config("accrue")
    previous = make_learner(cfg.replace(seed=11), D, H, A)
    memory = memory_buffer()
    cache = cache_teacher(previous, memory)
    with torch.no_grad():
        want = previous.actor.deterministic(memory.column("state"), memory.column("ref"))
    torch.testing.assert_close(cache.targets, want)
    assert cache.fresh_ref is None


def test_accrue_critic_reads_current_task_only_critic_reads_prior(monkeypatch):
    """Mutation critic-reads-prior: ACCRUE's critic (Eq. 2) and Eq. 1 see B^k only; B^{<k} only reaches Eq. 4."""
    rec = Recorder(monkeypatch)
    run_stage2(config("accrue"))
    assert rec.critic_batches and all(len(b) == BATCH and not bool(is_memory_row(b).any()) for b in rec.critic_batches)
    assert rec.eq1 and all(e["q"].shape[0] == BATCH for e in rec.eq1)


def test_critic_all_replay_ablation_critic_reads_both(monkeypatch):
    rec = Recorder(monkeypatch)
    run_stage2(config("accrue", ablation="critic-all-replay"))
    for b in rec.critic_batches:
        assert len(b) == 2 * BATCH and int(is_memory_row(b).sum()) == BATCH
    assert len(rec.eq4) == len(rec.updates) > 0  # still distils


def test_lambda_from_config_weights_eq4_in_eq5_lambda_hardcoded_1(monkeypatch):
    """Mutation lambda-hardcoded-1: loss_actor == loss_cur + λ·loss_prior with the config's λ (0.37)."""
    rec = Recorder(monkeypatch)
    run_stage2(config("accrue", lam=0.37))
    assert rec.updates
    for u in rec.updates:
        info = u["info"]
        assert float(info["loss_prior"]) > 0
        want = float(info["loss_cur"]) + 0.37 * float(info["loss_prior"])
        assert float(info["actor_loss"]) == pytest.approx(want, rel=1e-5, abs=1e-7)


def test_beta_from_config_is_the_eq1_anchor_beta_hardcoded_0(monkeypatch):
    """Mutations beta-hardcoded-0 and beta-term-dropped: Eq. 1 gets the config's β (0.23), and its value is
    E[−Q + β‖a − ã‖²] by hand, with ã the current minibatch's stored reference chunk."""
    rec = Recorder(monkeypatch)
    run_stage2(config("accrue", beta=0.23))
    assert len(rec.eq1) == len(rec.updates) > 0
    for u, e in zip(rec.updates, rec.eq1):
        assert e["beta"] == pytest.approx(0.23)
        assert torch.equal(e["ref"], u["current"].ref)
        dist = ((e["action"] - e["ref"]) ** 2).flatten(1).sum(1)
        assert float(dist.mean()) > 1e-2  # the anchor term is not trivially zero here
        hand = (-e["q"] + 0.23 * dist).mean()
        torch.testing.assert_close(e["out"], hand)
        assert float(u["info"]["loss_cur"]) == pytest.approx(float(hand), rel=1e-5, abs=1e-6)


def test_beta0_ablation_passes_zero_beta(monkeypatch):
    rec = Recorder(monkeypatch)
    run_stage2(config("accrue", ablation="beta0", beta=0.23))
    assert rec.eq1 and all(e["beta"] == 0.0 for e in rec.eq1)


# ----------------------------------------------------------------------------------------- baselines
@pytest.mark.parametrize("method", ["sequential", "ewc", "retain", "isolated", "single-task"])
def test_methods_without_prior_memory_never_see_it(monkeypatch, method):
    """Sequential and the regularisation baselines: no B^{<k} minibatch, no Eq. 4, critic on B^k."""
    rec = Recorder(monkeypatch)
    run_stage2(config(method))
    assert rec.updates
    assert all(u["prior"] is None for u in rec.updates)
    assert not rec.eq4
    assert all(len(b) == BATCH and not bool(is_memory_row(b).any()) for b in rec.critic_batches)
    assert all("loss_prior" not in u["info"] for u in rec.updates)


def test_er_replays_prior_memory_in_critic_and_actor_without_distillation_er_actor_current_only(monkeypatch):
    """Mutation er-actor-current-only: ER's critic and Eq. 1 both read B^k ∪ B^{<k}; no teacher, no Eq. 4."""
    rec = Recorder(monkeypatch)
    run_stage2(config("er"))
    assert rec.updates
    for u in rec.updates:
        assert u["prior"] is not None and bool(is_memory_row(u["prior"]).all())
        assert u["prior"].teacher is None
    for b in rec.critic_batches:
        assert len(b) == 2 * BATCH and int(is_memory_row(b).sum()) == BATCH
    assert all(e["q"].shape[0] == 2 * BATCH for e in rec.eq1)
    assert not rec.eq4


@pytest.mark.parametrize(
    "method, ablation, same_actor, same_critic",
    [
        ("accrue", "none", True, True),
        ("sequential", "none", True, True),
        ("accrue", "reset-critic", True, False),
        ("single-task", "none", False, False),
    ],
)
def test_what_a_stage_inherits(monkeypatch, method, ablation, same_actor, same_critic):
    """Line 1: at the first update the actor/critic are θ^{k-1}/ψ^{k-1} exactly when the row says so."""
    rec = Recorder(monkeypatch)
    run = run_stage2(config(method, ablation=ablation))
    first = rec.updates[0]
    prev_actor, prev_critic = run.previous.actor.state_dict(), run.previous.critic.state_dict()
    actor_same = all(torch.equal(first["actor_before"][k], prev_actor[k]) for k in prev_actor if "obs_norm" not in k)
    critic_same = all(torch.equal(first["critic_before"][k], prev_critic[k]) for k in prev_critic)
    assert (actor_same, critic_same) == (same_actor, same_critic)


def test_ewc_penalises_with_a_fisher_from_the_previous_task(monkeypatch):
    rec = Recorder(monkeypatch)
    run = run_stage2(config("ewc"))
    learner = run.learner
    assert learner.ewc_fisher and set(learner.ewc_anchor) == set(learner.ewc_fisher)
    prev = dict(run.previous.actor.named_parameters())
    assert all(torch.equal(learner.ewc_anchor[k], prev[k].detach()) for k in learner.ewc_anchor)
    assert all("ewc_penalty" in u["info"] for u in rec.updates)
    assert float(rec.updates[0]["info"]["ewc_penalty"]) == 0.0  # θ = θ* before the first step
    assert float(rec.updates[-1]["info"]["ewc_penalty"]) > 0.0


@pytest.mark.parametrize("interval", [0, 1])
def test_retain_merges_at_stage_end_and_every_retain_interval_updates(monkeypatch, interval):
    """RETAIN's retain_interval: 0 merges only at end_stage; n > 0 also after every n-th actor update."""
    Recorder(monkeypatch)
    run = run_stage2(config("retain", retain_interval=interval))
    learner = run.learner
    actor_updates = learner.counters["actor_updates"]
    assert actor_updates > 1
    assert learner.counters["merges"] == 1 + (actor_updates if interval else 0)
    prev = dict(run.previous.actor.named_parameters())
    assert all(torch.equal(learner.retain_prev[k], prev[k].detach()) for k in learner.retain_prev)


def test_isolated_scores_each_earlier_task_with_its_own_actor_isolated_frozen_ignored(monkeypatch):
    """Mutations isolated-frozen-ignored and chosen-scores-base-policy: with frozen_acts for task 1 (an actor
    that lifts z and so always succeeds on the fake env), task 1's score is that actor's, task 2's curve the
    stage's own (near ã: fails). Task 1 is scored once, at e* (the earliest best point of task 2: 0)."""
    lifted = []

    def lift(s, ref, fresh):
        lifted.append(len(s))
        out = np.zeros((len(s), H, A), dtype=np.float32)
        out[..., 2] = 0.9
        return out

    Recorder(monkeypatch)
    run = run_stage2(config("isolated"), frozen_acts={T1: lift})
    assert lifted
    assert run.state.curve[T1] == [1.0, None]
    assert run.state.curve[T2] == [0.0, 0.0]
    # without the frozen actor, task 1 is scored with the stage's actor (near ã) and fails
    plain = run_stage2(config("isolated"))
    assert plain.state.curve[T1] == [0.0, None]
