"""Helpers the step bodies share: JSON files, determinism, the base policy's reference function, envs.

Heavy libraries (torch, mujoco, lerobot) are imported inside the functions: `stages.plan` imports
the step definitions, and `accrue --help` must stay fast.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from stages.errors import StageError

TORCH_THREADS = 1  # fixed, so that a workflow run is reproducible from its seed on CPU


def write_json(path: Path, data: Any) -> Path:
    """Canonical JSON (sorted keys): identical data gives identical bytes, hence identical content ids."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n", encoding="utf-8")
    return path


def read_json(path: Path) -> Any:
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise StageError(f"{path.parent.name}: expected {path.name} in this artifact; it is missing") from None


def deterministic(seed: int) -> None:
    """Fixed torch threads, deterministic kernels and seeded global RNGs (CPU runs repeat bit for bit)."""
    import numpy as np
    import torch

    torch.set_num_threads(TORCH_THREADS)
    torch.use_deterministic_algorithms(True, warn_only=True)
    torch.manual_seed(seed)
    np.random.seed(seed % 2**32)


def load_base_policy(path: Path, seed: int):
    import contextlib
    import sys

    from accrue.policy import BasePolicy
    from accrue.scripted_reference import ScriptedReference

    scripted = Path(path) / "scripted_reference.json"
    if scripted.is_file():  # the scripted stand-in (accrue.scripted_reference), not a lerobot checkpoint
        return ScriptedReference(read_json(scripted)["known_bias"])
    with contextlib.redirect_stdout(sys.stderr):  # lerobot prints while loading; stdout may be --json
        return BasePolicy.load(path, device="cpu", seed=seed)


def reference_fn(policy, task_id: str, horizon: int):
    """ã = π_base(obs, ℓ): the base policy's chunk for a batch of observations of task_id."""
    from accrue.sim import get_task

    instruction = get_task(task_id).instruction
    return lambda obs: policy.reference_chunk(obs, instruction, horizon)


def per_task_features(config: dict, task_ids: list[str]) -> dict:
    """task id -> its learner state s(obs) (accrue.learner_inputs), from a step's config."""
    from accrue.learner_inputs import per_task_features as features

    return features(
        config["encoder"],
        config.get("task_features", 0),
        task_ids,
        history=config.get("history", 0),
        descriptor=config.get("task_descriptor", "none"),
    )


def make_env(task_id: str, num_envs: int, seed: int, obs_mode: str):
    from accrue.sim import make_vec_env

    return make_vec_env(task_id, num_envs=num_envs, seed=seed, obs_mode=obs_mode)


def learner_config(settings: dict):
    from accrue.learner import LearnerConfig

    return LearnerConfig.from_dict(dict(settings))


def copy_tree(src: Path, dst: Path) -> None:
    """Copy a (read-only, materialised) artifact directory into a writable output directory."""
    import shutil

    shutil.copytree(src, dst, dirs_exist_ok=True)
    for root, dirs, files in os.walk(dst):
        for name in dirs + files:
            p = Path(root) / name
            p.chmod(p.stat().st_mode | 0o200)
    Path(dst).chmod(Path(dst).stat().st_mode | 0o200)


def took_text(seconds: float) -> str:
    """A duration as a person reads it: 4.2 s, 3 min 05 s, 2 h 07 min."""
    if seconds < 60:
        return f"{seconds:.1f} s"
    minutes, secs = divmod(round(seconds), 60)
    return f"{minutes} min {secs:02d} s" if minutes < 60 else f"{minutes // 60} h {minutes % 60:02d} min"


class Progress:
    """The progress line of a long step: `name: step 4/10 (2.1 steps/s, 3.0 s left)`, printed when a fifth
    of the work more is done and once at the end (a report of the same count again prints nothing)."""

    def __init__(self, print_line, name: str, unit: str = "step", parts: int = 5, base: int = 0):
        import time

        self.print_line, self.name, self.unit, self.parts = print_line, name, unit, parts
        self.started, self.shown, self.base = time.monotonic(), base, base  # base: done before (a resumed step)

    def __call__(self, done: int, total: int) -> None:
        import time

        if done <= self.shown or (done - self.shown < max(1, total // self.parts) and done < total):
            return
        self.shown = done
        elapsed = max(time.monotonic() - self.started, 1e-9)
        rate = max(done - self.base, 1e-9) / elapsed
        tail = "done" if done >= total else f"{took_text((total - done) / rate)} left"
        self.print_line(f"{self.name}: {self.unit} {done}/{total} ({rate:.3g} {self.unit}s/s, {tail})")
