"""A synthetic committed run for the report tests: tiny `train` / `evaluate-all` step bodies that
write curve.json / eval.json (the step-bodies' documented layout) from their config, run through
the real Runner so refs, records and artifacts are the genuine article."""

from __future__ import annotations

import json
import os
from pathlib import Path

import yaml
from rich.console import Console

from artifacts.store import Store
from stages.runner import Runner
from stages.runner_types import StagePlan, StepDef, StepInvocation

TASKS = ["nist/rect_peg", "nist/round_peg", "nist/gear"]
GRID = [0, 100, 200, 300, 400]
# CURVES[i][j] = success of task j at each grid point of stage i (0-based). The maxima are placed so
# that e* differs per stage and ties must resolve to the earliest point.
CURVES = [
    [[0.2, 0.5, 0.9, 0.9, 0.8]],  # stage 1: e* = 2 (tie 2/3)
    [[0.9, 0.85, 0.8, 0.7, 0.75], [0.1, 0.4, 0.6, 0.95, 0.95]],  # stage 2: e* = 3
    [[0.8, 0.7, 0.75, 0.6, 0.7], [0.9, 0.9, 0.85, 0.8, 0.8], [0.3, 1.0, 0.5, 0.7, 1.0]],  # stage 3: e* = 1
]
EVAL_SUCCESS = [[0.85], [0.7, 0.9], [0.65, 0.8, 0.95]]
BASE_SUCCESS = [[0.3], [0.25, 0.2], [0.3, 0.2, 0.35]]
EPISODES = 20


def _train_body(ctx) -> None:
    out = ctx.new_output("curve", "eval")
    (out / "curve.json").write_text(json.dumps(dict(ctx.config["curve"])))


def _evaluate_body(ctx) -> None:
    out = ctx.new_output("eval", "eval")
    (out / "eval.json").write_text(json.dumps(dict(ctx.config["eval"])))


TRAIN = StepDef(name="train", code_version="test-report-1", run=_train_body, outputs={"curve": "eval"})
EVALUATE = StepDef(name="evaluate-all", code_version="test-report-1", run=_evaluate_body, outputs={"eval": "eval"})


def curve_json(k: int) -> dict:
    tasks = TASKS[:k]
    return {
        "stage": k,
        "task_ids": tasks,
        "grid": GRID,
        "success": {t: CURVES[k - 1][j] for j, t in enumerate(tasks)},
        "episodes_per_point": 10,
        "method": "accrue",
        "seed": 0,
    }


def eval_json(k: int) -> dict:
    tasks = TASKS[:k]
    return {
        "stage": k,
        "task_ids": tasks,
        "success": dict(zip(tasks, EVAL_SUCCESS[k - 1])),
        "base_success": dict(zip(tasks, BASE_SUCCESS[k - 1])),
        "episodes": EPISODES,
        "method": "accrue",
        "seed": 0,
    }


def write_workflow(directory: Path, name: str = "rep", tasks: list[str] = TASKS) -> Path:
    path = directory / f"{name}.yaml"
    path.write_text(
        yaml.safe_dump(
            {
                "name": name,
                "tasks": tasks,
                "method": "accrue",
                "budgets": {"env_steps": GRID[-1], "eval_every": GRID[1]},
            }
        )
    )
    return path


def commit_stage(store: Store, k: int, workflow: str = "rep", evaluate: bool = True, curve: dict | None = None) -> None:
    steps = [StepInvocation(step=TRAIN, config={"curve": curve or curve_json(k)})]
    if evaluate:
        steps.append(StepInvocation(step=EVALUATE, config={"eval": eval_json(k)}))
    quiet = Console(file=open(os.devnull, "w"))
    Runner(store, console=quiet).run_plan(StagePlan(workflow=workflow, stage=k, steps=tuple(steps)))
