"""`warmup`: Algorithm 1 line 3, roll out π_base^k on task k; its transitions are the first shard of B^k.

In the simulator on `num_envs` vector envs for `episodes` episodes; on a robot (stages.steps.robot_env)
operator-labelled, each episode sealed at once, with an `episodes` output."""

from __future__ import annotations

from stages.runner_context import StepContext
from stages.runner_types import StepDef
from stages.steps.common import write_json
from stages.steps.environments import environment_for
from stages.steps.stage_io import WARMUP_INFO_FILE, base_inputs

INFO_FILE = WARMUP_INFO_FILE  # in the `replay` output, beside the shards: counts and the next episode id


def run(ctx: StepContext, robot=None) -> None:
    """`robot`: the session settings the plan binds for a workflow with a robot (outside the cache key)."""
    from accrue.learner import ReplayBuffer

    c = ctx.config
    env = environment_for(c, robot)
    with env.scope(ctx):
        base = base_inputs(ctx, [c["task"]])
        # B^k's rows: s of the environment's width, chunks H x d (d: the robot's action keys; the simulator's 6)
        result = env.warmup(ctx, base, lambda state_dim, d=6: ReplayBuffer(state_dim, c["horizon"], d))
        out = ctx.new_output("replay", "replay")
        result.buffer.save_new_shards(out)
        write_json(
            out / INFO_FILE,
            {
                "stage": c["stage"],
                "task": c["task"],
                "episodes": result.episodes,
                "successes": result.successes,
                "env_steps": result.env_steps,
                "transitions": len(result.buffer),
                "next_episode": result.next_episode,
                **result.extra,
            },
        )
        ctx.console.print(result.line)


STEP = StepDef(
    name="warmup",
    code_version="warmup-2",
    run=run,
    inputs=("base-policy",),
    outputs={"replay": "replay"},
    description="base-policy rollouts seeding B^k",
)
