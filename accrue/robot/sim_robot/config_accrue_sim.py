"""`accrue_sim`: the config of accrue's simulated robot, registered in lerobot's RobotConfig registry
like any third-party robot (importing accrue.robot.sim_robot registers it)."""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.robots.config import RobotConfig


@RobotConfig.register_subclass("accrue_sim")
@dataclass(kw_only=True)
class AccrueSimConfig(RobotConfig):
    task: str = "nist/rect_peg"  # an accrue.sim task id
    seed: int = 0
    estimate_noise: float = 1.0  # scale of the socket-estimate error (a better or worse camera)
    # MuJoCo cameras rendered into each observation as (image_size, image_size, 3) uint8 (MUJOCO_GL=egl)
    render_cameras: list[str] = field(default_factory=list)  # of "front", "side" (`cameras` is lerobot's own)
    image_size: int = 64
    # delta: the 6-D normalised end-effector delta; joint: absolute targets of the gripper's six joints
    # (x, y, z in m, roll, pitch, yaw in rad, socket frame), as an arm that takes joint targets
    action_mode: str = "delta"
    # injectable faults, counted in control steps (send_action calls) of this config's arm (every
    # driver built from this config object shares one count, so a rebuilt driver does not fault again)
    disconnect_after_steps: int = 0  # the link drops at this step (0: never); connect() restores it
    late_observation_steps: list[int] = field(default_factory=list)  # get_observation answers late here
    late_by_s: float = 2.0
    drop_command_steps: list[int] = field(default_factory=list)  # send_action ignores these commands
    # the process stops itself (SIGSTOP) at this control step (0: never): a test kills -9 the actor exactly here
    stop_at_step: int = 0
