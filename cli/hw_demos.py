"""`accrue add DIR --kind demos --workflow WF [--task TASK]`: a lerobot-record dataset, checked against WF's
robot mapping and converted into accrue's demo layout for TASK, so base_policy.demos can name it."""

from __future__ import annotations

from pathlib import Path


def _task_of(wf, recorded: list[str], task: str | None) -> str:
    """--task, else the workflow task whose id or instruction lerobot-record stored, else its only task."""
    from accrue.sim.demos import get_task_spec
    from stages.errors import StageError

    if task is not None:
        if task not in wf.tasks:
            raise StageError(f"--task {task!r}: not one of workflow {wf.name}'s tasks ({', '.join(wf.tasks)})")
        return task
    said = {t.strip().lower() for t in recorded}
    matches = [t for t in wf.tasks if t.lower() in said or get_task_spec(t).instruction.strip().lower() in said]
    if len(matches) == 1:
        return matches[0]
    if len(wf.tasks) == 1:
        return wf.tasks[0]
    raise StageError(
        f"name the demonstrations' task with --task (one of {', '.join(wf.tasks)}); the dataset "
        f"says {', '.join(repr(t) for t in recorded[:3]) or 'nothing'}"
    )


def convert_demos_for_workflow(path: Path, kind: str, workflow: Path, task: str | None, out_dir: Path) -> dict:
    """Check `path` against the workflow's robot mapping and write accrue demos of the task to out_dir.

    Returns the converted dataset's meta (meta/accrue.json). Every refusal is one line (exit 2).
    """
    import dataclasses

    from accrue.errors import AccrueError
    from stages.errors import StageError
    from stages.workflow import load_workflow

    if kind != "demos":
        raise StageError(f"--workflow converts demonstrations: it goes with --kind demos (got --kind {kind})")
    wf = load_workflow(workflow)
    if wf.robot is None:
        raise StageError(f"--workflow {workflow}: has no robot section to check the dataset against")
    from accrue.robot.bridge import robot_factory
    from accrue.robot.demo_convert import carried_camera, convert_robot_dataset, recorded_tasks
    from accrue.robot.demos import check_robot_dataset
    from accrue.robot.mapping import RobotMapping
    from accrue.robot.robot_types import config_class
    from accrue.sim.demos import get_task_spec
    from stages.steps.robot_plan import robot_config
    from stages.steps.robot_session import task_fields

    r = robot_config(wf)
    config_class("robot", r["type"], tuple(r["imports"]), where="robot", type_key="type")  # registers its tasks
    try:
        task_id, unnamed = _task_of(wf, recorded_tasks(path), task), None
    except (StageError, AccrueError) as exc:  # said after the dataset check: a foreign robot's is refused first
        task_id, unnamed = None, exc
    # the keys the robot itself declares for that task (building its driver object connects nothing): the
    # dataset must hold them, so demos recorded on another robot, or with another task's camera, are refused
    robot = robot_factory(
        r["type"], task_fields({**r, "task_config": wf.robot.task_config}, task_id), tuple(r["imports"])
    )()
    mapping = RobotMapping.from_dict(r).bind(
        robot.observation_features, robot.action_features, f"robot {wf.robot.type}", robot=robot
    )
    camera = carried_camera(mapping, robot.observation_features, wf.obs_mode, f"robot {wf.robot.type}")
    mapping = dataclasses.replace(mapping, camera_keys=())  # the camera (an image workflow's) goes separately
    check_robot_dataset(path, mapping, wf.robot.type, camera)  # metadata first: refused before lerobot loads
    if unnamed is not None:
        raise unnamed
    return convert_robot_dataset(
        path, out_dir, mapping, wf.robot.type, task_id, get_task_spec(task_id).instruction, progress=True, camera=camera
    )
