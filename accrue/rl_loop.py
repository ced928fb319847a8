"""One stage of ACCRUE's RL on a simulated task, store-agnostic (paper Algorithm 1, lines 3-10).

The `warmup` and `train` steps wrap these functions; a script or test can call them directly:

    collector = ChunkCollector(env, reference, features, buffer, task_index=k - 1, gamma=γ)
    warmup(collector, episodes)                                    # line 3: π_base^k fills B^k
    state = train_loop(learner, collector, evaluator, settings)    # lines 4-10 + the eval grid

Vocabulary
    reference(obs) -> (N, H, 6)   π_base^k's chunk ã for a batch of observations (instruction bound in)
    features(obs)  -> (N, D)      the learner state s = (E(I), q): frozen encoder features ‖ sim state
    a chunk step                  every env executes one H-step chunk; env steps = control steps run

Exact resume. A checkpoint is taken only at fixed env-step points (never on a timer), and every env
starts a fresh episode right after it: the in-progress episodes end there as time-limit truncations
(they still bootstrap). The env's seeded per-episode generators then make the continuation a function
of (learner state, buffer, episode counters) alone, so a run resumed from a checkpoint produces
bit-identical artifacts to one that never stopped (CPU, fixed torch threads). Because each checkpoint
cuts the episodes in progress, checkpoints are kept at least `min_checkpoint_gap` env steps apart (the
train step uses two full episodes of every env), so that most episodes still run to their end.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from accrue.errors import AccrueError

ReferenceFn = Callable[[dict], np.ndarray]
FeatureFn = Callable[[dict], np.ndarray]
ActFn = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]  # (s, ã, fresh) -> a


def subset(obs: dict, rows: np.ndarray) -> dict:
    return {k: v[rows] for k, v in obs.items()}


EVAL_SETS = {"eval": 50_000, "report": 75_000}  # seed offsets; task indices stay below 25_000


def env_seed(seed: int, stage: int, purpose: str, task_index: int = 0) -> int:
    """Distinct, reproducible env seeds per (workflow seed, stage, purpose) so that warmup, training and
    evaluation never replay each other's episodes; evaluation seeds depend on the task only, so every
    grid point and every stage evaluates task i on the same M episodes. Two evaluation sets: "eval"
    (the selection set: the best checkpoint of a stage is chosen on it) and "report" (disjoint episodes
    on which the chosen checkpoint's success is reported)."""
    offset = {"warmup": 1, "train": 2}.get(purpose)
    if purpose in EVAL_SETS:
        return seed * 100_003 + EVAL_SETS[purpose] + task_index
    if offset is None:
        raise ValueError(f"unknown env purpose {purpose!r}")
    return seed * 100_003 + stage * 10 + offset


# ---------------------------------------------------------------------------------------- collection
@dataclass
class ChunkStats:
    env_steps: int = 0
    episodes: int = 0
    successes: int = 0


class ChunkCollector:
    """Steps N envs one chunk at a time, writing (s, a, ã, R^(H), s', ã', done, task, episode, ended) to B^k."""

    def __init__(
        self,
        env,
        reference: ReferenceFn,
        features: FeatureFn,
        buffer,
        task_index: int,
        gamma: float,
        next_episode: int = 0,
    ):
        self.env, self.reference, self.features, self.buffer = env, reference, features, buffer
        self.task_index, self.gamma = task_index, gamma
        self.next_episode = next_episode
        self.s = self.ref = self.episode_id = self.fresh = None  # set by restart()

    def restart(self) -> None:
        """Every env starts a fresh episode (stage start, and right after each checkpoint)."""
        n = self.env.num_envs
        obs = self.env.reset()
        self.s, self.ref = self.features(obs), self.reference(obs)
        self.episode_id = np.arange(self.next_episode, self.next_episode + n)
        self.next_episode += n
        self.fresh = np.ones(n, dtype=bool)

    def step(self, act: ActFn) -> ChunkStats:
        """Algorithm 1 lines 5-7 for every env: ã_t is ready, execute a_t, observe R^(H) and s_{t+H}, store."""
        a = np.asarray(act(self.s, self.ref, self.fresh), dtype=np.float32)
        res = self.env.step_chunk(a, self.gamma)
        s_next, ref_next = self.features(res.obs), self.reference(res.obs)
        done = res.terminated | res.truncated
        self.buffer.add(
            self.s,
            a,
            self.ref,
            res.reward.astype(np.float32),
            s_next,
            ref_next,
            res.terminated,
            self.task_index,
            self.episode_id,
            ended=done,
        )
        stats = ChunkStats(
            env_steps=int(res.steps.sum()), episodes=int(done.sum()), successes=int(res.success[done].sum())
        )
        if done.any():
            obs = self.env.reset(done)
            rows = np.flatnonzero(done)
            s_next[rows] = self.features(subset(obs, rows))
            ref_next[rows] = self.reference(subset(obs, rows))
            self.episode_id[rows] = np.arange(self.next_episode, self.next_episode + len(rows))
            self.next_episode += len(rows)
        self.s, self.ref, self.fresh = s_next, ref_next, done
        return stats


def execute_reference(s, ref, fresh):
    """π_base alone: execute the reference chunk as is."""
    return ref


def warmup(collector: ChunkCollector, episodes: int) -> ChunkStats:
    """Algorithm 1 line 3: roll out π_base^k until `episodes` episodes have finished (at least one chunk)."""
    total = ChunkStats()
    while total.episodes < episodes or total.env_steps == 0:
        st = collector.step(execute_reference)
        total.env_steps += st.env_steps
        total.episodes += st.episodes
        total.successes += st.successes
    return total


# ---------------------------------------------------------------------------------------- evaluation
class Evaluator:
    """Success rate of π_base^k alone or of the actor refining π_base^k's chunks, on M fixed episodes per
    task (the same episodes at every call: each env's episode counter is rewound first).

    `report`: an Evaluator of the same policies on a disjoint episode set; train_loop scores every grid
    point on both, so the best checkpoint is chosen on this one and reported on that one."""

    def __init__(
        self,
        make_env: Callable[[str, int], object],
        references: dict[str, ReferenceFn],
        features: FeatureFn | dict[str, FeatureFn],
        episodes: int,
        num_envs: int,
        horizon: int,
        gamma: float,
        report: "Evaluator | None" = None,
    ):
        self.make_env, self.references, self.features = make_env, references, features
        self.episodes, self.num_envs, self.horizon, self.gamma = episodes, min(num_envs, episodes), horizon, gamma
        self.report = report
        self._envs: dict[str, object] = {}

    def _env(self, task_id: str):
        if task_id not in self._envs:
            self._envs[task_id] = self.make_env(task_id, self.num_envs)
        env = self._envs[task_id]
        env.episode[:] = -1  # replay the same M episodes every time
        return env

    def success_rate(self, task_id: str, act: ActFn | None = None) -> float:
        """act=None evaluates π_base alone; otherwise act(s, ã, fresh) is the deterministic actor π̄_θ."""
        env, reference = self._env(task_id), self.references[task_id]
        features = self.features[task_id] if isinstance(self.features, dict) else self.features
        act = act or execute_reference
        obs = env.reset()
        started, finished, successes = env.num_envs, 0, 0
        live = np.ones(env.num_envs, dtype=bool)
        fresh = np.ones(env.num_envs, dtype=bool)
        while finished < self.episodes:
            rows = np.flatnonzero(live)
            part = subset(obs, rows)
            a = np.zeros((env.num_envs, self.horizon, 6), dtype=np.float32)
            a[rows] = act(features(part), reference(part), fresh[rows])
            res = env.step_chunk(a, self.gamma)
            done = (res.terminated | res.truncated) & live
            finished += int(done.sum())
            successes += int(res.success[done].sum())
            restart = np.zeros_like(done)
            for i in np.flatnonzero(done):
                if started < self.episodes:
                    restart[i], started = True, started + 1
                else:
                    live[i] = False
            obs = env.reset(restart) if restart.any() else res.obs
            fresh = restart
        return successes / self.episodes

    def close(self) -> None:
        for env in self._envs.values():
            env.close()
        self._envs.clear()
        if self.report is not None:
            self.report.close()


def actor_act(learner) -> ActFn:
    """π̄ of the actor the method deploys now (RETAIN: the merged actor), fixed at this call: evaluate with
    a fresh one at every grid point."""
    actor = learner.deployed_actor()
    return lambda s, ref, fresh: learner.act_with(actor, s, ref)


# ---------------------------------------------------------------------------------------- training
@dataclass(frozen=True)
class LoopSettings:
    task_ids: list[str]  # tasks 1..k; the last one is the current task
    env_steps: int  # RL budget of the stage (control steps, all envs together)
    eval_every: int  # E: evaluation grid spacing in env steps
    checkpoint_every: int  # env steps between checkpoints (0 = at every evaluation point)
    min_checkpoint_gap: int = 0  # never closer: every checkpoint restarts the envs' episodes
    full_curves: bool = False  # score earlier tasks at every grid point too (retention curves), not only at e*

    def grid(self) -> list[int]:
        points = list(range(0, self.env_steps, self.eval_every)) + [self.env_steps]
        return sorted(set(points))

    def checkpoint_points(self) -> list[int]:
        every = max(self.checkpoint_every or self.eval_every, self.min_checkpoint_gap, 1)
        return [p for p in range(every, self.env_steps, every)]


@dataclass
class LoopState:
    """Everything the loop itself needs to continue exactly (the learner and buffer save themselves)."""

    env_steps: int = 0
    chunk_steps: int = 0
    updates: int = 0
    episodes: int = 0
    successes: int = 0
    next_episode: int = 0
    env_episode_counts: list[int] = field(default_factory=list)
    curve: dict[str, list[float]] = field(default_factory=dict)
    report_curve: dict[str, list[float]] = field(default_factory=dict)  # the same points on the report set
    grid_done: list[int] = field(default_factory=list)
    checkpoints_done: list[int] = field(default_factory=list)
    chosen: int = -1  # e*: index of the current task's earliest best point so far on the selection set
    chosen_scored: bool = False  # earlier tasks have been scored at e* (the stage's last act)
    # the deployed actor at e* (a module, saved beside the checkpoint by its caller, never in the JSON)
    chosen_actor: object = field(default=None, repr=False, compare=False)

    def to_json(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k != "chosen_actor"}

    @classmethod
    def from_json(cls, data: dict) -> "LoopState":
        return cls(**data)


def train_loop(
    learner,
    collector: ChunkCollector,
    evaluator: Evaluator,
    settings: LoopSettings,
    prior=None,
    teacher=None,
    state: LoopState | None = None,
    fresh_ref=None,
    frozen_acts: dict[str, ActFn] | None = None,
    on_checkpoint: Callable[[LoopState], None] | None = None,
    on_progress: Callable[[LoopState, dict], None] | None = None,
    on_update: Callable[[LoopState, dict], None] | None = None,
) -> LoopState:
    """Algorithm 1 lines 4-10 with an evaluation grid: the current task at every grid point (selection and
    report sets); earlier tasks once, at the stage's chosen checkpoint e* (the earliest best point of the
    current task on the selection set), from a snapshot of the actor deployed there, which is all the
    continual metrics read of them (accrue.metrics). settings.full_curves scores every task at every
    point instead (retention curves for the plots); both give the same metrics on the same episodes.

    on_update(state, info) follows every learner update with its losses (tracking; it must not touch
    the learner, the buffer or any random stream).

    frozen_acts overrides the actor used to evaluate some earlier tasks (the Isolated method keeps one
    checkpoint per task). A resumed run passes the LoopState of its checkpoint and a collector whose env
    episode counters were restored (restore_collector), exactly as the uninterrupted run restarted it.
    """
    state = state or LoopState()
    grid, ckpt_points = settings.grid(), settings.checkpoint_points()
    started, info = time.monotonic(), {}

    current, earlier = settings.task_ids[-1], settings.task_ids[:-1]
    if state.chosen < 0 and state.curve.get(current):  # a checkpoint saved before e* was tracked
        state.chosen = int(np.argmax(state.curve[current]))
    report = getattr(evaluator, "report", None)  # a stand-in evaluator may have no report set

    def evaluate_due() -> None:
        """One evaluation covers every grid point reached and not yet evaluated. The current task is scored
        on both sets at every point; earlier tasks only with full_curves (the metrics read them at e* alone,
        which score_chosen fills in at the end). Each task is scored with the actor the method would
        deploy for it now."""
        due = [g for g in grid if g <= state.env_steps and g not in state.grid_done]
        if not due:
            return
        deployed = actor_act(learner)
        acts = {t: (frozen_acts or {}).get(t, deployed) for t in settings.task_ids}
        scored = settings.task_ids if settings.full_curves else [current]
        rates = {t: evaluator.success_rate(t, acts[t]) for t in scored}
        report_rates = {t: report.success_rate(t, acts[t]) for t in scored} if report else {}
        own = state.curve.get(current, [])
        if not own or rates[current] > max(own):  # a new earliest maximum: e* moves here
            state.chosen = len(own)
            if not settings.full_curves and earlier:
                state.chosen_actor = copy.deepcopy(learner.deployed_actor())
        for g in due:
            state.grid_done.append(g)
            for t in settings.task_ids:
                state.curve.setdefault(t, []).append(rates.get(t))
                if report:
                    state.report_curve.setdefault(t, []).append(report_rates.get(t))
        if on_progress:
            on_progress(state, {**info, "eval": rates, "elapsed": time.monotonic() - started})

    def score_chosen() -> None:
        """Earlier tasks at e* only, on the set the metrics read (report when there is one): c_{k,j} = c[k][j][e*]."""
        if settings.full_curves or not earlier or state.chosen_scored:
            return
        chosen = state.chosen_actor
        at_chosen = lambda s, ref, fresh: learner.act_with(chosen, s, ref)  # noqa: E731
        acts = {t: (frozen_acts or {}).get(t, at_chosen) for t in earlier}
        values, curves = (report, state.report_curve) if report else (evaluator, state.curve)
        missing = [t for t in earlier if curves[t][state.chosen] is None]  # scored there already: kept
        if chosen is None and any(t not in (frozen_acts or {}) for t in missing):
            raise AccrueError(
                "train: the checkpoint this run resumed from has no snapshot of the actor at its best point; "
                "run the step again from its start (or with budgets.full_curves: true)"
            )
        for t in missing:
            curves[t][state.chosen] = values.success_rate(t, acts[t])
        state.chosen_scored = True

    while True:
        evaluate_due()
        if state.env_steps >= settings.env_steps:
            score_chosen()
            break
        # lines 5-7: fresh reference chunks ã_t, the actor refines them (with exploration), store in B^k
        stats = collector.step(lambda s, ref, fresh: learner.act(s, ref, explore=True, reset_mask=fresh))
        state.env_steps += stats.env_steps
        state.chunk_steps += 1
        state.episodes += stats.episodes
        state.successes += stats.successes
        # lines 8-9: critic on B^k (Eq. 2), actor on B^k and B^{<k} (Eq. 5): `utd` updates per chunk step
        info = learner.train_step(collector.buffer, prior, teacher, fresh_ref)
        state.updates += learner.cfg.utd if info else 0  # {}: still before learning_starts
        if on_update and info:
            on_update(state, info)
        crossed = [p for p in ckpt_points if p <= state.env_steps and p not in state.checkpoints_done]
        if crossed and state.env_steps < settings.env_steps:
            evaluate_due()  # a grid point under the checkpoint is evaluated before it is saved
            state.checkpoints_done.extend(crossed)
            state.next_episode = collector.next_episode
            state.env_episode_counts = [int(c) for c in collector.env.episode]
            if on_checkpoint:
                on_checkpoint(state)
            collector.restart()  # fresh episodes: the continuation depends only on what was saved
        elif on_progress and state.chunk_steps % 10 == 0:
            on_progress(state, {**info, "elapsed": time.monotonic() - started})
    return state


def restore_collector(collector: ChunkCollector, state: LoopState) -> None:
    """Put a fresh collector where a checkpointed run was just before its post-checkpoint restart."""
    collector.env.episode[:] = np.asarray(state.env_episode_counts, dtype=np.int64)
    collector.next_episode = state.next_episode
    collector.restart()


# ---------------------------------------------------------------------------------------- episode logs
def record_episodes(
    env, reference: ReferenceFn, features: FeatureFn, act: ActFn | None, recorder, horizon: int, metadata: dict
) -> list[bool]:
    """One episode per env, logged step by step to an accrue.logs EpisodeRecorder (MCAP): each chunk is
    executed one control step at a time so every intermediate state, action and reward is recorded."""
    from accrue.sim.observation import decode_state

    act = act or execute_reference
    obs = env.reset()
    n = env.num_envs
    live = np.ones(n, dtype=bool)
    success = np.zeros(n, dtype=bool)
    for i in range(n):
        recorder.start(i, {**metadata, "env_seed": env.seed})
    t = 0
    while live.any():
        ref = reference(obs)
        chunk = np.asarray(act(features(obs), ref, np.full(n, t == 0)), dtype=np.float32)
        for h in range(horizon):
            res = env.step(chunk[:, h])
            state = obs["state"]
            for i in np.flatnonzero(live):
                d = decode_state(state[i : i + 1])
                recorder.log_step(
                    int(i),
                    t,
                    state[i],
                    chunk[i, h],
                    reference=ref[i] if h == 0 else None,
                    reward=float(res.rewards[i, 0]),
                    ee_pose=d["pos"][0],
                    wrench=np.concatenate([d["force"][0], d["torque"][0]]),
                )
            ended = live & (res.terminated | res.truncated)
            for i in np.flatnonzero(ended):
                success[i] = bool(res.success[i])
                recorder.end(int(i), success=bool(success[i]), truncated=bool(res.truncated[i]))
            live &= ~ended
            obs = res.obs
            t += 1
            if not live.any():
                break
    return success.tolist()
