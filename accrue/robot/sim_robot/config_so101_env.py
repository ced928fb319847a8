"""`so101_env`: the config of the SO-101 arm simulated by the third-party package lerobot-env-so101 (PyPI),
registered in lerobot's RobotConfig registry like any third-party robot (importing accrue.robot.sim_robot
registers it; the package itself is imported only when the robot is built)."""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.robots.config import RobotConfig

CONTROL_HZ = 10.0  # the package's control_dt of 0.1 s


@dataclass(frozen=True)
class Scene:
    env: str  # the package's env class
    max_steps: int  # control steps per episode (10 Hz)
    instruction: str
    scripted_steps: int  # control steps its scripted controller took on mujoco 4.0 (seed 0, fixed cube)


SCENES = {
    # the package's README: its pick-cube lift is never reached with the position-only IK, so the reach
    # scene's success is the package's reach-and-close signal, not the lift
    "reach_close": Scene("SO101PickCubeGymEnv", 30, "reach the cube and close the gripper on it", 8),
    "pick_place": Scene("SO101PickPlaceGymEnv", 80, "pick up the cube and place it on the goal", 44),
}


def task_id(scene: str) -> str:
    return f"so101/{scene}"


@RobotConfig.register_subclass("so101_env")
@dataclass(kw_only=True)
class SO101EnvConfig(RobotConfig):
    # the package's scene behind the arm: reach_close (SO101PickCube, success = its is_reach_close_success:
    # gripper closed within 5 cm of the cube) or pick_place (SO101PickPlace, success = its own: the cube
    # lifted, carried and set down at the goal)
    scene: str = "reach_close"
    seed: int = 0
    random_block_position: bool = False  # the package's own option: a new cube (and goal) place per reset
    render_cameras: list[str] = field(default_factory=lambda: ["front"])  # the scene's one camera, or none
    image_size: int = 64  # (image_size, image_size, 3) uint8 frames
    fast_render: bool = True  # no shadows, reflections, skybox or multisampling (see SO101Env._render)
    episode_steps: int = 0  # the scene's time limit in control steps (0: the task's own, see so101_env.SCENES)
