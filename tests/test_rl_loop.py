"""accrue.rl_loop without the store: warmup, the evaluation grid, repeatable evaluation, and exact resume
of the train loop from a checkpoint (learner + replay shards + loop state) on the real sim."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from accrue import rl_loop
from accrue.learner import LearnerConfig, ReplayBuffer, load_learner, make_learner, save_learner
from accrue.learner_inputs import state_features
from accrue.sim import STATE_DIM, make_vec_env

TASK, H, N = "nist/rect_peg", 4, 2


@pytest.fixture(autouse=True)
def one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def reference(obs):
    """A deterministic stand-in for π_base: push down, correct the lateral offset from the estimate."""
    s = np.asarray(obs["state"], dtype=np.float32)
    a = np.zeros((len(s), 6), dtype=np.float32)
    a[:, 2] = -0.6
    a[:, :2] = np.clip(0.05 * s[:, :2], -1, 1)
    return np.repeat(a[:, None, :], H, axis=1)


def small_learner(seed=0):
    cfg = LearnerConfig(
        actor_hidden=[32, 32], critic_hidden=[32, 32], projector_dim=16, batch_size=32, num_atoms=11, utd=1, seed=seed
    )
    return make_learner(cfg, STATE_DIM, H)


def make_collector(buffer, next_episode=0):
    env = make_vec_env(TASK, N, seed=11)
    return rl_loop.ChunkCollector(
        env, reference, state_features, buffer, task_index=0, gamma=0.99, next_episode=next_episode
    )


def make_evaluator(episodes=3):
    return rl_loop.Evaluator(
        lambda t, n: make_vec_env(t, n, seed=99), {TASK: reference}, state_features, episodes, N, H, 0.99
    )


def test_grid_and_checkpoint_points():
    s = rl_loop.LoopSettings([TASK], env_steps=1000, eval_every=300, checkpoint_every=0)
    assert s.grid() == [0, 300, 600, 900, 1000]
    assert s.checkpoint_points() == [300, 600, 900]
    assert rl_loop.LoopSettings([TASK], 1000, 500, 200).checkpoint_points() == [200, 400, 600, 800]
    assert rl_loop.LoopSettings([TASK], 1000, 500, 200, min_checkpoint_gap=300).checkpoint_points() == [300, 600, 900]


def test_env_seeds_differ_by_purpose_and_eval_seed_ignores_stage():
    seeds = {rl_loop.env_seed(0, 1, p) for p in ("warmup", "train")} | {rl_loop.env_seed(0, 1, "eval", 0)}
    assert len(seeds) == 3
    assert rl_loop.env_seed(0, 1, "eval", 2) == rl_loop.env_seed(0, 3, "eval", 2)
    assert rl_loop.env_seed(0, 1, "train") != rl_loop.env_seed(0, 2, "train")


def test_warmup_fills_the_buffer_with_base_policy_chunks():
    buf = ReplayBuffer(STATE_DIM, H)
    col = make_collector(buf)
    col.restart()
    stats = rl_loop.warmup(col, 3)
    assert stats.episodes >= 3 and len(buf) > 0
    assert torch.equal(buf.column("action"), buf.column("ref"))  # π_base executed as is
    assert stats.env_steps > 0 and stats.successes <= stats.episodes
    ids = buf.column("episode").unique()
    assert len(ids) >= 3 and col.next_episode > int(ids.max())
    assert int(buf.column("done").sum()) == stats.successes  # done = termination (success)


def test_evaluation_is_repeatable_and_counts_exactly_m_episodes():
    ev = make_evaluator(episodes=3)
    first = ev.success_rate(TASK)
    assert first == ev.success_rate(TASK)
    assert first in (0.0, 1 / 3, 2 / 3, 1.0)
    # the act function is what is scored: with a reference that succeeds (the scripted stand-in with the
    # fixture's bias known), passing ã through reproduces its rate exactly, and lifting the plug scores 0
    from accrue.scripted_reference import ScriptedReference
    from accrue.sim import get_task

    scripted, instruction = ScriptedReference(1.0), get_task(TASK).instruction
    good = rl_loop.Evaluator(
        lambda t, n: make_vec_env(t, n, seed=99),
        {TASK: lambda obs: scripted.reference_chunk(obs, instruction, H)},
        state_features,
        4,
        N,
        H,
        0.99,
    )
    base = good.success_rate(TASK)
    assert base > 0
    assert good.success_rate(TASK, lambda s, ref, fresh: ref) == base
    lift = np.zeros((1, H, 6), dtype=np.float32)
    lift[..., 2] = 1.0
    assert good.success_rate(TASK, lambda s, ref, fresh: np.repeat(lift, len(s), 0)) == 0.0


def train_with_checkpoints(tmp_path, settings, evaluator, stop_after_checkpoint=None, resume_dir=None):
    """train_loop from a fresh warmup, or from a saved checkpoint; each checkpoint is saved as the train
    step saves it (learner, new replay shards, loop state, the e* actor snapshot); optionally raise after
    the n-th checkpoint (a crash). Returns (final LoopState or None after a crash, checkpoints, learner,
    buffer)."""
    from stages.steps.sim_env import CHOSEN_ACTOR_FILE, load_actor_snapshot

    torch.manual_seed(0)  # the global RNG is part of the saved state (the train step seeds it too)
    if resume_dir is None:
        buf = ReplayBuffer(STATE_DIM, H)
        col = make_collector(buf)
        col.restart()
        rl_loop.warmup(col, 2)
        learner, state = small_learner(), rl_loop.LoopState(next_episode=col.next_episode)
        col = make_collector(buf, state.next_episode)
        col.restart()
    else:
        buf = ReplayBuffer.load(resume_dir / "replay")
        learner = load_learner(resume_dir / "learner")
        state = rl_loop.LoopState.from_json(json.loads((resume_dir / "loop.json").read_text()))
        if (resume_dir / CHOSEN_ACTOR_FILE).exists():
            state.chosen_actor = load_actor_snapshot(learner, resume_dir / CHOSEN_ACTOR_FILE)
        col = make_collector(buf, state.next_episode)
        rl_loop.restore_collector(col, state)
    saved = []

    def on_checkpoint(st):
        d = tmp_path / f"ckpt-{len(saved)}"
        save_learner(learner, d / "learner")
        buf.save_new_shards(d / "replay")
        (d / "loop.json").write_text(json.dumps(st.to_json()))
        if st.chosen_actor is not None:
            torch.save(st.chosen_actor.state_dict(), d / CHOSEN_ACTOR_FILE)
        saved.append(d)
        if stop_after_checkpoint is not None and len(saved) == stop_after_checkpoint:
            raise KeyboardInterrupt

    try:
        state = rl_loop.train_loop(learner, col, evaluator, settings, state=state, on_checkpoint=on_checkpoint)
    except KeyboardInterrupt:
        return None, saved, learner, buf
    return state, saved, learner, buf


def run_loop(tmp_path, stop_after_checkpoint=None, resume_dir=None):
    """Train 240 env steps with checkpoints every 80."""
    settings = rl_loop.LoopSettings([TASK], env_steps=240, eval_every=120, checkpoint_every=80)
    state, saved, learner, buf = train_with_checkpoints(
        tmp_path, settings, make_evaluator(2), stop_after_checkpoint, resume_dir
    )
    if state is None:
        return None, saved
    final = tmp_path / "final"
    save_learner(learner, final / "learner")
    buf.save_new_shards(final / "replay")
    return (state, final), saved


def files(d):
    return {p.relative_to(d).as_posix(): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


def test_resumed_loop_ends_with_identical_bytes(tmp_path):
    (full_state, full_dir), saved = run_loop(tmp_path / "a")
    assert len(saved) == 2 and full_state.env_steps >= 240
    assert full_state.grid_done == [0, 120, 240] and len(full_state.curve[TASK]) == 3
    crashed, crash_saved = run_loop(tmp_path / "b", stop_after_checkpoint=1)
    assert crashed is None and len(crash_saved) == 1
    (resumed_state, resumed_dir), _ = run_loop(tmp_path / "c", resume_dir=crash_saved[0])
    assert resumed_state.to_json() == full_state.to_json()
    assert files(resumed_dir) == files(full_dir)


def test_scripted_reference_holds_one_expert_action_and_misses_by_the_unknown_bias():
    from accrue.scripted_reference import ScriptedReference, parse_spec
    from accrue.sim import get_task, make_expert

    assert parse_spec("scripted-reference") == 0.0 and parse_spec("scripted-reference:0.5") == 0.5
    assert parse_spec("embedded-act") is None
    obs = make_vec_env(TASK, 3, seed=4).reset()
    instruction = get_task(TASK).instruction
    blind = ScriptedReference(0.0).reference_chunk(obs, instruction, H)
    knowing = ScriptedReference(1.0).reference_chunk(obs, instruction, H)
    assert blind.shape == (3, H, 6) and blind.dtype == np.float32
    np.testing.assert_allclose(knowing[:, 0], make_expert(TASK, 1.0, seed=0).act(obs["state"]), atol=1e-6)
    assert np.all(blind[:, 1:, [0, 1, 3, 4, 5]] == 0) and np.all(blind[:, 1:, 2] == blind[:, :1, 2])
    assert not np.allclose(blind[:, 0, :2], knowing[:, 0, :2])  # aims at the biased estimate


EARLIER = "nist/round_peg"


class CountingEvaluator(rl_loop.Evaluator):
    """Counts the episodes it scores, per task."""

    def __init__(self, *args, **kw):
        super().__init__(*args, **kw)
        self.scored: dict[str, int] = {}

    def success_rate(self, task_id, act=None):
        self.scored[task_id] = self.scored.get(task_id, 0) + self.episodes
        return super().success_rate(task_id, act)


def two_task_loop(full_curves: bool, crash_after=None, resume_dir=None, tmp_path=None):
    """Stage 2 of [EARLIER, TASK] with selection and report sets; checkpoints save the e* actor snapshot as
    the train step does (stages.steps.sim_env)."""
    from accrue.scripted_reference import ScriptedReference
    from accrue.sim import get_task

    tasks = [EARLIER, TASK]
    settings = rl_loop.LoopSettings(tasks, 240, 80, 120, full_curves=full_curves)
    scripted = ScriptedReference(0.5)  # succeeds sometimes, so the actor's changes move the curves
    references = {t: (lambda obs, i=get_task(t).instruction: scripted.reference_chunk(obs, i, H)) for t in tasks}

    def evaluator(seed, episodes, report=None):
        make = lambda t, n: make_vec_env(t, n, seed=seed + tasks.index(t))  # noqa: E731
        return CountingEvaluator(make, references, state_features, episodes, N, H, 0.99, report)

    report = evaluator(500, 4)
    ev = evaluator(99, 2, report)
    state, saved, _, _ = train_with_checkpoints(tmp_path, settings, ev, crash_after, resume_dir)
    return state, ev, saved


def stage_metrics(state: rl_loop.LoopState):
    """The continual metrics of a two-stage run whose stage 2 is this loop (stage 1 a fixed curve)."""
    from accrue.metrics import continual_metrics

    stage1 = [0.2, 0.6, 0.5, 0.4]
    curves = [[stage1], [state.curve[EARLIER], state.curve[TASK]]]
    report = [[stage1], [state.report_curve[EARLIER], state.report_curve[TASK]]]
    return continual_metrics(curves, report)


def test_scoring_earlier_tasks_at_the_chosen_checkpoint_only_gives_the_same_metrics(tmp_path):
    full, full_ev, _ = two_task_loop(True, tmp_path=tmp_path / "full")
    chosen, chosen_ev, _ = two_task_loop(False, tmp_path=tmp_path / "chosen")
    # the current task is scored at every point either way, identically (evaluation leaves training alone)
    assert chosen.curve[TASK] == full.curve[TASK] and chosen.report_curve[TASK] == full.report_curve[TASK]
    assert chosen.chosen == full.chosen == int(np.argmax(full.curve[TASK]))
    assert 0 < full.chosen < 3  # e* is neither the start nor the end: the snapshot is what gets scored
    # the earlier task: once, on the report set, at e*, with the actor deployed there
    e = chosen.chosen
    assert chosen.report_curve[EARLIER][e] == full.report_curve[EARLIER][e]
    assert [v for i, v in enumerate(chosen.report_curve[EARLIER]) if i != e] == [None] * 3
    assert chosen.curve[EARLIER] == [None] * 4
    assert stage_metrics(chosen) == stage_metrics(full)
    # what it saves: the earlier task's selection episodes at every point, its report episodes at all but e*
    assert full_ev.scored[EARLIER] == 4 * 2 and full_ev.report.scored[EARLIER] == 4 * 4
    assert EARLIER not in chosen_ev.scored and chosen_ev.report.scored[EARLIER] == 4
    assert chosen_ev.scored[TASK] == full_ev.scored[TASK]


def test_a_resumed_loop_scores_the_chosen_checkpoint_it_had_saved(tmp_path):
    whole, _, _ = two_task_loop(False, tmp_path=tmp_path / "a")
    crashed, _, saved = two_task_loop(False, crash_after=1, tmp_path=tmp_path / "b")
    assert crashed is None and (saved[0] / "chosen_actor.pt").exists()
    resumed, _, _ = two_task_loop(False, resume_dir=saved[0], tmp_path=tmp_path / "c")
    assert resumed.to_json() == whole.to_json()


def test_the_grid_scores_the_deployed_actor_not_the_base_policy():
    """Mutation eval-scores-base-policy: a learner whose deployed actor lifts the plug scores 0 at every
    grid point, where the scripted base policy alone succeeds."""
    from types import SimpleNamespace

    from accrue.scripted_reference import ScriptedReference
    from accrue.sim import get_task

    scripted, instruction = ScriptedReference(1.0), get_task(TASK).instruction

    def base(obs):
        return scripted.reference_chunk(obs, instruction, H)

    class LiftingLearner:
        cfg = SimpleNamespace(utd=1)

        def act(self, s, ref, explore=True, reset_mask=None):
            return ref

        def train_step(self, *args):
            return {}

        def deployed_actor(self):
            return "lifting"

        def act_with(self, actor, s, ref):
            out = np.zeros((len(s), H, 6), dtype=np.float32)
            out[..., 2] = 1.0
            return out

    ev = rl_loop.Evaluator(lambda t, n: make_vec_env(t, n, seed=99), {TASK: base}, state_features, 4, N, H, 0.99)
    assert ev.success_rate(TASK) > 0
    buf = ReplayBuffer(STATE_DIM, H)
    col = make_collector(buf)
    col.restart()
    state = rl_loop.train_loop(LiftingLearner(), col, ev, rl_loop.LoopSettings([TASK], 16, 8, 0))
    assert state.curve[TASK] == [0.0, 0.0, 0.0]


def test_a_state_from_before_e_star_was_tracked_keeps_the_scores_it_has(tmp_path):
    """A loop state without `chosen` (saved while every task was scored at every point) derives e* from the
    current task's curve, and earlier tasks already scored there are kept: nothing is scored again."""
    full, ev, _ = two_task_loop(True, tmp_path=tmp_path / "a")
    old = {k: v for k, v in full.to_json().items() if k not in ("chosen", "chosen_scored")}
    state = rl_loop.LoopState.from_json(json.loads(json.dumps(old)))
    scored = dict(ev.report.scored)
    settings = rl_loop.LoopSettings([EARLIER, TASK], 240, 80, 120)
    done = rl_loop.train_loop(None, None, ev, settings, state=state)
    assert done.chosen == full.chosen and done.chosen_scored
    assert done.report_curve == full.report_curve and ev.report.scored == scored
