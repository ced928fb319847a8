"""`evaluate-all`: row k of the success matrix, π_base^k + θ^k on tasks 1..k.

In the simulator M episodes per task, the base policy alone on the same episodes (for the report), and
MCAP logs of a few episodes per task (with budgets.report_episodes the disjoint report set); on a robot
(stages.steps.robot_env) operator-labelled retention trials on each earlier task (Table III)."""

from __future__ import annotations

from stages.runner_context import StepContext
from stages.runner_types import StepDef
from stages.steps.common import write_json
from stages.steps.environments import environment_for
from stages.steps.stage_io import base_inputs, deployed

EVAL_FILE = "eval.json"  # the `eval` output: row k of the success matrix and the base policy alone


def run(ctx: StepContext, robot=None) -> None:
    """`robot`: the session settings the plan binds for a workflow with a robot (outside the cache key)."""
    c = ctx.config
    tasks = c["task_ids"]
    env = environment_for(c, robot)
    with env.scope(ctx):
        base = base_inputs(ctx, tasks)
        learners = deployed(ctx, tasks)
        result = env.evaluate(ctx, base, learners)
        write_json(
            ctx.new_output("eval", "eval") / EVAL_FILE,
            {
                "stage": c["stage"],
                "task_ids": tasks,
                "success": result.success,
                "base_success": result.base_success,
                "episodes": result.episodes,
                "method": c["method"],
                "seed": c["seed"],
                "per_task_checkpoint": learners.per_task_checkpoint(),
                **result.extra,
            },
        )


STEP = StepDef(
    name="evaluate-all",
    code_version="evaluate-all-1",
    run=run,
    inputs=("base-policy", "checkpoint"),
    outputs={"eval": "eval", "episodes": "episodes"},
    description="success of base policy + actor on tasks 1..k (row k of the success matrix)",
)
