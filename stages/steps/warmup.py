"""`warmup`: Algorithm 1 line 3, roll out π_base^k on task k; its transitions are the first shard of B^k."""

from __future__ import annotations

from stages.runner_context import StepContext
from stages.runner_types import StepDef
from stages.steps.common import deterministic, load_base_policy, make_env, per_task_features, reference_fn, write_json

INFO_FILE = "warmup.json"  # in the `replay` output, beside the shards: counts and the next episode id


def run(ctx: StepContext) -> None:
    from accrue import rl_loop
    from accrue.learner import ReplayBuffer

    c = ctx.config
    deterministic(c["seed"])
    policy = load_base_policy(ctx.input_path("base-policy"), c["seed"])
    env = make_env(c["task"], c["num_envs"], rl_loop.env_seed(c["seed"], c["stage"], "warmup"), c["obs_mode"])
    features = per_task_features(c, [c["task"]])[c["task"]]
    obs_dim = features(env.reset()).shape[1]
    buffer = ReplayBuffer(obs_dim, c["horizon"])
    collector = rl_loop.ChunkCollector(
        env,
        reference_fn(policy, c["task"], c["horizon"]),
        features,
        buffer,
        task_index=c["stage"] - 1,
        gamma=c["gamma"],
    )
    collector.restart()
    stats = rl_loop.warmup(collector, c["episodes"])
    env.close()
    out = ctx.new_output("replay", "replay")
    buffer.save_new_shards(out)
    write_json(
        out / INFO_FILE,
        {
            "stage": c["stage"],
            "task": c["task"],
            "episodes": stats.episodes,
            "successes": stats.successes,
            "env_steps": stats.env_steps,
            "transitions": len(buffer),
            "next_episode": collector.next_episode,
        },
    )
    ctx.console.print(
        f"warmup: {stats.episodes} base-policy episodes on {c['task']}, "
        f"{stats.successes} succeeded, {len(buffer)} chunk transitions"
    )


STEP = StepDef(
    name="warmup",
    code_version="warmup-2",
    run=run,
    inputs=("base-policy",),
    outputs={"replay": "replay"},
    description="base-policy rollouts seeding B^k",
)
