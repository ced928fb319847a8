"""`evaluate-all` on a robot: `trials` operator-labelled retention trials of π_base^k + θ^k on each earlier
task (paper Table III), resumable like `train`. The current task's figure is its training window."""

from __future__ import annotations

from stages.runner_context import StepContext
from stages.runner_types import StepDef
from stages.steps import train as train_step
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
    from accrue import rl_loop
    from accrue.learner import load_learner

    c = ctx.config
    tasks = c["task_ids"]
    deterministic(c["seed"])
    policy = load_base_policy(ctx.input_path("base-policy"), c["seed"])
    learner = load_learner(ctx.input_path("checkpoint") / train_step.LEARNER_DIR, device="cpu")
    act = rl_loop.actor_act(learner)  # the deterministic actor the method deploys
    features = per_task_features(c, tasks)
    session = HardwareSession(ctx, settings)
    try:
        _session(ctx, settings, session, policy, act, features)
    except SessionStop as stop:
        raise session.stopped(stop) from None


def _session(ctx, settings, session, policy, act, features) -> None:
    c = ctx.config
    k, tasks, horizon, n = c["stage"], c["task_ids"], c["horizon"], c["trials"]
    current = _Current()  # one operator (one page) for every task's bridge
    operator = None
    for i, task in enumerate(tasks[:-1]):
        mine = lambda t=task: [e for e in session.ordered() if e["task"] == t]  # noqa: E731
        if len(mine()) >= n:
            continue
        bridge = current.bridge = make_bridge(
            c, settings, task, lambda line: ctx.log_event("robot-fault", message=line, stage=k)
        )
        if operator is None:
            operator = make_operator(settings, current, ctx.console, store_root=ctx.store.root, audit=session.audit)
        operator.tell(f"retention trials on task {i + 1} ({task}): set up its parts")
        try:
            episode_loop(
                ctx,
                session,
                operator,
                bridge,
                task=task,
                done=lambda mine=mine: len(mine()) >= n,
                policy_now=lambda: (act, None),
                reference=reference_fn(policy, task, horizon),
                features=features[task],
                settings=episode_settings(c, task, settings.clock),
                gamma=c["gamma"],
                index_base=0,
                metadata={"task_id": task, "stage": k, "phase": "evaluate", "policy": "base+actor"},
            )
        except BaseException:
            operator.close()
            raise
        finally:
            release_robot(bridge, session)
    if operator is not None:
        operator.close()
    session.close("retention trials done")
    trials = {t: [bool(e["label"]["success"]) for e in session.ordered() if e["task"] == t] for t in tasks[:-1]}
    success = {t: sum(v) / len(v) for t, v in trials.items() if v}
    write_json(
        ctx.new_output("eval", "eval") / "eval.json",
        {
            "stage": k,
            "task_ids": tasks,
            "hardware": True,
            "success": success,
            "base_success": {},
            "trials": trials,
            "successes": {t: sum(v) for t, v in trials.items()},
            "episodes": n,
            "method": c["method"],
            "seed": c["seed"],
            "per_task_checkpoint": [],
        },
    )
    episodes_output(ctx, session)
    for t, v in trials.items():
        ctx.console.print(f"evaluate-all: {t}: {sum(v)}/{len(v)} retention trials succeeded")


class _Current:
    """The bridge of the task being evaluated, for an operator that outlives each task's bridge."""

    bridge = None

    def hook(self, name: str):
        return self.bridge.hook(name) if self.bridge is not None else None


STEP = StepDef(
    name="evaluate-all",
    code_version="hw-evaluate-all-1",
    run=lambda ctx: run(ctx, SessionSettings()),
    inputs=("base-policy", "checkpoint"),
    outputs={"eval": "eval", "episodes": "episodes"},
    description="operator-labelled retention trials on each earlier task (Table III)",
)
