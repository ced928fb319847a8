"""Demonstrations recorded with lerobot's own tooling (`lerobot-record`) checked against a robot mapping.

A lerobot-record dataset of robot R has `observation.state` named by R's float observation keys and
`action` named by R's action keys (lerobot's hw_to_dataset_features). It fits a workflow when those
names include every key the workflow's robot mapping reads (`robot.state_keys`) and writes
(`robot.action_keys`). Only meta/info.json is read: no lerobot import, no video decoding.
"""

from __future__ import annotations

import json
from pathlib import Path

from accrue.errors import AccrueError
from accrue.robot.mapping import RobotMapping

LEROBOT_FORMAT = "v3.0"


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


def check_robot_dataset(root: Path | str, mapping: RobotMapping, robot: str) -> dict:
    """{episodes, frames, fps, robot_type, state_names, action_names}; AccrueError (one line) when it does not
    fit the mapping."""
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
    }
