"""MuJoCo contact-rich assembly tasks (NIST-board-like and AutoMate-like plug/socket families).

Light imports only here; mujoco and pxr load when an env, expert or USD part is first used.
"""

import os

# MuJoCo reads MUJOCO_GL at import; EGL renders headless (Mesa on CPU). A user's choice wins.
os.environ.setdefault("MUJOCO_GL", "egl")

from accrue.sim.observation import ACTION_DIM, ACTION_NAMES, STATE_DIM, STATE_NAMES
from accrue.sim.tasks import TaskSpec, get_task, list_tasks


def make_vec_env(task_id, num_envs=1, seed=0, obs_mode="state", image_size=64, nthread=None):
    from accrue.sim.vec_env import make_vec_env as _make

    return _make(task_id, num_envs, seed=seed, obs_mode=obs_mode, image_size=image_size, nthread=nthread)


def make_expert(task_id, quality=1.0, seed=0, **kw):
    from accrue.sim.expert import make_expert as _make

    return _make(task_id, quality=quality, seed=seed, **kw)


def expert_success_rate(task_id, episodes, seed=0, quality=1.0, **kw):
    from accrue.sim.expert import expert_success_rate as _rate

    return _rate(task_id, episodes, seed=seed, quality=quality, **kw)


def register_usd_task(*args, **kw):
    from accrue.sim.usd_tasks import register_usd_task as _register

    return _register(*args, **kw)


def load_task_yaml(path):
    from accrue.sim.usd_tasks import load_task_yaml as _load

    return _load(path)


__all__ = [
    "ACTION_DIM",
    "ACTION_NAMES",
    "STATE_DIM",
    "STATE_NAMES",
    "TaskSpec",
    "get_task",
    "list_tasks",
    "make_vec_env",
    "make_expert",
    "expert_success_rate",
    "register_usd_task",
    "load_task_yaml",
]
