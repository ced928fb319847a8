"""Demonstrations recorded with lerobot's own tooling (`lerobot-record`) checked against a robot mapping.

A lerobot-record dataset of robot R has `observation.state` named by R's float observation keys and
`action` named by R's action keys (lerobot's hw_to_dataset_features). It fits a workflow when those
names include every key the workflow's robot mapping reads (`robot.state_keys`) and writes
(`robot.action_keys`), and, for an image workflow, the camera its base policy is fed: R's camera `key` is
recorded as `observation.images.<key>` (an image or video feature of shape (h, w, 3)). Only
meta/info.json is read: no lerobot import, no video decoding.
"""

from __future__ import annotations

import json
from pathlib import Path

from accrue.errors import AccrueError
from accrue.robot.mapping import RobotMapping

LEROBOT_FORMAT = "v3.0"
CAMERA_PREFIX = "observation.images."  # lerobot-record's name for a camera's frames (hw_to_dataset_features)
ASPECT_TOLERANCE = 0.01  # a recorded frame is resized to the robot's declared one only at the same aspect


def _names(features: dict, key: str, root: Path) -> list[str]:
    feature = features.get(key)
    if not isinstance(feature, dict):
        raise AccrueError(
            f"{root}: not demonstrations for this robot: the dataset has no {key!r} feature "
            f"(it has {', '.join(sorted(features)[:6])})"
        )
    names = feature.get("names")
    if isinstance(names, dict):  # older writers: {"motors": [...]}
        names = next(iter(names.values()), [])
    if not isinstance(names, list):
        raise AccrueError(f"{root}: feature {key!r} has no list of names to match against the robot mapping")
    return [str(n) for n in names]


def _camera(features: dict, camera: tuple[str, tuple[int, int, int]], root: Path) -> dict:
    """{key, shape, dtype} of the recorded feature of robot camera camera[0], whose declared frame shape is
    camera[1]; one line when the dataset lacks it or its frames cannot become the declared ones."""
    name, declared = camera
    key = CAMERA_PREFIX + name
    feature = features.get(key)
    if not isinstance(feature, dict) or feature.get("dtype") not in ("image", "video"):
        recorded = [k for k, f in features.items() if isinstance(f, dict) and f.get("dtype") in ("image", "video")]
        raise AccrueError(
            f"{root}: has no camera {name!r} ({key}), which the workflow's image policy is fed "
            f"(the dataset's cameras: {', '.join(recorded) or 'none'})"
        )
    shape = [int(s) for s in feature.get("shape") or []]
    if len(shape) != 3 or shape[2] != 3:
        raise AccrueError(
            f"{root}: camera {name!r} was recorded as {shape}, not RGB frames (h, w, 3) like the robot's "
            f"{list(declared)}"
        )
    (h, w), (dh, dw) = shape[:2], declared[:2]
    if abs(h * dw - dh * w) > ASPECT_TOLERANCE * dh * w:
        raise AccrueError(
            f"{root}: camera {name!r} was recorded at {h}x{w}, which cannot be resized to the robot's "
            f"{dh}x{dw} without distorting it"
        )
    return {"key": key, "shape": tuple(shape), "dtype": feature["dtype"]}


def check_robot_dataset(
    root: Path | str, mapping: RobotMapping, robot: str, camera: tuple[str, tuple[int, int, int]] | None = None
) -> dict:
    """{episodes, frames, fps, robot_type, state_names, action_names, camera}; AccrueError (one line) when it
    does not fit the mapping. `camera` is (robot camera key, declared (h, w, 3)) for an image workflow: the
    dataset must hold that camera's RGB frames at the same aspect (`camera` in the result is then its
    {key, shape, dtype}, else None)."""
    root = Path(root)
    info_path = root / "meta" / "info.json"
    if not info_path.is_file():
        raise AccrueError(f"{root}: not a LeRobot dataset (no meta/info.json)")
    try:
        info = json.loads(info_path.read_text())
        features = dict(info["features"])
    except (ValueError, KeyError, TypeError) as exc:
        raise AccrueError(f"{info_path}: unreadable ({type(exc).__name__})") from None
    if str(info.get("codebase_version")) != LEROBOT_FORMAT:
        raise AccrueError(f"{root}: LeRobotDataset {info.get('codebase_version')}; accrue reads {LEROBOT_FORMAT}")
    recorded = {}
    for key, wanted, what in (
        ("observation.state", mapping.state_keys, "robot.state_keys"),
        ("action", mapping.action_keys, "robot.action_keys"),
    ):
        names = recorded[key] = _names(features, key, root)
        missing = [k for k in (wanted or ()) if k not in names]  # None: the robot's keys as recorded
        if missing:
            raise AccrueError(
                f"{root}: recorded on robot {info.get('robot_type') or '?'} with {key} "
                f"({len(names)} values: {', '.join(names[:4])}{', ...' if len(names) > 4 else ''}), "
                f"which lacks {len(missing)} key(s) {robot}'s mapping needs ({what}: {missing[0]}, ...)"
            )
    return {
        "episodes": int(info.get("total_episodes", 0)),
        "frames": int(info.get("total_frames", 0)),
        "fps": info.get("fps"),
        "robot_type": info.get("robot_type"),
        "state_names": recorded["observation.state"],
        "action_names": recorded["action"],
        "camera": _camera(features, camera, root) if camera is not None else None,
    }
