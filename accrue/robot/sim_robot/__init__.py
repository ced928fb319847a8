"""accrue's simulated robot as a lerobot plugin: importing this package registers robot type `accrue_sim`
(lerobot's make_robot_from_config finds AccrueSim next to AccrueSimConfig)."""

from accrue.robot.sim_robot.accrue_sim import DONE_KEY, AccrueSim
from accrue.robot.sim_robot.config_accrue_sim import AccrueSimConfig

__all__ = ["DONE_KEY", "AccrueSim", "AccrueSimConfig"]
