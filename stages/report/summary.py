"""The numbers of a report: the paper's continual metrics (Sec. V-A, via accrue.metrics) from the
committed learning curves c[i][j][e], and per task the base policy's and the after-RL deployment
success from the latest `evaluate-all`.

    summary = summarize(run)       # a JSON-able dict; see REPORT_KEYS and PER_TASK_KEYS

With m of K stages committed, the metrics are those of the sequence 1..m (ACC_final and F_final at
stage m); NBT and F_final need m >= 2 and are None before that.
"""

from __future__ import annotations

from accrue.metrics import SEC_VA_METRICS, continual_metrics
from stages.errors import StageError
from stages.report.data import RunData

REPORT_KEYS = (
    "workflow",
    "method",
    "seed",
    "tasks",
    "stages_total",
    "stages_reported",
    "complete",
    "missing",
    "metrics",
    "per_stage",
    "success_matrix",
    "best_checkpoint",
    "per_task",
    "evaluations",
    "stages",
)
PER_TASK_KEYS = (
    "task",
    "stage",
    "base_success",
    "after_rl_success",
    "eval_stage",
    "episodes",
    "best_in_own_stage",
    "at_last_stage",
)


def curve_tensor(run: RunData) -> list[list[list[float]]]:
    """c[i][j][e] (0-based) for the committed stages, as accrue.metrics takes it."""
    first = run.curves[0]
    for sc in run.curves[1:]:
        if len(sc.grid) != len(first.grid):
            raise StageError(
                f"stage {sc.stage} was evaluated at {len(sc.grid)} grid points but stage 1 at "
                f"{len(first.grid)}: the continual metrics need one evaluation grid for all stages"
            )
    return [[sc.success[t] for t in sc.task_ids] for sc in run.curves]


def report_tensor(run: RunData) -> list[list[list[float]]] | None:
    """The same c[i][j][e] on the disjoint report episodes, or None when any stage has none (a run made
    before the selection/report split: its numbers then come from the selection set alone)."""
    if any(sc.report is None for sc in run.curves):
        return None
    curve_tensor(run)  # one grid length for all stages
    return [[sc.report[t] for t in sc.task_ids] for sc in run.curves]


def summarize(run: RunData) -> dict:
    wf = run.workflow
    m = run.stages_done
    # chosen on the selection episodes, read from the disjoint report set when the run has one
    result = continual_metrics(curve_tensor(run), report_tensor(run))
    c = result["c"]
    latest = run.latest_eval()
    per_task = []  # a list, in workflow order (JSON objects get sorted)
    for j, task in enumerate(wf.tasks[:m]):
        evaluated = latest is not None and task in latest.success
        per_task.append(
            {
                "task": task,
                "stage": j + 1,
                "base_success": latest.base_success[task] if evaluated else None,
                "after_rl_success": latest.success[task] if evaluated else None,
                "eval_stage": latest.stage if evaluated else None,
                "episodes": latest.episodes if evaluated else None,
                "best_in_own_stage": c[j][j],  # c_{j,j} = max_e c[j][j][e]
                "at_last_stage": c[m - 1][j],  # c_{m,j}, the matrix's last row
            }
        )
    return {
        "workflow": wf.name,
        "method": wf.method,
        "seed": wf.seed,
        "tasks": list(wf.tasks),
        "stages_total": wf.num_stages,
        "stages_reported": m,
        "complete": run.complete,
        "missing": [{"stage": x.stage, "step": x.step, "ref": x.ref} for x in run.missing],
        "metrics": {name: result[name] for name in SEC_VA_METRICS},
        "per_stage": result["per_stage"],
        "success_matrix": c,
        "disjoint_report": result["disjoint_report"],
        "best_checkpoint": [
            {"index": e, "env_steps": run.curves[i].grid[e]} for i, e in enumerate(result["best_checkpoint"])
        ],
        "per_task": per_task,
        "evaluations": [
            {
                "stage": ev.stage,
                "episodes": ev.episodes,
                "success": ev.success,
                "base_success": ev.base_success,
                "record": ev.record,
                "artifact": ev.artifact,
            }
            for _, ev in sorted(run.evals.items())
        ],
        "stages": [
            {
                "stage": sc.stage,
                "task": wf.tasks[sc.stage - 1],
                "grid": sc.grid,
                "success": sc.success,
                "episodes_per_point": sc.episodes_per_point,
                "record": sc.record,
                "artifact": sc.artifact,
            }
            for sc in run.curves
        ],
    }
