"""Measure a base policy's success on a sim task by executing its reference chunks open-loop."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from accrue.policy.base_policy import BasePolicy


@dataclass
class SuccessEstimate:
    task_id: str
    episodes: int
    successes: int
    mean_steps: float

    @property
    def rate(self) -> float:
        return self.successes / self.episodes if self.episodes else 0.0


def evaluate_success(
    policy: BasePolicy,
    task_id: str,
    episodes: int = 50,
    horizon: int | None = None,
    num_envs: int = 10,
    seed: int = 10_000,
) -> SuccessEstimate:
    """Run `episodes` episodes in rounds of num_envs parallel envs; re-plan every `horizon` steps.

    The env's episode randomisation is seeded by (seed, env, episode), so the same call sees the
    same initial conditions; use a seed the demos were not written with.
    """
    from accrue.sim import get_task, make_vec_env

    instruction = get_task(task_id).instruction
    num_envs = max(1, min(num_envs, episodes))
    env = make_vec_env(task_id, num_envs=num_envs, seed=seed, obs_mode="state+image" if policy.image_keys else "state")
    successes, finished, steps_total = 0, 0, 0
    while finished < episodes:
        obs = env.reset()
        done = np.zeros(num_envs, dtype=bool)
        success = np.zeros(num_envs, dtype=bool)
        steps = np.zeros(num_envs, dtype=np.int64)
        while not done.all():
            chunk = policy.reference_chunk(obs, instruction, horizon)
            result = env.step_chunk(chunk, gamma=1.0)
            steps += np.where(done, 0, result.steps)
            success |= result.success & ~done
            done |= result.done
            obs = result.obs
        take = min(num_envs, episodes - finished)
        successes += int(success[:take].sum())
        steps_total += int(steps[:take].sum())
        finished += take
    return SuccessEstimate(task_id, episodes, successes, steps_total / episodes)
