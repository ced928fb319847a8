"""Actions in the robot's own units: with `action_mode: joint` and no `robot.action_bounds`, each action key's
[lo, hi] is read from the robot's motor calibration the way lerobot 0.6 normalises it (a bus's motors, their
MotorNormMode and calibrated range_min..range_max), for one arm or a bimanual pair; a robot that has no
calibrated range for a key is refused in one line naming the keys to set."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from lerobot.motors import Motor, MotorCalibration, MotorNormMode
from lerobot.motors.feetech.tables import MODEL_RESOLUTION
from lerobot.motors.motors_bus import MotorsBus

from accrue.errors import AccrueError
from accrue.robot.mapping import RobotMapping, calibrated_bounds

ROOT = Path(__file__).resolve().parents[1]
SO101_MOTORS = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper")


def so101_bus(body_mode: MotorNormMode, calibrated: bool = True):
    """An SO-101 follower's Feetech bus as lerobot 0.6 builds it (so_follower.py: five body motors in
    `body_mode`, the gripper in range_0_100), its calibration file loaded; no serial port behind it."""
    motors = {name: Motor(i, "sts3215", body_mode) for i, name in enumerate(SO101_MOTORS, 1)}
    motors["gripper"] = Motor(6, "sts3215", MotorNormMode.RANGE_0_100)
    ranges = [(740, 3410), (820, 3200), (880, 3080), (860, 3180), (120, 3990), (2030, 3500)]
    calibration = (
        {n: MotorCalibration(i, 0, 0, lo, hi) for i, (n, (lo, hi)) in enumerate(zip(SO101_MOTORS, ranges), 1)}
        if calibrated
        else {}
    )
    return SimpleNamespace(
        motors=motors,
        calibration=calibration,
        model_resolution_table=dict(MODEL_RESOLUTION),
        apply_drive_mode=False,
        _id_to_name=lambda i: SO101_MOTORS[i - 1],
        _id_to_model=lambda i: "sts3215",
    )


def features(prefix: str = "") -> tuple[dict, dict]:
    keys = {f"{prefix}{m}.pos": float for m in SO101_MOTORS}
    return dict(keys), dict(keys)


@pytest.mark.parametrize("mode", [MotorNormMode.DEGREES, MotorNormMode.RANGE_M100_100])
def test_joint_bounds_are_what_lerobot_reads_at_the_calibrated_ends(mode):
    bus = so101_bus(mode)
    robot = SimpleNamespace(bus=bus, name="so101_follower")
    m = RobotMapping(action_mode="joint").bind(*features(), "robot so101_follower", robot=robot)
    # lerobot's own normalisation of each motor's raw calibrated ends is the range the arm reads and takes
    ids = {i: bus.calibration[n] for i, n in enumerate(SO101_MOTORS, 1)}
    lo = MotorsBus._normalize(bus, {i: c.range_min for i, c in ids.items()})
    hi = MotorsBus._normalize(bus, {i: c.range_max for i, c in ids.items()})
    assert np.array(m.action_bounds) == pytest.approx(np.array([(lo[i], hi[i]) for i in ids]))
    if mode is MotorNormMode.DEGREES:  # about the middle of the range, in degrees
        assert m.action_bounds[0] == pytest.approx((-(3410 - 740) / 2 * 360 / 4095, (3410 - 740) / 2 * 360 / 4095))
    else:
        assert m.action_bounds[:5] == ((-100.0, 100.0),) * 5
    assert m.action_bounds[5] == (0.0, 100.0)  # the gripper's range_0_100
    sent = m.action(np.ones(6))
    assert list(sent.values()) == pytest.approx([hi[i] for i in ids])  # a = +1 is the calibrated top


def test_a_bimanual_pair_reads_each_arms_bus_under_its_prefix():
    """lerobot's bi_so_follower: `left_arm`/`right_arm` followers, their keys `left_<motor>.pos`."""
    robot = SimpleNamespace(
        left_arm=SimpleNamespace(bus=so101_bus(MotorNormMode.RANGE_M100_100)),
        right_arm=SimpleNamespace(bus=so101_bus(MotorNormMode.DEGREES)),
    )
    left, right = features("left_"), features("right_")
    m = RobotMapping(action_mode="joint").bind({**left[0], **right[0]}, {**left[1], **right[1]}, "bi", robot=robot)
    assert m.action_dim == 12
    assert m.action_bounds[0] == (-100.0, 100.0) and m.action_bounds[6][0] == pytest.approx(
        -(3410 - 740) / 2 * 360 / 4095
    )
    assert m.action_bounds[5] == m.action_bounds[11] == (0.0, 100.0)


def test_without_a_calibration_the_refusal_names_the_keys_to_set():
    uncalibrated = SimpleNamespace(bus=so101_bus(MotorNormMode.DEGREES, calibrated=False))
    with pytest.raises(AccrueError) as info:
        RobotMapping(action_mode="joint").bind(*features(), "robot so101_follower", robot=uncalibrated)
    line = str(info.value)
    assert line.startswith("robot.action_bounds: action_mode joint needs one [lo, hi] per action key")
    assert "gives no calibrated range for shoulder_pan.pos, " in line and "set robot.action_bounds for" in line
    assert "\n" not in line
    # a key the calibration does not cover is named alone; the workflow's bounds always win
    bus = so101_bus(MotorNormMode.DEGREES)
    del bus.calibration["gripper"]
    assert calibrated_bounds(SimpleNamespace(bus=bus), list(features()[1]))[1] == ["gripper.pos"]
    given = ((-1.0, 1.0),) * 6
    m = RobotMapping(action_mode="joint", action_bounds=given).bind(*features(), "r", robot=SimpleNamespace(bus=bus))
    assert m.action_bounds == given
    assert calibrated_bounds(None, ["x.pos"]) == (None, ["x.pos"])


def test_a_robot_without_calibration_is_refused_before_any_step(tmp_path):
    """accrue_sim in joint mode declares no motor bus: `accrue stage run` says which keys to set, exit 2."""
    from robot_workflow import write_hw_workflow

    policy = tmp_path / "policy"
    policy.mkdir()
    config = {
        "type": "act",
        "input_features": {"observation.state": {"type": "STATE", "shape": [35]}},
        "output_features": {"action": {"type": "ACTION", "shape": [6]}},
    }
    (policy / "config.json").write_text(json.dumps(config))
    wf = write_hw_workflow(tmp_path / "hw.yaml", tmp_path / "calib")
    text = wf.read_text().replace('base_policy: {init: "scripted-reference:1.0"}', f"base_policy: {{init: {policy}}}")
    text = text.replace("config: {calibration_dir:", "config: {action_mode: joint, calibration_dir:")
    wf.write_text(text + "  action_mode: joint\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": "egl", "HF_HUB_OFFLINE": "1", "RERUN": "off"}
    run = lambda *a: subprocess.run(  # noqa: E731
        [sys.executable, "-m", "cli.main", *a], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300
    )
    assert run("init").returncode == 0
    proc = run("stage", "run", str(wf), "--stage", "1")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert len(proc.stderr.strip().splitlines()) == 1
    assert "robot.action_bounds: action_mode joint needs one [lo, hi] per action key" in proc.stderr
    assert "robot.type accrue_sim gives no calibrated range for x.pos, y.pos" in proc.stderr  # the preflight
    assert "finetune-base" not in proc.stdout + proc.stderr
