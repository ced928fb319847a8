"""N assembly environments of one task stepped together on mujoco.batch's C thread pool.

Physics runs in the socket frame (socket fixed at the origin). The policy sees and acts in a
robot frame where the socket sits at a random pose (placement noise) known only through a noisy,
per-task-biased estimate, and (contact family) reads the held part's tip off by its in-hand offset.
Every random draw comes from a generator seeded by
(seed, env index, episode count), so trajectories do not depend on which other envs were reset.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from accrue.errors import AccrueError
from accrue.sim.model import KP_POS, KP_ROT, build_model, damping_for, socket_geom_ids
from accrue.sim.observation import (
    ACTION_DIM,
    FORCE_SCALE,
    HISTORY_DIM,
    HISTORY_STEPS,
    POS_SCALE,
    REL_POS_SCALE,
    STATE_DIM,
    TILT_SCALE,
    TORQUE_SCALE,
    VEL_SCALE,
    rotate_xy,
)
from accrue.sim.tasks import DEG, MM, TaskSpec, get_task

TARGET_LEAD_POS = 4 * MM  # the position target never leads the plug by more (bounds the push)
TARGET_LEAD_ROT = 6 * DEG
MAX_TILT = 5 * DEG  # success also needs the plug upright
WORKSPACE = 40 * MM  # target box half-width around the socket
_XY_PAIRS = [0, 1, 3, 4, 6, 7, 9, 10]  # (x, y), (roll, pitch), (vx, vy), (wx, wy) in concat(qpos, qvel)


@dataclass
class StepResult:
    obs: dict
    reward: np.ndarray  # (N,) discounted sum over the executed steps
    rewards: np.ndarray  # (N, H)
    terminated: np.ndarray  # (N,) success reached
    truncated: np.ndarray  # (N,) time limit
    success: np.ndarray  # (N,)
    steps: np.ndarray  # (N,) control steps actually executed

    @property
    def done(self) -> np.ndarray:
        return self.terminated | self.truncated


def wrap_angle(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def yaw_error(yaw: np.ndarray, period: float) -> np.ndarray:
    """Yaw distance to the nearest aligned orientation (0 for round parts)."""
    if period <= 0:
        return np.zeros_like(yaw)
    return np.abs((yaw + period / 2) % period - period / 2)


def is_success(task: TaskSpec, qpos: np.ndarray) -> np.ndarray:
    """Inserted to depth, laterally centred, upright and yaw-aligned (socket frame joint values)."""
    deep = qpos[:, 2] <= -task.success_depth
    centred = np.hypot(qpos[:, 0], qpos[:, 1]) <= task.xy_tol
    upright = np.maximum(np.abs(qpos[:, 3]), np.abs(qpos[:, 4])) <= MAX_TILT
    aligned = yaw_error(qpos[:, 5], task.yaw_period) <= task.yaw_tol
    return deep & centred & upright & aligned


class VecAssemblyEnv:
    def __init__(
        self,
        task: TaskSpec | str,
        num_envs: int,
        seed: int = 0,
        obs_mode: str = "state",
        image_size: int = 64,
        nthread: int | None = None,
    ):
        from mujoco import batch

        self.task = get_task(task) if isinstance(task, str) else task
        if obs_mode not in ("state", "state+image"):
            raise AccrueError(f"obs_mode must be 'state' or 'state+image', got {obs_mode!r}")
        if num_envs < 1:
            raise AccrueError(f"num_envs must be >= 1, got {num_envs}")
        self.num_envs, self.seed, self.obs_mode, self.image_size = int(num_envs), int(seed), obs_mode, image_size
        self.model = build_model(self.task)
        threads = nthread or max(1, min(self.num_envs, os.cpu_count() or 1))
        self.batch = batch.Batch(self.model, nsim=self.num_envs, nthread=threads)
        self._qpos, self._qvel = self.batch.bind("qpos"), self.batch.bind("qvel")
        self._ctrl, self._sensor = self.batch.bind("ctrl"), self.batch.bind("sensordata")
        self._friction = self.batch.expand("geom_friction")
        self._mass = self.batch.expand("body_mass")
        self._gain, self._bias = self.batch.expand("actuator_gainprm"), self.batch.expand("actuator_biasprm")
        self._socket_geoms = socket_geom_ids(self.model)
        self._plug_body = self.model.body("plug").id
        self._limits = np.array([self.task.max_delta_pos] * 3 + [self.task.max_delta_rot] * 3)
        self._lead = np.array([TARGET_LEAD_POS] * 3 + [TARGET_LEAD_ROT] * 3)
        n = self.num_envs
        self.episode = np.full(n, -1, dtype=np.int64)  # episodes started per env
        self.t = np.zeros(n, dtype=np.int64)
        self.done = np.ones(n, dtype=bool)
        self.target = np.zeros((n, 6))
        self.socket_pose = np.zeros((n, 3))  # true socket (x, y, yaw) in the robot frame
        self.estimate = np.zeros((n, 4))  # estimated socket (x, y, z, yaw) in the robot frame
        self.in_hand = np.zeros((n, 3))  # held part's (x, y, yaw) offset in the gripper: the tip reading is off by it
        self._rngs: list[np.random.Generator | None] = [None] * n
        self._renderer = None
        self._noise = np.zeros((n, 12))
        self._state = np.zeros((n, STATE_DIM))
        self._history = np.zeros((n, HISTORY_STEPS, HISTORY_DIM))  # newest first (observation.HISTORY_NAMES)

    # ---------------------------------------------------------------- reset
    def reset(self, mask=None) -> dict:
        ids = np.arange(self.num_envs) if mask is None else np.flatnonzero(np.asarray(mask, dtype=bool))
        if len(ids):
            self.batch.reset(ids)
            for i in ids:
                self._start_episode(int(i))
            self.batch.forward(ids)
            self._draw_noise(ids)
        return self._observe()

    def _start_episode(self, i: int) -> None:
        task, r = self.task, self.task.randomisation
        self.episode[i] += 1
        rng = np.random.default_rng([self.seed, i, int(self.episode[i])])
        self._rngs[i] = rng
        self.t[i], self.done[i] = 0, False
        self._history[i] = 0.0
        self.socket_pose[i] = [*rng.uniform(-r.socket_xy, r.socket_xy, 2), rng.uniform(-r.socket_yaw, r.socket_yaw)]
        err = [*rng.normal(0, r.estimate_xy, 2), rng.normal(0, r.estimate_xy / 2), rng.normal(0, r.estimate_yaw)]
        bias = np.array([task.estimate_bias[0], task.estimate_bias[1], 0.0, task.estimate_bias[2]])
        self.estimate[i] = np.array([*self.socket_pose[i, :2], 0.0, self.socket_pose[i, 2]]) + bias + err
        q0 = np.array(
            [
                *rng.uniform(-r.init_xy, r.init_xy, 2),
                rng.uniform(*r.init_z),
                *rng.uniform(-r.init_tilt, r.init_tilt, 2),
                rng.uniform(-r.init_yaw, r.init_yaw),
            ]
        )
        self._qpos[i] = q0
        self._qvel[i] = 0.0
        self.target[i] = q0
        self._ctrl[i] = q0
        self._friction[i, self._socket_geoms, 0] = rng.uniform(*r.friction)
        self._mass[i, self._plug_body] = task.plug_mass + rng.uniform(-r.mass_delta, r.mass_delta)
        gain = rng.uniform(*r.gain_scale)
        kv_pos, kv_rot = damping_for(KP_POS * gain, KP_ROT * gain, task.plug_mass)
        kp = np.array([KP_POS * gain] * 3 + [KP_ROT * gain] * 3)
        self._gain[i, :, 0] = kp
        self._bias[i, :, 1] = -kp
        self._bias[i, :, 2] = [-kv_pos] * 3 + [-kv_rot] * 3
        if r.in_hand_xy > 0 or r.in_hand_yaw > 0:  # drawn last and only when set: other tasks' streams unchanged
            self.in_hand[i] = [*rng.normal(0, r.in_hand_xy, 2), rng.normal(0, r.in_hand_yaw)]

    # ---------------------------------------------------------------- step
    def step(self, actions: np.ndarray) -> StepResult:
        return self.step_chunk(np.asarray(actions)[:, None, :], gamma=1.0)

    def step_chunk(self, actions: np.ndarray, gamma: float = 0.99) -> StepResult:
        actions = np.asarray(actions, dtype=np.float64)
        n = self.num_envs
        if actions.ndim != 3 or actions.shape[0] != n or actions.shape[2] != ACTION_DIM:
            raise AccrueError(f"actions must have shape ({n}, H, {ACTION_DIM}), got {actions.shape}")
        horizon = actions.shape[1]
        rewards = np.zeros((n, horizon))
        steps = np.zeros(n, dtype=np.int64)
        success = np.zeros(n, dtype=bool)
        truncated = np.zeros(n, dtype=bool)
        active = ~self.done
        for h in range(horizon):
            ids = np.flatnonzero(active)
            if len(ids) == 0:
                break
            act = np.clip(actions[ids, h], -1.0, 1.0)
            self._apply_action(ids, act)
            self.batch.step(ids, nstep=self.task.substeps)
            self.t[ids] += 1
            steps[ids] += 1
            self._draw_noise(ids)
            self._record_history(ids, act)
            won = is_success(self.task, self._qpos[ids])
            late = ~won & (self.t[ids] >= self.task.max_steps)
            # the paper's rule: the final three steps of a successful episode carry reward 1
            for i in ids[won]:
                rewards[i, max(0, h - 2) : h + 1] = 1.0
            success[ids[won]] = True
            truncated[ids[late]] = True
            active[ids[won | late]] = False
            self.done[ids[won | late]] = True
        discounts = gamma ** np.arange(horizon)
        return StepResult(
            obs=self._observe(),
            reward=rewards @ discounts,
            rewards=rewards,
            terminated=success.copy(),
            truncated=truncated,
            success=success,
            steps=steps,
        )

    def _apply_action(self, ids: np.ndarray, act: np.ndarray) -> None:
        """Robot-frame deltas -> socket-frame joint targets, kept within a lead of the current pose."""
        delta = act * self._limits
        yaw = self.socket_pose[ids, 2]
        delta[:, 0:2] = rotate_xy(delta[:, 0:2], -yaw)
        delta[:, 3:5] = rotate_xy(delta[:, 3:5], -yaw)
        q = self._qpos[ids]
        target = np.clip(self.target[ids] + delta, q - self._lead, q + self._lead)
        target[:, :3] = np.clip(target[:, :3], -WORKSPACE, WORKSPACE)
        self.target[ids] = target
        self._ctrl[ids] = target

    # ---------------------------------------------------------------- observation
    def _draw_noise(self, ids) -> None:
        """One observation-noise draw per env per control step, from that env's own stream."""
        for i in ids:
            self._noise[i] = self._rngs[i].standard_normal(12)

    def _record_history(self, ids: np.ndarray, act: np.ndarray) -> None:
        """Push one control step (this step's noise draw, the same one the state would show) per env."""
        r, noise, q = self.task.randomisation, self._noise[ids], self._qpos[ids]
        yaw = self.socket_pose[ids, 2]
        tip = rotate_xy(q[:, :2], yaw) + self.socket_pose[ids, :2] + noise[:, :2] * r.obs_pos - self.in_hand[ids, :2]
        entry = np.empty((len(ids), HISTORY_DIM))
        entry[:, 0:3] = (self._sensor[ids, 0:3] + noise[:, 6:9] * r.obs_force) * FORCE_SCALE
        entry[:, 3:6] = (self._sensor[ids, 3:6] + noise[:, 9:12] * (r.obs_force * 0.02)) * TORQUE_SCALE
        entry[:, 6:8] = (self.estimate[ids, :2] - tip) * REL_POS_SCALE
        entry[:, 8] = (self.estimate[ids, 2] - q[:, 2] - noise[:, 2] * r.obs_pos) * REL_POS_SCALE
        entry[:, 9:] = act
        self._history[ids, 1:] = self._history[ids, :-1]
        self._history[ids, 0] = entry

    def _observe(self) -> dict:
        """The scaled robot-frame state (layout: observation.STATE_NAMES), filled column by column:
        at small N the per-step cost is numpy call overhead, so this avoids temporaries."""
        n, r, noise = self.num_envs, self.task.randomisation, self._noise
        q, v, f = self._qpos, self._qvel, self._sensor
        c, s = np.cos(self.socket_pose[:, 2:3]), np.sin(self.socket_pose[:, 2:3])
        qv = np.concatenate([q, v], axis=1)[:, _XY_PAIRS].reshape(n, 4, 2)  # pos, tilt, lin vel, ang vel
        rx, ry = c * qv[:, :, 0] - s * qv[:, :, 1], s * qv[:, :, 0] + c * qv[:, :, 1]
        st = self._state
        hand = self.in_hand
        st[:, 0] = (rx[:, 0] + self.socket_pose[:, 0] + noise[:, 0] * r.obs_pos - hand[:, 0]) * POS_SCALE
        st[:, 1] = (ry[:, 0] + self.socket_pose[:, 1] + noise[:, 1] * r.obs_pos - hand[:, 1]) * POS_SCALE
        st[:, 2] = (q[:, 2] + noise[:, 2] * r.obs_pos) * POS_SCALE
        st[:, 3] = (rx[:, 1] + noise[:, 3] * r.obs_rot) * TILT_SCALE
        st[:, 4] = (ry[:, 1] + noise[:, 4] * r.obs_rot) * TILT_SCALE
        yaw = q[:, 5] + self.socket_pose[:, 2] + noise[:, 5] * r.obs_rot - hand[:, 2]
        st[:, 5], st[:, 6] = np.sin(yaw), np.cos(yaw)
        st[:, 7], st[:, 8], st[:, 9] = rx[:, 2] * VEL_SCALE, ry[:, 2] * VEL_SCALE, v[:, 2] * VEL_SCALE
        st[:, 10], st[:, 11], st[:, 12] = rx[:, 3], ry[:, 3], v[:, 5]
        st[:, 13:16] = (f[:, 0:3] + noise[:, 6:9] * r.obs_force) * FORCE_SCALE
        st[:, 16:19] = (f[:, 3:6] + noise[:, 9:12] * (r.obs_force * 0.02)) * TORQUE_SCALE
        st[:, 19:22] = self.estimate[:, 0:3] * POS_SCALE
        st[:, 22], st[:, 23] = np.sin(self.estimate[:, 3]), np.cos(self.estimate[:, 3])
        st[:, 24] = np.minimum(self.t / self.task.max_steps, 1.0)
        st[:, 25:28] = (st[:, 19:22] - st[:, 0:3]) * (REL_POS_SCALE / POS_SCALE)
        st[:, 28] = (np.mod(self.estimate[:, 3] - yaw + np.pi, 2 * np.pi) - np.pi) * TILT_SCALE
        obs = {"state": st.astype(np.float32), "history": self._history.reshape(n, -1).astype(np.float32)}
        if self.obs_mode == "state+image":
            obs["image"] = self.render()
        return obs

    def render(self, camera: str = "front") -> np.ndarray:
        """(N, h, w, 3) uint8 frames of every env (MUJOCO_GL=egl renders on CPU)."""
        import mujoco

        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.model, self.image_size, self.image_size)
            for flag in (
                mujoco.mjtRndFlag.mjRND_SHADOW,
                mujoco.mjtRndFlag.mjRND_REFLECTION,
                mujoco.mjtRndFlag.mjRND_SKYBOX,
            ):  # a third less software-GL time at 64 px
                self._renderer.scene.flags[flag] = 0
        frames = np.empty((self.num_envs, self.image_size, self.image_size, 3), dtype=np.uint8)
        for i in range(self.num_envs):
            data = self.batch.get_data(i)
            mujoco.mj_kinematics(self.model, data)  # materialised data carries state, not poses
            mujoco.mj_camlight(self.model, data)  # the cameras' poses (without it every camera sat at the origin)
            self._renderer.update_scene(data, camera=camera)
            frames[i] = self._renderer.render()
        return frames

    def true_socket_pose(self) -> np.ndarray:
        """(N, 3) socket (x, y, yaw) in the robot frame, for diagnostics and tests (not an observation)."""
        return self.socket_pose.copy()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


def make_vec_env(
    task_id: str,
    num_envs: int = 1,
    seed: int = 0,
    obs_mode: str = "state",
    image_size: int = 64,
    nthread: int | None = None,
) -> VecAssemblyEnv:
    return VecAssemblyEnv(task_id, num_envs, seed=seed, obs_mode=obs_mode, image_size=image_size, nthread=nthread)
