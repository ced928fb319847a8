"""The environment a step's config names: the simulator, or the robot of a workflow's `robot:` section
(whose unkeyed session settings the plan binds to the step, stages.steps.robot_plan)."""

from __future__ import annotations

from stages.steps.robot_env import RobotEnvironment
from stages.steps.robot_session import SessionSettings
from stages.steps.sim_env import SimEnvironment


def environment_for(config, robot: SessionSettings | None = None):
    """RobotEnvironment where the config holds a `robot` (the keyed part of the robot section), else the
    simulator."""
    return RobotEnvironment(robot) if "robot" in config else SimEnvironment()
