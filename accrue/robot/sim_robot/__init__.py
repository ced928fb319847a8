"""accrue's simulated robot as a lerobot plugin: importing this package registers robot type `accrue_sim`
(lerobot's make_robot_from_config finds AccrueSim next to AccrueSimConfig) and teleoperator type
`accrue_sim_expert` (the scripted expert taking over; make_teleoperator_from_config finds AccrueSimExpert)."""

from accrue.robot.sim_robot.accrue_sim import DONE_KEY, AccrueSim
from accrue.robot.sim_robot.accrue_sim_expert import AccrueSimExpert
from accrue.robot.sim_robot.config_accrue_sim import AccrueSimConfig
from accrue.robot.sim_robot.config_accrue_sim_expert import AccrueSimExpertConfig
from accrue.robot.sim_robot.config_so101_env import SO101EnvConfig  # so101_env (lerobot-env-so101)

__all__ = ["DONE_KEY", "AccrueSim", "AccrueSimConfig", "AccrueSimExpert", "AccrueSimExpertConfig", "SO101EnvConfig"]
