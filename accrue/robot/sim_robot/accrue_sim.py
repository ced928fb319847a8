"""A lerobot `Robot` backed by one accrue.sim MuJoCo task (make_vec_env with num_envs=1).

Observations are the task's state vector as flat floats named like accrue.sim.STATE_NAMES plus
`episode.done` (1.0 once the plug is seated or the time limit passed); actions are the 6-D normalised
end-effector delta named like ACTION_NAMES. Two extras that no real robot has, used by the scripted
operator in place of a person: `reset_scene()` (the operator puts the parts back) and `episode_success()`
(what the operator would see). Pacing (real time or a clock factor) is the control loop's business, as
with lerobot's own record loop. Faults are injected from the config (see config_accrue_sim).
"""

from __future__ import annotations

import time

import numpy as np
from lerobot.robots.robot import Robot
from lerobot.utils.errors import DeviceNotConnectedError

from accrue.robot.sim_robot.config_accrue_sim import AccrueSimConfig
from accrue.sim.observation import ACTION_NAMES, STATE_NAMES

DONE_KEY = "episode.done"

# Fault schedules count the steps of the simulated *arm*, not of one driver object: a bridge that rebuilds
# the driver after a timeout talks to the same arm, whose faults do not fire again. The count lives on the
# config object the drivers share. (A module-level map keyed by id(config) once handed a later step's new
# config, allocated at a dead config's address, a spent schedule: that step never faulted.)
_ARM_ATTR = "_accrue_sim_arm"


def _arm_of(config: AccrueSimConfig) -> list:
    """[send_action calls, late observations already served] of the arm behind this config."""
    if not hasattr(config, _ARM_ATTR):
        object.__setattr__(config, _ARM_ATTR, [0, set()])
    return getattr(config, _ARM_ATTR)


class AccrueSim(Robot):
    config_class = AccrueSimConfig
    name = "accrue_sim"

    def __init__(self, config: AccrueSimConfig):
        super().__init__(config)
        self.config = config
        self._env = None
        self._connected = False
        # [send_action calls, late observations already served] of this arm, for fault injection
        self._arm = _arm_of(config)
        self._obs: np.ndarray | None = None
        self._done = False
        self._success = False
        self._dropped_link = False

    @property
    def observation_features(self) -> dict:
        return {**{n: float for n in STATE_NAMES}, DONE_KEY: float}

    @property
    def action_features(self) -> dict:
        return {n: float for n in ACTION_NAMES}

    @property
    def is_connected(self) -> bool:
        return self._connected

    @property
    def is_calibrated(self) -> bool:
        return True

    def calibrate(self) -> None:
        pass

    def configure(self) -> None:
        pass

    def connect(self, calibrate: bool = True) -> None:
        if self._env is None:
            import dataclasses

            from accrue.sim import get_task
            from accrue.sim.vec_env import VecAssemblyEnv

            spec = get_task(self.config.task)
            r, f = spec.randomisation, float(self.config.estimate_noise)
            if f != 1.0:
                spec = dataclasses.replace(
                    spec,
                    randomisation=dataclasses.replace(
                        r, estimate_xy=r.estimate_xy * f, estimate_yaw=r.estimate_yaw * f
                    ),
                )
            self._env = VecAssemblyEnv(spec, num_envs=1, seed=self.config.seed, nthread=1)
            self.reset_scene()
        self._connected = True

    def disconnect(self) -> None:
        self._connected = False

    def _check(self) -> None:
        if not self._connected:
            raise DeviceNotConnectedError(f"{self} is not connected")

    def get_observation(self) -> dict:
        self._check()
        steps, fired = self._arm
        if steps in self.config.late_observation_steps and steps not in fired:
            fired.add(steps)
            time.sleep(self.config.late_by_s)
        out = {n: float(v) for n, v in zip(STATE_NAMES, self._obs)}
        out[DONE_KEY] = 1.0 if self._done else 0.0
        return out

    def send_action(self, action: dict) -> dict:
        self._check()
        self._arm[0] += 1
        steps = self._arm[0]
        if self.config.disconnect_after_steps and steps == self.config.disconnect_after_steps:
            self._connected = False
            raise DeviceNotConnectedError(f"{self}: link lost (injected fault at step {steps})")
        if steps in self.config.drop_command_steps:
            return {}  # the command never reached the controller
        if not self._done:
            a = np.array([[float(action[n]) for n in ACTION_NAMES]], dtype=np.float64)
            res = self._env.step(a)
            self._obs = res.obs["state"][0]
            self._done = bool(res.done[0])
            self._success = bool(res.success[0])
        return dict(action)

    # --------------------------------------------------------------- the scripted operator's view
    def reset_scene(self) -> None:
        obs = self._env.reset()
        self._obs, self._done, self._success = obs["state"][0], False, False

    def episode_success(self) -> bool:
        return self._success
