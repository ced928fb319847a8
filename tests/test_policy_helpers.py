"""Small synthetic LeRobotDatasets for the policy tests (no test functions here).

A synthetic task: the expert action is a fixed function of the state that differs per task, so a
policy must read both the state and the instruction to imitate it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

STATE_DIM = 4
ACTION_DIM = 6


def expert_action(state: np.ndarray, task_sign: float) -> np.ndarray:
    base = np.concatenate([state[:3], -state[:3]])
    return np.clip(task_sign * np.tanh(base), -1.0, 1.0).astype(np.float32)


def write_synthetic_demos(
    root: Path,
    instruction: str,
    task_sign: float,
    episodes: int = 4,
    length: int = 12,
    seed: int = 0,
    extra_features: dict | None = None,
    image_hw: tuple[int, int] | None = None,
) -> Path:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    features = {
        "observation.state": {"dtype": "float32", "shape": (STATE_DIM,), "names": None},
        "action": {"dtype": "float32", "shape": (ACTION_DIM,), "names": None},
        **(extra_features or {}),
    }
    if image_hw:
        features["observation.images.wrist"] = {
            "dtype": "image",
            "shape": (*image_hw, 3),
            "names": ["height", "width", "channels"],
        }
    ds = LeRobotDataset.create(repo_id="local/synthetic", root=root, fps=10, features=features, use_videos=False)
    rng = np.random.default_rng(seed)
    for ep in range(episodes):
        state = rng.uniform(-1, 1, STATE_DIM).astype(np.float32)
        for t in range(length):
            frame = {
                "observation.state": state,
                "action": expert_action(state, task_sign),
                "task": instruction,
            }
            for key, spec in (extra_features or {}).items():
                frame[key] = np.full(spec["shape"], ep, np.float32)
            if image_hw:
                frame["observation.images.wrist"] = np.full((*image_hw, 3), (ep * 40 + t) % 255, np.uint8)
            ds.add_frame(frame)
            state = np.clip(state + 0.1 * expert_action(state, task_sign)[:STATE_DIM], -1, 1).astype(np.float32)
        ds.save_episode()
    ds.finalize()
    return root
