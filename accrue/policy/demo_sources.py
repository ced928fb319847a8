"""Open the demonstration datasets of tasks 1..k and check they can be trained on together."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from accrue.errors import AccrueError

STATE_KEY = "observation.state"
ACTION_KEY = "action"
IMAGE_PREFIX = "observation.images."


@dataclass
class DemoSource:
    """One task's demonstrations: per-episode arrays read once from a LeRobotDataset."""

    root: Path
    fps: int
    instruction_of_episode: list[str]
    states: list[np.ndarray]  # per episode (T, D) float32
    actions: list[np.ndarray]  # per episode (T, d) float32
    image_keys: list[str]
    dataset: object  # the open LeRobotDataset, for decoding images on demand
    frame_ranges: list[tuple[int, int]]  # per episode [from, to) absolute frame indices

    @property
    def num_episodes(self) -> int:
        return len(self.states)


def _feature_shape(features: dict, key: str, root: Path) -> tuple[int, ...]:
    if key not in features:
        raise AccrueError(f"dataset {root} has no feature '{key}' (has: {', '.join(sorted(features))})")
    shape = tuple(features[key]["shape"])
    if len(shape) != 1 or features[key]["dtype"] not in ("float32", "float64"):
        raise AccrueError(
            f"dataset {root}: feature '{key}' must be a 1-D float vector, got dtype "
            f"{features[key]['dtype']} shape {list(shape)}"
        )
    return shape


def open_demo_source(root: Path) -> DemoSource:
    """Read a local LeRobotDataset (v3) without touching the network."""
    root = Path(root)
    if not (root / "meta" / "info.json").is_file():
        raise AccrueError(f"{root} is not a LeRobotDataset (missing meta/info.json)")
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    try:
        dataset = LeRobotDataset(repo_id=f"local/{root.name}", root=root, video_backend="pyav")
    except Exception as exc:  # noqa: BLE001 - any load failure is a broken user dataset
        first_line = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise AccrueError(f"cannot read dataset {root}: {first_line}") from exc
    features = dataset.meta.features
    _feature_shape(features, STATE_KEY, root)
    _feature_shape(features, ACTION_KEY, root)
    if dataset.num_episodes == 0:
        raise AccrueError(f"dataset {root} has no episodes")

    table = dataset.hf_dataset.with_format("numpy")
    columns = table.select_columns([STATE_KEY, ACTION_KEY, "episode_index", "task_index", "index"])[:]
    episode_index = np.asarray(columns["episode_index"])
    tasks = dataset.meta.tasks  # DataFrame indexed by task string
    task_of_index = {int(i): str(t) for t, i in zip(tasks.index, tasks["task_index"])}
    state_all = np.asarray(np.stack(columns[STATE_KEY]), dtype=np.float32)
    action_all = np.asarray(np.stack(columns[ACTION_KEY]), dtype=np.float32)
    task_all = np.asarray(columns["task_index"])

    states, actions, instructions, ranges = [], [], [], []
    for ep in sorted(set(episode_index.tolist())):
        rows = np.flatnonzero(episode_index == ep)
        states.append(state_all[rows])
        actions.append(action_all[rows])
        instructions.append(task_of_index[int(task_all[rows[0]])])
        ranges.append((int(rows[0]), int(rows[-1]) + 1))
    image_keys = sorted(k for k in features if k.startswith(IMAGE_PREFIX))
    return DemoSource(root, int(dataset.meta.fps), instructions, states, actions, image_keys, dataset, ranges)


def check_compatible(sources: list[DemoSource]) -> None:
    """All tasks must share fps, state and action sizes, or one policy cannot train on them."""
    first = sources[0]
    for src in sources[1:]:
        for what, a, b in (
            ("fps", first.fps, src.fps),
            ("observation.state size", first.states[0].shape[1], src.states[0].shape[1]),
            ("action size", first.actions[0].shape[1], src.actions[0].shape[1]),
        ):
            if a != b:
                raise AccrueError(f"dataset {src.root}: {what} {b} differs from {first.root} ({a})")
