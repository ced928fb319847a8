"""A workflow with a `robot:` section: the same stage plan and the same steps, with the robot as the
environment of warmup, train and evaluate-all (stages.steps.robot_env).

finetune-base, cache-teacher and handoff do not touch the environment and run as in simulation. The three
steps that do get the robot's keyed settings in their configs (robot, mapping, stop rule, learner) in
place of the simulator's (vector envs, env-step budget, evaluation grid), the robot's code versions,
the `episodes` output, and its session settings (operator, learner address, clock, faults) bound to
their run the way stages.steps.train.bind_tracking binds tracking: outside the cache key.
"""

from __future__ import annotations

import dataclasses
import functools

from stages.errors import StageError
from stages.runner_types import FromStep, StepInvocation
from stages.workflow import Workflow

KEYED = (
    "type",
    "config",
    "imports",
    "state_keys",
    "camera_keys",
    "action_keys",
    "action_mode",
    "action_limits",
    "action_bounds",
    "done_key",
    "control_hz",
    "episode_steps",
    "safety",
)


def session_settings(wf: Workflow):
    from stages.steps.robot_session import SessionSettings

    r = wf.robot
    return SessionSettings(
        operator=r.operator,
        operator_name=r.operator_name,
        scripted=r.scripted.model_dump(),
        operator_page=dict(r.operator_page),
        learner_address=r.learner_address,
        link=dict(r.link) if r.link is not None else None,
        hold_staleness_s=r.hold.staleness_s,
        hold_wait_s=r.hold.wait_s,
        handoff_wait_s=r.handoff_wait_s,
        clock=r.clock,
        faults=dict(r.faults),
        timeouts=dict(r.timeouts),
        intervention=r.intervention.model_dump() if r.intervention is not None else None,
        tracking=wf.tracking.model_dump(),
        stop_window=r.stop_window,
    )


# keyed only when set, so the workflows without them keep their keys: the pose each episode starts from,
# and the part of each camera frame the encoder and the base policy read
KEYED_WHEN_SET = ("reset_pose", "crop")


def robot_config(wf: Workflow) -> dict:
    r = wf.robot.model_dump()
    keyed = {k: r[k] for k in KEYED} | {k: r[k] for k in KEYED_WHEN_SET if r[k]}
    if keyed["type"] == "accrue_sim" and keyed["done_key"] is None:
        keyed["done_key"] = "episode.done"  # the simulated robot says when the plug is seated or time is up
    return keyed


# what the robot's warmup, train and evaluate-all do (the simulator's descriptions name vector envs and an
# evaluation grid, which a robot stage has not)
DESCRIPTIONS = {
    "warmup": "base-policy episodes on the robot seeding B^k (operator-labelled, sealed)",
    "train": "off-policy RL on the robot in real time until the stop rule or the robot-time budget",
    "evaluate-all": "retention trials on the robot of base policy + actor on tasks 1..k-1",
}

SIM_ONLY = ("num_envs", "env_steps", "eval_every", "eval_episodes", "checkpoint_every", "episodes", "record_episodes")


def check_robot_workflow(wf: Workflow, stage: int) -> None:
    """One line for a base policy that cannot act on this robot, or missing robot demonstrations."""
    from accrue.scripted_reference import parse_spec

    r = wf.robot
    if r.action_mode == "joint" and parse_spec(wf.base_policy.init) is not None:
        raise StageError(
            f"workflow {wf.name}: base_policy.init {wf.base_policy.init} acts in end-effector deltas; "
            "robot.action_mode joint needs a base policy of joint targets (fine-tuned on the robot's demos)"
        )
    from stages.demo_rules import uses_demos

    if r.type != "accrue_sim" and uses_demos(wf):
        missing = [t for t in wf.tasks[:stage] if t not in wf.base_policy.demos]
        if missing:
            raise StageError(
                f"workflow {wf.name}: base_policy.demos: a real robot's demonstrations come from "
                f"lerobot-record; add the dataset of {missing[0]} "
                f"(`accrue add DIR --kind demos --workflow WF --task {missing[0]}`) and name it here"
            )


def robot_step_config(wf: Workflow, name: str, config: dict) -> dict:
    """A step's config with the robot in place of the simulator's vector envs and env-step budget."""
    r = wf.robot
    c = {k: v for k, v in config.items() if k not in SIM_ONLY}
    c.update(robot=robot_config(wf), workflow=wf.name)
    # robot.task_config of the tasks up to this stage's (a later task's fields do not change its key), and
    # in the key only when there is some, so workflows without it keep theirs
    per_task = {t: dict(r.task_config[t]) for t in wf.tasks[: config["stage"]] if t in r.task_config}
    if per_task:
        c["robot"]["task_config"] = per_task
    if name in ("warmup", "train") and r.success_classifier.enabled:  # keyed only when on: the others keep theirs
        c["success_classifier"] = r.success_classifier.model_dump()
    if name == "warmup":
        c.update(phase="warmup", episodes=wf.budgets.warmup_episodes)
    elif name == "train":
        c.update(
            phase="train",
            stop_window=r.stop_window,
            stop_successes=r.stop_successes,
            budget_s=r.budget_s,
            max_episodes=r.max_episodes,
            checkpoint_every=r.checkpoint_every,
            publish_every=r.publish_every,
        )
    else:
        c.update(phase="evaluate", trials=r.retention_trials)
    return c


def classifier_output(wf: Workflow, name: str) -> dict:
    """warmup's and train's `success_classifier` output, with robot.success_classifier on."""
    if name not in ("warmup", "train") or not wf.robot.success_classifier.enabled:
        return {}
    from stages.steps.robot_classifier import KIND, OUTPUT

    return {OUTPUT: KIND}


def bind_robot(wf: Workflow, stage: int, steps: list[StepInvocation]) -> list[StepInvocation]:
    """The stage's invocations with warmup, train and evaluate-all on the workflow's robot: the same
    step bodies, their configs keyed on the robot, its session settings bound (unkeyed)."""
    from stages.steps.robot_env import CODE_VERSIONS

    check_robot_workflow(wf, stage)
    settings = session_settings(wf)
    out = []
    for inv in steps:
        name = inv.step.name
        if name not in CODE_VERSIONS:
            out.append(inv)
            continue
        step = dataclasses.replace(
            inv.step,
            run=functools.partial(inv.step.run, robot=settings),
            code_version=CODE_VERSIONS[name],  # the robot's episodes are not the simulator's: their own caches
            description=DESCRIPTIONS[name],
            # every sealed episode and the sessions; with robot.success_classifier, the classifier too
            outputs={**inv.step.outputs, "episodes": "episodes", **classifier_output(wf, name)},
        )
        inputs = dict(inv.inputs)
        if classifier_output(wf, name) and name == "train":  # it starts from what the operator taught warmup
            from stages.steps.robot_classifier import CARRIED, OUTPUT

            step = dataclasses.replace(step, optional_inputs=(*step.optional_inputs, CARRIED))
            inputs[CARRIED] = FromStep("warmup", OUTPUT)
        config = robot_step_config(wf, name, dict(inv.config))
        out.append(dataclasses.replace(inv, step=step, config=config, inputs=inputs))
    return out
