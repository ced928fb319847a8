"""The report's rerun recording (.rrd): the whole sequence on one `env_steps` timeline (cumulative
over stages), so a task's curve runs on through the later stages that re-evaluate it.

    success/<task>                 success rate at each evaluation point of every stage (scalars)
    deployment/after_rl/<task>     evaluate-all of stage k: π_base^k + RL actor, at the stage's end
    deployment/base/<task>         evaluate-all of stage k: π_base^k alone, at the stage's end
    stage                          the stage number (a step function marking the boundaries)
    log                            one text line per stage start ("stage 2: learning plugs/cross")

Open with `rerun FILE.rrd` (rerun 0.26).
"""

from __future__ import annotations

import re
from pathlib import Path

from stages.report.data import RunData

TIMELINE = "env_steps"


def entity_part(task_id: str) -> str:
    """A task id as an entity path part: '/' keeps its hierarchy, anything unusual becomes '_'."""
    return re.sub(r"[^A-Za-z0-9_\-./]", "_", task_id).strip("/") or "_"


def stage_offsets(run: RunData) -> list[int]:
    """Cumulative env steps at the start of each committed stage."""
    offsets, total = [], 0
    for sc in run.curves:
        offsets.append(total)
        total += sc.grid[-1]
    return offsets


def write_recording(run: RunData, path: Path) -> Path:
    from accrue.logs.rerun_log import RerunLog

    wf = run.workflow
    # The user asked for this file, so RERUN=off does not silently drop it (force=True).
    with RerunLog(path, app_id="accrue-report", recording_id=f"{wf.name}-report", timeline=TIMELINE, force=True) as rl:
        for sc, offset in zip(run.curves, stage_offsets(run)):
            steps = [offset + g for g in sc.grid]
            rl.set_step(offset)
            rl.text("log", f"stage {sc.stage}: learning {wf.tasks[sc.stage - 1]}")
            rl.curve("stage", steps, [float(sc.stage)] * len(steps), name="stage")
            for task in sc.task_ids:
                scored = [(x, v) for x, v in zip(steps, sc.success[task]) if v is not None]  # see full_curves
                if scored:
                    rl.curve(f"success/{entity_part(task)}", [x for x, _ in scored], [v for _, v in scored], name=task)
            ev = run.evals.get(sc.stage)
            if ev is not None:
                rl.set_step(steps[-1])
                for task in ev.task_ids:
                    rl.scalar(f"deployment/after_rl/{entity_part(task)}", ev.success[task])
                    rl.scalar(f"deployment/base/{entity_part(task)}", ev.base_success[task])
    return path
