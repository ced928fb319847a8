"""`record-demos`: the scripted expert's demonstrations D^k of the stage's task (a LeRobotDataset).

Used when the workflow gives no recorded demos for a task; its config carries the seed, so a
base policy's lineage reaches back to the seed that drew its demonstrations.
"""

from __future__ import annotations

from stages.runner_context import StepContext
from stages.runner_types import StepDef


def run(ctx: StepContext) -> None:
    from accrue.sim.demos import write_demos

    c = ctx.config
    out = ctx.new_output("demos", "demos")
    summary = write_demos(
        c["task"],
        c["episodes"],
        out,
        seed=c["seed"],
        quality=c["quality"],
        obs_mode=c["obs_mode"],
        progress=False,
        num_envs=c["num_envs"],
        search=c.get("search", True),
        bias_known=c.get("bias_known", 1.0),
        max_attempts=10 * c["episodes"],
    )  # a non-searching demonstrator succeeds ~1 in 3
    ctx.console.print(
        f"record-demos: {summary.episodes} episodes of {c['task']} "
        f"({summary.successes}/{summary.attempts} expert attempts succeeded)"
    )
    ctx.log_event("demos-recorded", task=c["task"], episodes=summary.episodes, attempts=summary.attempts)


# code version 2: the state gained the socket-relative columns (25 -> 29), so older demos are not reused
STEP = StepDef(
    name="record-demos",
    code_version="record-demos-2",
    run=run,
    outputs={"demos": "demos"},
    description="scripted-expert demonstrations of the stage's task",
)
