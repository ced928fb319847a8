"""A Gymnasium single-environment view of one task (the batch of one underneath)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from accrue.sim.observation import ACTION_DIM, STATE_DIM
from accrue.sim.vec_env import VecAssemblyEnv


class AssemblyEnv(gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}

    def __init__(
        self,
        task_id: str = "nist/round_peg",
        obs_mode: str = "state",
        image_size: int = 64,
        render_mode: str | None = None,
        seed: int = 0,
    ):
        self._env = VecAssemblyEnv(task_id, 1, seed=seed, obs_mode=obs_mode, image_size=image_size, nthread=1)
        self.task, self.render_mode = self._env.task, render_mode
        self.metadata = {**self.metadata, "render_fps": self.task.control_hz}
        self.action_space = gym.spaces.Box(-1.0, 1.0, (ACTION_DIM,), np.float32)
        state_space = gym.spaces.Box(-np.inf, np.inf, (STATE_DIM,), np.float32)
        if obs_mode == "state":
            self.observation_space = state_space
        else:
            img = gym.spaces.Box(0, 255, (image_size, image_size, 3), np.uint8)
            self.observation_space = gym.spaces.Dict({"state": state_space, "image": img})

    def _unbatch(self, obs: dict):
        if self._env.obs_mode == "state":
            return obs["state"][0]
        return {k: obs[k][0] for k in ("state", "image")}  # the spaces declared above (no history)

    def reset(self, *, seed: int | None = None, options=None):
        super().reset(seed=seed)
        if seed is not None:  # a new seed restarts the episode stream
            self._env.seed, self._env.episode[:] = int(seed), -1
        return self._unbatch(self._env.reset()), {}

    def step(self, action):
        res = self._env.step(np.asarray(action, dtype=np.float32)[None])
        info = {"success": bool(res.success[0])}
        return (self._unbatch(res.obs), float(res.rewards[0, 0]), bool(res.terminated[0]), bool(res.truncated[0]), info)

    def render(self):
        return self._env.render()[0]

    def close(self):
        self._env.close()


def register_gym_ids() -> None:
    """Register every task as "accrue/<family>-<name>-v0" (idempotent)."""
    from accrue.sim.tasks import list_tasks

    for tid in list_tasks():
        gid = "accrue/" + tid.replace("/", "-") + "-v0"
        if gid not in gym.registry:
            gym.register(gid, entry_point="accrue.sim.gym_env:AssemblyEnv", kwargs={"task_id": tid})
