"""`warmup` on a robot: Algorithm 1 line 3, π_base^k alone for `episodes` operator-labelled episodes; their
chunk transitions are the first shard of B^k. Episodes are sealed one by one (resumable like `train`);
their robot time is reported apart from RL's (Fig. 4's shaded warmup)."""

from __future__ import annotations

from stages.runner_context import StepContext
from stages.runner_types import StepDef
from stages.steps import warmup as warmup_step
from stages.steps.common import deterministic, load_base_policy, per_task_features, reference_fn, write_json
from stages.steps.hw_session import (
    HardwareSession,
    SessionSettings,
    SessionStop,
    StopSignals,
    episode_loop,
    episodes_output,
    make_bridge,
    make_operator,
    release_robot,
)
from stages.steps.hw_train import episode_settings


def run(ctx: StepContext, settings: SessionSettings) -> None:
    with StopSignals():  # Ctrl-C / SIGTERM: a clean stop (SessionStop), a second one forces
        _run(ctx, settings)


def _run(ctx: StepContext, settings: SessionSettings) -> None:
    c = ctx.config
    task, k, horizon = c["task"], c["stage"], c["horizon"]
    deterministic(c["seed"])
    policy = load_base_policy(ctx.input_path("base-policy"), c["seed"])
    reference = reference_fn(policy, task, horizon)
    features = per_task_features(c, [task])[task]
    session = HardwareSession(ctx, settings)
    try:
        _session(ctx, settings, session, c, task, k, reference, features)
    except SessionStop as stop:
        raise session.stopped(stop) from None


def _session(ctx, settings, session, c, task, k, reference, features) -> None:
    import numpy as np

    from accrue import rl_loop
    from accrue.learner import ReplayBuffer
    from accrue.robot.episode import replay_from_episodes

    horizon = c["horizon"]
    bridge = make_bridge(c, settings, task, lambda line: ctx.log_event("robot-fault", message=line, stage=k))
    operator = make_operator(settings, bridge, ctx.console, store_root=ctx.store.root, audit=session.audit)
    try:
        episode_loop(
            ctx,
            session,
            operator,
            bridge,
            task=task,
            done=lambda: len(session.episodes) >= c["episodes"],
            policy_now=lambda: (rl_loop.execute_reference, None),
            reference=reference,
            features=features,
            settings=episode_settings(c, task, settings.clock),
            gamma=c["gamma"],
            index_base=0,
            metadata={"task_id": task, "stage": k, "phase": "warmup", "policy": "base"},
        )
        session.close(f"{c['episodes']} warmup episodes")
    finally:
        release_robot(bridge, session)
        operator.close()
    eps = session.ordered()
    arrays = [session.arrays(e["index"]) for e in eps]
    # s's width from an episode that executed a chunk (one a fault ended before its first has no s rows)
    widths = [a["s"].shape[-1] for a in arrays if len(a["action"])]
    dim = widths[0] if widths else features({"state": np.zeros((1, 29), np.float32)}).shape[1]
    buffer = replay_from_episodes(ReplayBuffer(dim, horizon), arrays, k - 1)
    out = ctx.new_output("replay", "replay")
    buffer.save_new_shards(out)
    successes = sum(bool(e["label"]["success"]) for e in eps)
    write_json(
        out / warmup_step.INFO_FILE,
        {
            "stage": k,
            "task": task,
            "episodes": len(eps),
            "successes": successes,
            "env_steps": sum(e["control_steps"] for e in eps),
            "transitions": len(buffer),
            "next_episode": max([e["index"] for e in eps], default=-1) + 1,
            "hardware": True,
            "robot_time_s": round(session.robot_time_s(), 6),
            "episode_robot_time_s": [e["robot_time_s"] for e in eps],
            "labels": [bool(e["label"]["success"]) for e in eps],
        },
    )
    episodes_output(ctx, session)
    ctx.console.print(
        f"warmup: {len(eps)} base-policy episodes on the robot ({task}), {successes} labelled success, "
        f"robot time {session.robot_time_s():.1f} s"
    )


STEP = StepDef(
    name="warmup",
    code_version="hw-warmup-1",
    run=lambda ctx: run(ctx, SessionSettings()),
    inputs=("base-policy",),
    outputs={"replay": "replay", "episodes": "episodes"},
    description="base-policy episodes on the robot, operator-labelled, seeding B^k",
)
