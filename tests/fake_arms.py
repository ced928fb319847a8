"""A seven-key arm for the tests (not a test module itself): accrue's simulated robot in joint mode with a
gripper servo on top, registered in lerobot's RobotConfig registry as `accrue_sim_gripper`.

It declares the six joints of `accrue_sim` (joint mode) plus `gripper.pos`, as an arm with a gripper does
(lerobot's SO-101 reports its gripper the same way, in lerobot's range_0_100 units): a command is clipped to
[0, 100] and read back at the next observation. The simulated plug stays held whatever the gripper is told,
so the seventh key changes what the learner acts in (H x 7 chunks), not the scene."""

from __future__ import annotations

from dataclasses import dataclass

from lerobot.robots.config import RobotConfig

from accrue.robot.sim_robot.accrue_sim import AccrueSim
from accrue.robot.sim_robot.config_accrue_sim import AccrueSimConfig

GRIPPER = "gripper.pos"


@RobotConfig.register_subclass("accrue_sim_gripper")
@dataclass(kw_only=True)
class GripperSimConfig(AccrueSimConfig):
    action_mode: str = "joint"
    gripper_start: float = 50.0


class GripperSim(AccrueSim):  # found by lerobot next to GripperSimConfig (its name without "Config")
    config_class = GripperSimConfig
    name = "accrue_sim_gripper"

    def __init__(self, config: GripperSimConfig):
        super().__init__(config)
        self.gripper = float(config.gripper_start)
        self.gripper_commands: list[float] = []

    @property
    def observation_features(self) -> dict:
        return {**super().observation_features, GRIPPER: float}

    @property
    def action_features(self) -> dict:
        return {**super().action_features, GRIPPER: float}

    def get_observation(self) -> dict:
        return {**super().get_observation(), GRIPPER: self.gripper}

    def send_action(self, action: dict) -> dict:
        action = dict(action)
        command = float(action.pop(GRIPPER))
        sent = super().send_action(action)
        if sent:
            self.gripper = min(100.0, max(0.0, command))
            self.gripper_commands.append(command)
            sent = {**sent, GRIPPER: command}
        return sent
