"""A lerobot `Robot` backed by one accrue.sim MuJoCo task (make_vec_env with num_envs=1).

Observations are the task's state vector as flat floats named like accrue.sim.STATE_NAMES plus
`episode.done` (1.0 once the plug is seated or the time limit passed) and, with `render_cameras`, a MuJoCo frame
per camera declared as (h, w, 3) like any lerobot camera. With `action_mode: delta` actions are the 6-D
normalised end-effector delta named like ACTION_NAMES; with `action_mode: joint` they are absolute targets
of the gripper's six joints (`x.pos` ... `yaw.pos`, socket frame, m and rad), whose readings join the
observation, as an arm that takes joint targets (an SO-101) reports and takes them. Two extras that no real robot has, used by the scripted
operator in place of a person: `reset_scene()` (the operator puts the parts back) and `episode_success()`
(what the operator would see). Pacing (real time or a clock factor) is the control loop's business, as
with lerobot's own record loop. Faults are injected from the config (see config_accrue_sim).
"""

from __future__ import annotations

import os
import signal
import time

import numpy as np
from lerobot.robots.robot import Robot
from lerobot.utils.errors import DeviceNotConnectedError

from accrue.robot.sim_robot.config_accrue_sim import AccrueSimConfig
from accrue.sim.model import JOINTS
from accrue.sim.observation import ACTION_NAMES, STATE_NAMES, rotate_xy

DONE_KEY = "episode.done"
JOINT_KEYS = tuple(f"{j}.pos" for j in JOINTS)
ACTION_MODES = ("delta", "joint")

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
        joints = {k: float for k in JOINT_KEYS} if self.config.action_mode == "joint" else {}
        size = int(self.config.image_size)
        cams = {c: (size, size, 3) for c in self.config.render_cameras}
        return {**{n: float for n in STATE_NAMES}, **joints, DONE_KEY: float, **cams}

    @property
    def action_features(self) -> dict:
        return {k: float for k in (JOINT_KEYS if self.config.action_mode == "joint" else ACTION_NAMES)}

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
            if self.config.action_mode not in ACTION_MODES:
                raise ValueError(
                    f"accrue_sim: action_mode must be one of {ACTION_MODES} (got {self.config.action_mode!r})"
                )
            self._env = VecAssemblyEnv(
                spec, num_envs=1, seed=self.config.seed, nthread=1, image_size=int(self.config.image_size)
            )
            self.reset_scene()
        self._warm_cameras()
        self._connected = True

    def _warm_cameras(self) -> None:
        """Pay the renderer's start-up here, not in the first get_observation: the first frame makes the GL
        context (EGL's display on the process's first), uploads the model and compiles the shaders, several
        times a later frame's cost (0.2-0.7 s against 5 ms on CPU GL), which on a loaded machine outlasted the
        bridge's observation timeout. Rendering only computes poses (mj_kinematics), so the scene is
        unchanged. Runs on every connect: disconnect closes the renderer."""
        for camera in self.config.render_cameras:
            self._env.render(camera)

    def disconnect(self) -> None:
        self._connected = False
        if self._env is not None:
            self._env.close()  # the camera's GL context (made again on the next frame); the scene stays

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
        if self.config.action_mode == "joint":
            out.update({k: float(v) for k, v in zip(JOINT_KEYS, self._joints())})
        out[DONE_KEY] = 1.0 if self._done else 0.0
        for camera in self.config.render_cameras:
            out[camera] = self._env.render(camera)[0]
        return out

    def _joints(self) -> np.ndarray:
        """The gripper's six joint positions (socket frame): what an arm's encoders would read."""
        return np.array(self._env.batch.get_data(0).qpos[: len(JOINTS)], dtype=np.float64)

    def _as_delta(self, action: dict) -> np.ndarray:
        """(1, 6) normalised delta that moves the env's joint targets to the commanded ones (the inverse of
        VecAssemblyEnv's delta -> target map, clipped to its per-step limits like a rate-limited servo)."""
        if self.config.action_mode == "delta":
            return np.array([[float(action[n]) for n in ACTION_NAMES]], dtype=np.float64)
        env = self._env
        step = np.array([float(action[k]) for k in JOINT_KEYS]) - env.target[0]
        yaw = env.socket_pose[0:1, 2]
        step[0:2] = rotate_xy(step[None, 0:2], yaw)[0]
        step[3:5] = rotate_xy(step[None, 3:5], yaw)[0]
        task = env.task
        limits = np.array([task.max_delta_pos] * 3 + [task.max_delta_rot] * 3)
        return np.clip(step / limits, -1.0, 1.0)[None]

    def send_action(self, action: dict) -> dict:
        self._check()
        self._arm[0] += 1
        steps = self._arm[0]
        if self.config.disconnect_after_steps and steps == self.config.disconnect_after_steps:
            self._connected = False
            raise DeviceNotConnectedError(f"{self}: link lost (injected fault at step {steps})")
        if self.config.stop_at_step and steps == self.config.stop_at_step:
            os.kill(os.getpid(), signal.SIGSTOP)  # frozen mid-episode until a SIGCONT or the test's SIGKILL
        if steps in self.config.drop_command_steps:
            return {}  # the command never reached the controller
        if not self._done:
            res = self._env.step(self._as_delta(action))
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
