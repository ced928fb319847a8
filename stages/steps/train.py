"""`train`: one stage of off-policy RL on action chunks (paper Algorithm 1, lines 1 and 4-10).

Inputs: `base-policy` (π_base^k), `replay` (B^k's warmup shard), and from stage 2 on `handoff`
(θ^{k-1}, ψ^{k-1}, B^{<k}) and `teacher` (Eq. 3 targets). Outputs: `checkpoint` (θ^k, ψ^k and the
whole learner state), `replay` (every shard of B^k) and `curve` (success on tasks 1..k every E env
steps). Intra-step checkpoints (learner + the replay shards appended since the last one + loop
counters) are saved at fixed env-step points, so `--continue` after a kill repeats nothing that was
saved and ends with the same bytes as a run that never stopped.
"""

from __future__ import annotations

from stages.runner_context import StepContext
from stages.runner_types import StepDef
from stages.steps.checkpoint_layout import CHECKPOINT_FILE, LEARNER_DIR, PER_TASK_DIR
from stages.steps.common import copy_tree, learner_config, write_json
from stages.steps.environments import environment_for
from stages.steps.stage_io import base_inputs, inherited, warmup_shard

CURVE_FILE = "curve.json"  # the `curve` output


def bind_tracking(steps, spec, workflow: str, root: str | None = None) -> tuple:
    """The stage's step invocations with the train step's tracking bound (outside its cache key):
    spec is the workflow's tracking section, root where runs go (default <store>/log/tracking)."""
    import dataclasses
    import functools

    bound = {"spec": spec.model_dump() if hasattr(spec, "model_dump") else spec, "workflow": workflow, "root": root}
    return tuple(
        dataclasses.replace(
            inv, step=dataclasses.replace(inv.step, run=functools.partial(run, **_bound(inv), tracking=bound))
        )
        if inv.step.name == STEP.name and getattr(inv.step.run, "func", inv.step.run) is run  # rebinds a bound one
        else inv
        for inv in steps
    )


def _bound(inv) -> dict:
    """What the plan bound to the train step's run besides tracking (the robot's session settings)."""
    keywords = dict(getattr(inv.step.run, "keywords", {}))
    keywords.pop("tracking", None)
    return keywords


def run(ctx: StepContext, tracking: dict | None = None, robot=None) -> None:
    """`tracking` and `robot` (the session settings of a workflow with a robot) are bound by the plan,
    outside the cache key (bind_tracking, stages.steps.robot_plan.bind_robot)."""
    from accrue.learner import save_learner

    c = ctx.config
    k, tasks, seed = c["stage"], c["task_ids"], c["seed"]
    env = environment_for(c, robot)
    with env.scope(ctx):
        settings = dict(c["learner"])
        if "device" not in settings:  # not pinned by the workflow: the environment's default
            settings["device"] = env.learner_device()
        cfg = learner_config(settings)
        # π_base^k, held fixed during the stage, proposes ã for every task (fresh references, Sec. IV-C)
        base = base_inputs(ctx, tasks)
        # what the stage inherits: (θ^{k-1}, ψ^{k-1}, B^{<k}) and the cached Eq. 3 targets
        result = env.train(ctx, cfg, base, warmup_shard(ctx), inherited(ctx, cfg), tracking)

        out = ctx.new_output("checkpoint", "checkpoint")
        save_learner(result.learner, out / LEARNER_DIR)
        for i, p in result.per_task.items():
            copy_tree(p, out / PER_TASK_DIR / str(i))
        write_json(
            out / CHECKPOINT_FILE,
            {
                "stage": k,
                "task_ids": tasks,
                "method": cfg.method,
                "per_task": sorted(result.per_task),
                **result.checkpoint,
            },
        )
        result.buffer.save_new_shards(ctx.new_output("replay", "replay"))
        write_json(
            ctx.new_output("curve", "eval") / CURVE_FILE,
            {"stage": k, "task_ids": tasks, "method": cfg.method, "seed": seed, **result.curve},
        )


STEP = StepDef(
    name="train",
    code_version="train-3",
    run=run,
    inputs=("base-policy", "replay"),
    optional_inputs=("handoff", "teacher"),
    outputs={"checkpoint": "checkpoint", "replay": "replay", "curve": "eval"},
    description="off-policy RL on chunks with an evaluation grid and resumable checkpoints",
)
