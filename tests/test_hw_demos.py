"""`accrue add DIR --kind demos --workflow WF`: a dataset written by lerobot's own recorder (LeRobotDataset
with hw_to_dataset_features of a robot's features, as lerobot-record writes it) is accepted when its
features fit the workflow's robot mapping and refused in one line when it comes from another robot."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hw_workflow import write_hw_workflow

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow      # lerobot writes the datasets: its import alone is ~30 s on 2 busy cores


def record(root: Path, robot_type: str, observation: dict, action: dict) -> Path:
    """One short episode written the way lerobot-record writes it."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.datasets.utils import build_dataset_frame, hw_to_dataset_features

    features = {**hw_to_dataset_features(observation, "observation", use_video=False),
                **hw_to_dataset_features(action, "action", use_video=False)}
    ds = LeRobotDataset.create(repo_id=f"local/{robot_type}", fps=10, features=features, root=root,
                               robot_type=robot_type, use_videos=False)
    for _ in range(3):
        frame = {**build_dataset_frame(ds.features, {k: 0.1 for k in observation}, prefix="observation"),
                 **build_dataset_frame(ds.features, {k: 0.0 for k in action}, prefix="action"), "task": "insert"}
        ds.add_frame(frame)
    ds.save_episode()
    ds.finalize()
    return root


def accrue(store: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "ACCRUE_STORE": str(store)}
    return subprocess.run([sys.executable, "-m", "cli.main", *args], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=120)


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    from accrue.robot.sim_robot import AccrueSim, AccrueSimConfig

    root = tmp_path_factory.mktemp("demos")
    sim = AccrueSim(AccrueSimConfig(calibration_dir=root / "calib"))
    ours = record(root / "sim", "accrue_sim", sim.observation_features, sim.action_features)
    joints = {f"{j}.pos": float for j in ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex",
                                          "wrist_roll", "gripper")}
    theirs = record(root / "so101", "so101_follower", joints, joints)
    return root, ours, theirs


def test_dataset_from_another_robot_is_refused_in_one_line(datasets):
    root, ours, theirs = datasets
    wf = write_hw_workflow(root / "hw.yaml", root / "calib")
    assert accrue(root / "store", "init").returncode == 0
    bad = accrue(root / "store", "add", str(theirs), "--kind", "demos", "--workflow", str(wf))
    assert bad.returncode == 2, bad.stderr
    lines = bad.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "so101_follower" in lines[0]
    assert "robot.state_keys: ee_x_cm" in lines[0] and "Traceback" not in bad.stderr
    good = accrue(root / "store", "add", str(ours), "--kind", "demos", "--workflow", str(wf))
    assert good.returncode == 0, good.stderr
    assert len(good.stdout.strip()) == 64                     # the artifact id


def test_robot_dataset_check_reads_only_metadata(datasets):
    from accrue.errors import AccrueError
    from accrue.robot.demos import check_robot_dataset
    from accrue.robot.mapping import RobotMapping

    root, ours, theirs = datasets
    info = check_robot_dataset(ours, RobotMapping(), "accrue_sim")
    assert info["episodes"] == 1 and info["frames"] == 3 and info["robot_type"] == "accrue_sim"
    with pytest.raises(AccrueError, match="not a LeRobot dataset"):
        check_robot_dataset(root, RobotMapping(), "accrue_sim")
    assert np.isfinite(info["fps"])
