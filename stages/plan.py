"""Turn a workflow's stage k into the runner's plan: which steps, wired to which inputs, with which config.

    plan = plan_stage(workflow, k, store)          # StagePlan of StepInvocations
    wf = apply_budget(workflow, "0.01")            # scale the env-step budget (CPU runs of GPU workflows)

Stage k runs, in order (paper Algorithm 1; `record-demos` only when the workflow gives no demos of task k):

    record-demos   expert demos D^k of task k                          config: task, seed, quality, expert kind
    finetune-base  π_base^{k-1} (or the workflow's init) + D^1..D^k -> π_base^k
    cache-teacher  handoff k-1 [+ π_base^k] -> Eq. 3 targets (a "skipped" record at stage 1 / non-distilling
                   methods; π_base^k's chunks at the retained states with learner.distill_inputs fresh/both)
    warmup         π_base^k on task k -> first shard of B^k
    train          π_base^k, B^k, handoff k-1, targets -> θ^k ψ^k, B^k, learning curve
    evaluate-all   π_base^k + θ^k on tasks 1..k -> row k of the success matrix, MCAP episodes
    handoff        θ^k ψ^k, B^k, handoff k-1 -> handoff k (θ^k, ψ^k, B^{<k+1})

Each step's config holds only the settings it reads, so changing one setting re-runs exactly the steps
that read it and those downstream (through their changed inputs). Earlier stages are reached through
refs (`workflow/<name>/stage/<i>/<step>:<role>`), resolved and pinned when the step starts.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from accrue.encoders import encoder_identity
from accrue.policy.from_scratch import SCRATCH_NAMES
from stages.demo_rules import stage_records_demos, uses_demos
from stages.errors import StageError
from stages.runner import step_ref
from stages.runner_types import FromRef, FromStep, StagePlan, StepInvocation
from stages.workflow import Workflow

DEMO_ENVS = 8


def output_ref(wf: Workflow, stage: int, step: str, role: str) -> FromRef:
    return FromRef(f"{step_ref(wf.name, stage, step)}:{role}")


def _gamma(wf: Workflow) -> float:
    from stages.workflow import _learner_config_class

    cls = _learner_config_class()
    return float(wf.learner.get("gamma", cls().gamma if cls is not None else 0.99))


def check_workflow(wf: Workflow) -> None:
    """Values the schema cannot check alone (task ids exist, given demos name a task of the workflow)."""
    from accrue.sim import list_tasks

    if wf.robot is not None:  # a robot's modules may add its tasks (so101_env: accrue.robot.sim_robot.so101_tasks)
        from accrue.robot.robot_types import import_robot_module

        for name in wf.robot.imports:
            import_robot_module(name, "robot.imports")
    known = list_tasks()
    for i, task in enumerate(wf.tasks):
        if task not in known:
            raise StageError(f"workflow {wf.name}: tasks[{i}]: unknown task {task!r} (known: {', '.join(known)})")
    for task in wf.base_policy.demos:
        if task not in wf.tasks:
            raise StageError(f"workflow {wf.name}: base_policy.demos: {task!r} is not one of the workflow's tasks")
    if not wf.base_policy.init.strip():
        raise StageError(f"workflow {wf.name}: base_policy.init: must not be empty")


def _init_source(wf: Workflow, store) -> str | None:
    """Stage 1's starting policy: None for a from-scratch name, else an artifact id or ref."""
    from accrue.scripted_reference import parse_spec

    init = wf.base_policy.init
    if init in SCRATCH_NAMES or parse_spec(init) is not None:
        return None
    path = Path(init).expanduser()
    if path.is_dir():  # a checkpoint directory on disk is brought into the store (idempotent)
        from artifacts.ingest import add_path

        return add_path(store, path, "base-policy")[0]
    return init


def _camera_version(obs_mode: str) -> dict:
    """Steps that render the simulator's cameras carry the renderer's version in their key: images rendered
    before the cameras were placed at their poses (every view from the world origin) are not reused. State-only
    steps render nothing and keep their keys."""
    return {} if obs_mode == "state" else {"sim_cameras": "posed"}


def plan_stage(wf: Workflow, stage: int, store) -> StagePlan:
    from stages.steps import STEPS

    wf.check_stage(stage)
    check_workflow(wf)
    k, task, b, bp = stage, wf.task(stage), wf.budgets, wf.base_policy
    tasks = wf.tasks[:k]
    gamma = _gamma(wf)
    learner = wf.learner_settings()
    if wf.task_descriptor != "none":  # its columns have a fixed scale: the normaliser passes them through
        from accrue.learner_inputs import descriptor_dim

        learner.setdefault("obs_norm_fixed_tail", descriptor_dim(wf.task_descriptor))
    method, ablation = learner["method"], learner.get("ablation", "none")
    steps: list[StepInvocation] = []

    def add(name: str, config: dict, inputs: dict, step=None) -> None:
        steps.append(StepInvocation(step=step or STEPS[name], config=config, inputs=inputs, workflow=wf.name, stage=k))

    # demos D^1..D^k: given artifacts, else recorded by the scripted expert (this stage records D^k);
    # none where finetune-base reads none (uses_demos: the scripted stand-in, a robot's policy used as given)
    demos = {}
    for i, t in enumerate(tasks if uses_demos(wf) else [], 1):
        if t in bp.demos:
            demos[f"demos-{i}"] = bp.demos[t]
        elif i == k:
            demos[f"demos-{i}"] = FromStep("record-demos", "demos")
        else:
            demos[f"demos-{i}"] = output_ref(wf, i, "record-demos", "demos")
    if stage_records_demos(wf, k):
        demo_config = {
            "task": task,
            "episodes": bp.demos_per_task,
            "seed": wf.seed,
            "quality": bp.demo_quality,
            "obs_mode": wf.obs_mode,
            "num_envs": DEMO_ENVS,
        }
        # the demonstrator's kind enters the cache key only when it is not the default searching expert
        if not bp.demo_search or bp.demo_bias_known != 1.0:
            demo_config.update(search=bp.demo_search, bias_known=bp.demo_bias_known)
        demo_config.update(_camera_version(wf.obs_mode))
        add("record-demos", demo_config, {})

    init = _init_source(wf, store) if k == 1 else output_ref(wf, k - 1, "finetune-base", "base-policy")
    ft_inputs = dict(demos, **({"init": init} if init is not None else {}))
    ft_step = dataclasses.replace(STEPS["finetune-base"], inputs=tuple(demos))
    add(
        "finetune-base",
        {
            "stage": k,
            "tasks": tasks,
            "init": bp.init if k == 1 else "previous-stage",
            "finetune": bp.finetune,
            "steps": bp.finetune_steps,
            "batch_size": bp.batch_size,
            "lr": bp.lr,
            "seed": wf.seed,
            "retention": bp.demo_retention,
            "chunk_size": wf.horizon,
        },
        ft_inputs,
        step=ft_step,
    )

    previous_handoff = output_ref(wf, k - 1, "handoff", "handoff") if k > 1 else None
    from stages.steps.cache_teacher import skip_reason

    distills = skip_reason(k, method, ablation) is None
    teacher_config = {"stage": k, "method": method, "ablation": ablation, "seed": wf.seed}
    teacher_inputs = {"handoff": previous_handoff} if distills else {}
    distill_inputs = learner.get("distill_inputs", "stored")
    if distills and distill_inputs != "stored":  # π_base^k's chunks at the retained states are cached too
        teacher_config.update(distill_inputs=distill_inputs, task_ids=tasks, encoder=wf.encoder, horizon=wf.horizon)
        if wf.encoder != "none":
            teacher_config["encoder_id"] = encoder_identity(wf.encoder)
        teacher_inputs["base-policy"] = FromStep("finetune-base", "base-policy")
    add("cache-teacher", teacher_config, teacher_inputs)

    env = {"horizon": wf.horizon, "obs_mode": wf.obs_mode, "encoder": wf.encoder, "num_envs": b.num_envs}
    env.update(_camera_version(wf.obs_mode))
    if wf.encoder != "none":  # the frozen encoder's identity (weights digest), not just its path
        env["encoder_id"] = encoder_identity(wf.encoder)
    if wf.task_features:  # in the cache key only when used, so workflows without it keep their keys
        env["task_features"] = wf.task_features
    if wf.history:  # likewise the opt-in learner inputs
        env["history"] = wf.history
    if wf.task_descriptor != "none":
        env["task_descriptor"] = wf.task_descriptor
    add(
        "warmup",
        {"stage": k, "task": task, "seed": wf.seed, "episodes": b.warmup_episodes, "gamma": gamma, **env},
        {"base-policy": FromStep("finetune-base", "base-policy")},
    )

    # the disjoint report set enters train's and evaluate-all's keys only when used (old runs keep theirs)
    report = {"report_episodes": b.report_episodes} if b.report_episodes else {}
    curves = {"curves": "full"} if b.full_curves else {}  # in train's key only when asked for
    train_inputs = {"base-policy": FromStep("finetune-base", "base-policy"), "replay": FromStep("warmup", "replay")}
    if previous_handoff is not None:
        train_inputs["handoff"] = previous_handoff
    if distills:
        train_inputs["teacher"] = FromStep("cache-teacher", "teacher")
    add(
        "train",
        {
            "stage": k,
            "task_ids": tasks,
            "seed": wf.seed,
            "learner": learner,
            "env_steps": b.env_steps,
            "eval_every": b.eval_every,
            "eval_episodes": b.eval_episodes,
            "checkpoint_every": b.checkpoint_every,
            **report,
            **curves,
            **env,
        },
        train_inputs,
    )

    add(
        "evaluate-all",
        {
            "stage": k,
            "task_ids": tasks,
            "seed": wf.seed,
            "episodes": b.eval_episodes,
            "gamma": gamma,
            "method": method,
            "record_episodes": b.log_episodes,
            **report,
            **env,
        },
        {"base-policy": FromStep("finetune-base", "base-policy"), "checkpoint": FromStep("train", "checkpoint")},
    )

    handoff_inputs = {"checkpoint": FromStep("train", "checkpoint"), "replay": FromStep("train", "replay")}
    if previous_handoff is not None:
        handoff_inputs["handoff"] = previous_handoff
    add(
        "handoff",
        {"stage": k, "retained_episodes": b.retained_episodes, "method": method, "ablation": ablation, "seed": wf.seed},
        handoff_inputs,
    )
    if wf.robot is not None:  # warmup, train and evaluate-all on a lerobot robot (stages/steps/robot_plan.py)
        from stages.steps.robot_plan import bind_robot

        steps = bind_robot(wf, k, steps)
    from stages.steps.train import bind_tracking  # the workflow's tracking: section, outside the cache key

    steps = bind_tracking(steps, wf.tracking, wf.name)
    return StagePlan(workflow=wf.name, stage=k, steps=tuple(steps))


def apply_budget(wf: Workflow, budget: str | None) -> Workflow:
    """`--budget 0.01` scales env_steps, eval_every, checkpoint_every and the base policy's fine-tuning
    steps by 0.01; `--budget 5000` sets env_steps to 5000 and scales the others alike (fine-tuning never
    grows). The evaluation grid keeps its number of points."""
    if budget is None:
        return wf
    try:
        value = float(budget)
    except ValueError:
        raise StageError(f"--budget: expected a fraction in (0, 1] or a number of env steps (got {budget!r})") from None
    if not value > 0 or value != value:
        raise StageError(f"--budget: must be positive (got {budget!r})")
    if value > 1 and not value.is_integer():
        raise StageError(f"--budget: env steps must be a whole number (got {budget!r})")
    b = wf.budgets
    scale = value if value <= 1 else value / b.env_steps
    env_steps = max(1, round(b.env_steps * scale))
    eval_every = min(env_steps, max(1, round(b.eval_every * scale)))
    ckpt = 0 if b.checkpoint_every == 0 else max(1, round(b.checkpoint_every * scale))
    budgets = b.model_copy(update={"env_steps": env_steps, "eval_every": eval_every, "checkpoint_every": ckpt})
    # the base policy's fine-tuning shrinks with the rest, so a GPU workflow can smoke-run on CPU
    base = wf.base_policy.model_copy(
        update={"finetune_steps": max(1, round(wf.base_policy.finetune_steps * min(scale, 1.0)))}
    )
    return wf.model_copy(update={"budgets": budgets, "base_policy": base})
