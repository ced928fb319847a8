"""A lerobot-record dataset turned into accrue's demo layout through a workflow's robot mapping.

lerobot-record stores what the robot reported (`observation.state` named by the robot's float observation
keys) and what it was told (`action` named by its action keys). finetune-base trains on accrue's layout
(accrue.sim.demos): q (the robot's own state keys, or those `state_keys` picks) and the normalised action in
the robot's action space. The mapping that drives the robot live gives both directions: the inverse of its
action map (RobotMapping.normalise, clipped to [-1, 1]) gives the normalised action.

Frames keep lerobot-record's order and fps: frame t is the observation before action t, as in accrue's demos.
A teleoperated demonstration counts as a success, so each episode's last frame is done and successful and
its last SUCCESS_TAIL frames carry reward 1, like the simulator's demos.

For a workflow with obs_mode state+image the robot's camera comes along: accrue's layout holds one camera,
the one the base policy is fed live, the first of the mapping's camera_keys (accrue.robot.bridge), under the
robot's own name for it, `observation.images.<key>`, as lerobot-record stored it. Its frames are written at the shape the robot declares for it (resized when recorded at another size of the
same aspect), as images when it was recorded as images (lossless) and as video when it was recorded as
video. A state workflow's demos stay state-only. The result is built under a hidden sibling and renamed
into place.
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import numpy as np

from accrue.errors import AccrueError
from accrue.robot.demos import check_robot_dataset
from accrue.robot.mapping import RobotMapping, crop_frame, image_feature
from accrue.sim.demos import (
    ACCRUE_META,
    ACCRUE_META_FORMAT,
    ACTION_KEY,
    DONE_KEY,
    REWARD_KEY,
    STATE_KEY,
    SUCCESS_KEY,
    check_out_dir,
    demo_features,
    label_success_tail,
    repo_id_for,
    save_episode,
    staged_dataset,
    write_json_atomic,
)

SOURCE = "lerobot-record"
Camera = tuple[str, tuple[int, int, int]]  # a robot camera key and the (h, w, 3) frame shape it declares


def carried_camera(mapping: RobotMapping, observation_features: dict, obs_mode: str, who: str) -> Camera | None:
    """The camera converted demos carry for a workflow: None with obs_mode state; with state+image the first of
    the bound mapping's camera_keys (the frame the base policy is fed live) and the shape the robot declares."""
    if obs_mode != "state+image":
        return None
    if not mapping.camera_keys:
        raise AccrueError(
            f"{who}: declares no camera (robot.camera_keys), but the workflow's obs_mode state+image needs one"
        )
    key = mapping.camera_keys[0]
    return key, tuple(int(s) for s in observation_features[key])


def mapped_states(observation: np.ndarray, names: list[str], mapping: RobotMapping) -> np.ndarray:
    """(T, len(names)) recorded observation.state -> (T, 29) accrue states: column i is state_keys[i]."""
    _check_width(observation, names, STATE_KEY)
    columns = [names.index(k) for k in mapping.state_keys]
    return np.asarray(observation, dtype=np.float64)[:, columns].astype(np.float32)


def normalised_actions(action: np.ndarray, names: list[str], mapping: RobotMapping) -> tuple[np.ndarray, int]:
    """(T, len(names)) recorded actions -> ((T, 6) normalised deltas in [-1, 1], values that were clipped).

    The inverse of RobotMapping.action: axis j is action_keys[j] in the mapping's action space (a delta over
    its action_limit, or a joint target spread over its action_bounds).
    """
    _check_width(action, names, ACTION_KEY)
    columns = [names.index(k) for k in mapping.action_keys]
    raw = mapping.normalise(np.asarray(action, dtype=np.float64)[:, columns])
    clipped = int(np.count_nonzero(np.abs(raw) > 1.0))
    raw[~np.isfinite(raw)] = np.nan  # an infinite command is a broken frame, not a full-scale one
    return np.clip(raw, -1.0, 1.0).astype(np.float32), clipped


def _check_width(values: np.ndarray, names: list[str], key: str) -> None:
    if np.ndim(values) != 2 or np.shape(values)[1] != len(names):
        raise AccrueError(
            f"recorded {key} has {np.shape(values)[1:] or 'no'} values per frame but names "
            f"{len(names)}: the names cannot be matched to the columns"
        )


def recorded_tasks(root: Path | str) -> list[str]:
    """The task strings lerobot-record stored (its --dataset.single_task), from meta/tasks.parquet."""
    import pandas as pd

    path = Path(root) / "meta" / "tasks.parquet"
    try:
        return [str(t) for t in pd.read_parquet(path).index]
    except Exception as exc:  # noqa: BLE001 - a missing or damaged file is a broken user dataset
        raise AccrueError(f"{path}: unreadable ({type(exc).__name__})") from None


def _read_recorded(root: Path):
    """(dataset, fps, observation.state (N, S), action (N, A), episode_index (N,)) of a local LeRobotDataset v3."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    try:
        dataset = LeRobotDataset(repo_id=f"local/{root.name}", root=root, video_backend="pyav")
        table = dataset.hf_dataset.with_format("numpy")
        columns = table.select_columns([STATE_KEY, ACTION_KEY, "episode_index"])[:]
        states = np.stack(columns[STATE_KEY]).astype(np.float64)
        actions = np.stack(columns[ACTION_KEY]).astype(np.float64)
    except Exception as exc:  # noqa: BLE001 - any load failure is a broken user dataset
        first_line = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise AccrueError(f"cannot read dataset {root}: {first_line}") from None
    return dataset, int(dataset.meta.fps), states, actions, np.asarray(columns["episode_index"])


def recorded_frame(dataset, row: int, key: str, shape: tuple[int, int, int], root: Path) -> np.ndarray:
    """Frame `row` of camera feature `key` as (h, w, 3) uint8 of `shape`, resized when recorded at another size.

    LeRobotDataset gives a frame as float (3, h, w) in [0, 1], decoded from its PNG or video; x 255 and
    rounded, a PNG's frame is its stored bytes again."""
    try:
        chw = np.asarray(dataset[row][key], dtype=np.float32)
    except Exception as exc:  # noqa: BLE001 - a missing or undecodable frame is a broken user dataset
        first_line = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise AccrueError(f"{root}: frame {row} of {key} cannot be decoded: {first_line}") from None
    frame = np.clip(np.rint(np.transpose(chw, (1, 2, 0)) * 255.0), 0, 255).astype(np.uint8)
    if frame.shape[:2] != tuple(shape[:2]):
        from PIL import Image

        frame = np.asarray(Image.fromarray(frame).resize((shape[1], shape[0]), Image.Resampling.BILINEAR))
    return frame


def convert_robot_dataset(
    src: Path | str,
    out_dir: Path | str,
    mapping: RobotMapping,
    robot: str,
    task_id: str,
    instruction: str,
    progress: bool = False,
    camera: Camera | None = None,
) -> dict:
    """Write accrue demos of `task_id` to out_dir from the lerobot-record dataset at src; return its meta.

    `camera` (carried_camera) is the robot camera whose frames become observation.images.<its key>, at its declared shape; None
    writes state-only demos. A dataset whose features do not fit the mapping or lack the camera, or whose
    mapped values are not finite, is a one-line AccrueError and nothing is written.
    """
    src, out_dir = Path(src), Path(out_dir)
    box = dict(mapping.crop).get(camera[0]) if camera is not None else None  # robot.crop of the carried camera
    check = check_robot_dataset(src, replace(mapping, camera_keys=(), crop=()), robot, camera)
    # the keys as lerobot-record wrote them stand for what the robot declares (the camera goes separately)
    mapping = replace(mapping, camera_keys=(), crop=()).bind(
        {n: float for n in check["state_names"]}, {n: float for n in check["action_names"]}, f"{src}"
    )
    recorded_camera = check["camera"]
    image_shape = tuple(camera[1]) if camera is not None else None
    dataset, fps, observation, action, episode_index = _read_recorded(src)
    states = mapped_states(observation, check["state_names"], mapping)
    actions, clipped = normalised_actions(action, check["action_names"], mapping)
    bad = np.flatnonzero(~(np.isfinite(states).all(axis=1) & np.isfinite(actions).all(axis=1)))
    if bad.size:
        raise AccrueError(
            f"{src}: episode {int(episode_index[bad[0]])} has a frame whose mapped state or action "
            f"is not finite ({bad.size} frame(s) in all)"
        )
    episodes = [np.flatnonzero(episode_index == ep) for ep in sorted(set(episode_index.tolist()))]
    episodes = [rows for rows in episodes if rows.size]
    if not episodes:
        raise AccrueError(f"{src}: has no frames to convert")
    check_out_dir(out_dir)

    os.environ.setdefault("SVT_LOG", "1")  # the AV1 encoder prints its whole config per video otherwise
    import datasets
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    use_video = recorded_camera is not None and recorded_camera["dtype"] == "video"
    image_key = image_feature(camera[0]) if camera is not None else None  # the robot's camera, by its name
    features = demo_features(list(mapping.state_keys), image_shape, use_video=use_video, image_key=image_key)
    bars_were_on = not datasets.are_progress_bars_disabled()
    datasets.disable_progress_bars()
    bar = _bar(progress, len(episodes), f"demos {task_id} from {check['robot_type'] or robot}")
    try:
        with staged_dataset(out_dir) as staging:
            ds = LeRobotDataset.create(
                repo_id=repo_id_for(task_id),
                root=staging,
                fps=fps,
                features=features,
                use_videos=any(f["dtype"] == "video" for f in features.values()),
                video_backend="pyav",
            )
            try:
                for n, rows in enumerate(episodes, 1):
                    frames = _episode_frames(rows, states, actions, instruction)
                    if recorded_camera is not None:
                        for frame, r in zip(frames, rows):
                            image = recorded_frame(dataset, int(r), recorded_camera["key"], image_shape, src)
                            # the base policy is fed the region of interest live: it learns from the same
                            frame[image_key] = image if box is None else crop_frame(image, box)
                    save_episode(ds, frames)
                    if bar is not None:
                        bar[0].update(bar[1], completed=n)
            finally:
                ds.finalize()
            meta = {
                "format": ACCRUE_META_FORMAT,
                "source": SOURCE,
                "task_id": task_id,
                "instruction": instruction,
                "recorded_tasks": recorded_tasks(src),
                "robot_type": check["robot_type"],
                "robot": robot,
                "seed": None,
                "quality": None,
                "obs_mode": "state+image" if camera is not None else "state",
                "requested": len(episodes),
                "episodes": len(episodes),
                "frames": int(sum(r.size for r in episodes)),
                # a teleoperated demonstration is taken as a success: the operator kept only what worked
                "attempts": len(episodes),
                "successes": len(episodes),
                "only_successful": True,
                "fps": fps,
                "clipped_action_values": clipped,
                # the recorded camera feature and its frame shape there ((h, w, 3); the demos hold the robot's)
                "recorded_camera": (
                    {"key": recorded_camera["key"], "shape": list(recorded_camera["shape"])}
                    if recorded_camera
                    else None
                ),
                "state_names": list(mapping.state_keys),
                "mapping": {
                    "state_keys": list(mapping.state_keys),
                    "camera_keys": [camera[0]] if camera is not None else [],
                    "action_keys": list(mapping.action_keys),
                    "action_mode": mapping.action_mode,
                    "action_limits": list(mapping.action_limits) if mapping.action_limits else None,
                    "action_bounds": [list(b) for b in mapping.action_bounds] if mapping.action_bounds else None,
                },
            }
            write_json_atomic(staging / ACCRUE_META, meta)
    finally:
        if bar is not None:
            bar[0].stop()
        if bars_were_on:
            datasets.enable_progress_bars()
    return meta


def _episode_frames(rows: np.ndarray, states: np.ndarray, actions: np.ndarray, instruction: str) -> list[dict]:
    """accrue frames of one recorded episode (its frame indices `rows`): a success, the last frame done."""
    last = rows.size - 1
    frames = [
        {
            STATE_KEY: states[r],
            ACTION_KEY: actions[r],
            REWARD_KEY: np.zeros(1, dtype=np.float32),
            DONE_KEY: np.array([i == last]),
            SUCCESS_KEY: np.array([i == last]),
            "task": instruction,
        }
        for i, r in enumerate(rows)
    ]
    label_success_tail(frames)
    return frames


def _bar(enabled: bool, total: int, label: str):
    """(rich Progress, task id) on stderr, or None."""
    if not enabled:
        return None
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    bar = Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=Console(stderr=True),
    )
    task = bar.add_task(label, total=total)
    bar.start()
    return bar, task
