"""One stage of ACCRUE, top to bottom as the paper's Algorithm 1 (store-agnostic).

    Require: π_base^k, frozen encoder E, chunk length H, handoff (θ^{k-1}, ψ^{k-1}, B^{<k})
    line 2      teacher = cache_teacher(previous, memory, fresh=...)          Eq. 3, cached before RL
    line 3      rl_loop.warmup(collector, episodes)                           π_base^k fills B^k
    lines 1,4-10 learner, loop = train_stage(cfg, previous, buffer, ...)       begin_stage, then per chunk
                                                                               step: act, store, Eq. 2, Eq. 5
    line 11     memory, kept = hand_over(previous_memory, buffer, N)           last N complete episodes

The workflow steps (`stages/steps/`) split these lines across resumable steps (cache-teacher, warmup,
train, handoff); each step body reads its inputs, calls one function here and writes its outputs. Every
method runs through the same lines; what differs is one row of `accrue.methods.METHOD_RULES`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

from accrue import rl_loop
from accrue.errors import AccrueError
from accrue.learner import ReplayBuffer, begin_stage, compute_teacher_targets, end_stage, retain_last_episodes
from accrue.learner.replay import complete_episodes


@dataclass
class TeacherCache:
    """Eq. 3 targets â_j for every row j of B^{<k}, and (distill_inputs fresh/both) the current base policy's
    chunk ã'_j at the same retained state."""

    targets: torch.Tensor  # (N, H, d)
    fresh_ref: torch.Tensor | None = None  # (N, H, d)


# ------------------------------------------------------------------------------------------- line 2
def cache_teacher(
    previous, memory: ReplayBuffer, fresh_reference: Callable[[np.ndarray, int], np.ndarray] | None = None
) -> TeacherCache:
    """â_j = π̄_{θ^{k-1}}(s_j, ã_j) at the stored inputs (the teacher copy is discarded after).
    fresh_reference(states, task_index) -> the current base policy's chunks for those retained states."""
    targets = compute_teacher_targets(previous, memory.column("state"), memory.column("ref"))
    if fresh_reference is None:
        return TeacherCache(targets)
    states, tasks = memory.column("state").numpy(), memory.column("task").numpy()
    fresh = np.zeros(tuple(memory.column("ref").shape), dtype=np.float32)
    for task in np.unique(tasks):
        rows = np.flatnonzero(tasks == task)
        fresh[rows] = fresh_reference(states[rows], int(task))
    return TeacherCache(targets, torch.from_numpy(fresh))


# ----------------------------------------------------------------------------------- lines 1, 4-10
def fisher_batch(memory: ReplayBuffer, task_index: int, samples: int):
    """EWC: the previous task's last `samples` retained transitions."""
    rows = torch.nonzero(memory.column("task") == task_index).flatten()[-samples:]
    if rows.numel() == 0:
        raise AccrueError(
            "method ewc needs retained transitions of the previous task for its Fisher: "
            "set budgets.retained_episodes > 0"
        )
    return memory.gather(rows)


def train_stage(
    cfg,
    previous,
    memory: ReplayBuffer | None,
    teacher: TeacherCache | None,
    collector: rl_loop.ChunkCollector,
    evaluator: rl_loop.Evaluator,
    settings: rl_loop.LoopSettings,
    frozen_acts: dict | None = None,
    resume: tuple | None = None,
    on_checkpoint: Callable | None = None,
    on_progress: Callable | None = None,
    on_update: Callable | None = None,
):
    """Lines 1 and 4-10 of stage k, returning (learner after its handoff rule, final LoopState).

    previous: the learner handed over by stage k-1 (None at stage 1). resume: (learner, LoopState) of an
    intra-step checkpoint (its buffer is the collector's). The collector's buffer is B^k (warmup
    included); `memory` is B^{<k}. on_checkpoint(learner, loop_state) saves an intra-step checkpoint.
    """
    if resume is None:
        k = len(settings.task_ids)
        fisher = (
            fisher_batch(memory, k - 2, cfg.ewc_samples) if cfg.rules.ewc_penalty and previous is not None else None
        )
        learner = begin_stage(
            previous, cfg, collector.buffer.state_dim, collector.buffer.horizon, fisher_batch=fisher
        )  # line 1
        state = rl_loop.LoopState(next_episode=collector.next_episode)
        collector.restart()
    else:
        learner, state = resume
        rl_loop.restore_collector(collector, state)
    state = rl_loop.train_loop(  # lines 4-10
        learner,
        collector,
        evaluator,
        settings,
        prior=memory,
        teacher=teacher.targets if teacher else None,
        fresh_ref=teacher.fresh_ref if teacher else None,
        state=state,
        frozen_acts=frozen_acts,
        on_progress=on_progress,
        on_update=on_update,
        on_checkpoint=(lambda st: on_checkpoint(learner, st)) if on_checkpoint else None,
    )
    return end_stage(learner), state


# ------------------------------------------------------------------------------------------ line 11
def hand_over(previous_memory: ReplayBuffer | None, current: ReplayBuffer, n: int):
    """B^{<k+1} = B^{<k} ∪ the last n complete episodes of B^k. Returns (memory, report), where report
    says per task how many episodes were kept and whether the stage had fewer than n to keep."""
    parts = ([previous_memory] if previous_memory is not None else []) + [current]
    memory = retain_last_episodes(ReplayBuffer.concat(parts), n)
    available = {t: len(e) for t, e in complete_episodes(current).items()}
    kept = {t: len(e) for t, e in complete_episodes(memory).items()}
    report = {
        "retained_episodes": n,
        "kept": {str(t): c for t, c in sorted(kept.items())},
        "current_complete_episodes": {str(t): c for t, c in sorted(available.items())},
        "short": sorted(str(t) for t, c in available.items() if c < n),
    }
    return memory, report
