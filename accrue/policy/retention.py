"""Which demonstrations of earlier tasks are kept when fine-tuning on D^1..D^k (paper Table VI).

Rule: the current task (the last dataset) keeps every episode. An earlier task with n episodes keeps
ceil(fraction * n) of them (at least one), drawn without replacement by a generator seeded with
(seed, task position), then sorted. Task i therefore keeps the same episodes at every later stage
for a given seed, and changing the seed draws a different subset.
"""

from __future__ import annotations

import math

import numpy as np


def kept_episode_count(num_episodes: int, fraction: float) -> int:
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"retention fraction must be in (0, 1], got {fraction}")
    return max(1, min(num_episodes, math.ceil(fraction * num_episodes - 1e-9)))


def retained_episodes(num_episodes: int, fraction: float, seed: int, task_position: int, is_current: bool) -> list[int]:
    """Sorted episode indices (0-based, within the task's dataset) to train on."""
    if is_current or fraction >= 1.0:
        return list(range(num_episodes))
    count = kept_episode_count(num_episodes, fraction)
    rng = np.random.default_rng([int(seed), int(task_position)])
    return sorted(int(i) for i in rng.choice(num_episodes, size=count, replace=False))
