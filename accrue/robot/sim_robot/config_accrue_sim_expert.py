"""`accrue_sim_expert`: the config of a lerobot Teleoperator that takes over the simulated robot with
accrue's scripted expert, registered in lerobot's TeleoperatorConfig registry like any third-party
teleoperator (importing accrue.robot.sim_robot registers it)."""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.teleoperators.config import TeleoperatorConfig


@TeleoperatorConfig.register_subclass("accrue_sim_expert")
@dataclass(kw_only=True)
class AccrueSimExpertConfig(TeleoperatorConfig):
    task: str = "nist/rect_peg"  # an accrue.sim task id (the expert's geometry and limits)
    quality: float = 1.0  # the scripted expert's quality (1: no aim error, no noise)
    seed: int = 0
    bias_known: float = 1.0  # fraction of the fixture's socket-estimate bias the expert corrects
    # when the expert "holds the takeover button" (its IS_INTERVENTION event): [from, to) control steps of
    # an episode; empty: never (the operator's `i` key can still hand it the robot)
    takeover: list[list[int]] = field(default_factory=list)
    episodes: list[int] = field(default_factory=list)  # the episode indices `takeover` applies to (empty: all)
