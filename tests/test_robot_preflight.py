"""A robot workflow is checked before any step runs (stages.steps.robot_preflight): the robot's type,
config fields, state/action/camera keys, the base policy's inputs against its cameras and readings and
obs_mode, and the learner's address and token - each a one-line error naming the workflow key, found in
seconds, before finetune-base (which can take hours) and before anything moves."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from robot_workflow import write_hw_workflow

from stages.errors import StageError

ROOT = Path(__file__).resolve().parents[1]


def accrue(cwd: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": "egl", "HF_HUB_OFFLINE": "1", "RERUN": "off"}
    return subprocess.run(
        [sys.executable, "-m", "cli.main", *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=600
    )


def workflow(tmp_path: Path, edit=None, **robot) -> Path:
    """tests/robot_workflow's workflow (accrue_sim, the scripted base policy) with robot.* keys set or edited."""
    import yaml

    path = write_hw_workflow(tmp_path / "hw.yaml", tmp_path / "calib")
    spec = yaml.safe_load(path.read_text())
    spec["robot"].update(robot)
    if edit is not None:
        edit(spec)
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path


@pytest.fixture
def store(tmp_path):
    from artifacts.store import Store

    return Store.init(tmp_path / ".accrue")[0]


def check(path: Path, store):
    from stages.steps.robot_preflight import preflight
    from stages.workflow import load_workflow

    return preflight(load_workflow(path), str(path), store)


def image_checkpoint(path: Path, state_dim: int = 6) -> Path:
    """A lerobot checkpoint's files as the preflight reads them: config.json taking a camera and q."""
    path.mkdir(parents=True)
    config = {
        "type": "act",
        "input_features": {
            "observation.state": {"type": "STATE", "shape": [state_dim]},
            "observation.images.front": {"type": "VISUAL", "shape": [3, 32, 32]},
        },
        "output_features": {"action": {"type": "ACTION", "shape": [6]}},
    }
    (path / "config.json").write_text(json.dumps(config))
    for name in ("model.safetensors", "policy_preprocessor.json", "policy_postprocessor.json"):
        (path / name).write_text("{}")
    return path


def test_a_typo_in_robot_type_fails_in_seconds_before_any_step(tmp_path):
    """Before: finetune-base ran first (166 s on the SO-101 workflow, hours at real scale), then warmup
    said the type was unknown."""
    wf = tmp_path / "so101.yaml"
    wf.write_text((ROOT / "workflows" / "so101-sim-ci.yaml").read_text().replace("type: so101_env", "type: so101_evn"))
    assert accrue(tmp_path, "init").returncode == 0
    started = time.monotonic()
    proc = accrue(tmp_path, "run", str(wf))
    took = time.monotonic() - started
    assert proc.returncode == 2 and took < 10, (took, proc.stderr[-2000:])
    assert proc.stderr.startswith(f"error: {wf}: robot.type: unknown lerobot robot type 'so101_evn' (did you mean")
    assert "'so101_env'" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert "Traceback" not in proc.stderr and "finetune-base" not in proc.stdout + proc.stderr
    assert not list((tmp_path / ".accrue").glob("records/*"))  # no step record, not even an attempt


def test_stage_run_checks_the_robots_keys_before_any_step(tmp_path):
    wf = workflow(tmp_path, action_keys=["dx", "dy", "dz", "droll", "dpitch", "dyawn"])
    assert accrue(tmp_path, "init").returncode == 0
    proc = accrue(tmp_path, "stage", "run", str(wf), "--stage", "1")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert proc.stderr.startswith(f"error: {wf}: robot.type accrue_sim: action has no 'dyawn' (robot.action_keys")
    assert "finetune-base" not in proc.stdout + proc.stderr


@pytest.mark.parametrize(
    "robot, line",
    [
        ({"config": {"calibration_dri": "x"}}, "robot.config: 'calibration_dri' is not a field of AccrueSimConfig"),
        (
            {"state_keys": ["ee_x_cm", "ee_q_cm"]},
            "robot.type accrue_sim: observation has no 'ee_q_cm' (robot.state_keys",
        ),
        ({"camera_keys": ["front"]}, "observation has no 'front' (robot.camera_keys"),
        ({"safety": {"max_step": {"joint_9": 0.1}}}, "robot.safety: 'joint_9' is not one of the robot's action keys"),
    ],
)
def test_a_wrong_config_field_or_key_is_one_line_naming_it(tmp_path, store, robot, line):
    if "config" in robot:
        robot["config"] = {"calibration_dir": str(tmp_path / "calib"), **robot["config"]}
    with pytest.raises(StageError) as err:
        check(workflow(tmp_path, **robot), store)
    assert line in str(err.value) and "\n" not in str(err.value)


def test_a_base_policy_that_needs_a_camera_the_robot_lacks_names_the_keys_not_a_temp_path(tmp_path, store):
    """Before: warmup failed with `.../tmp/attempt-.../inputs/base-policy needs camera images`."""
    ckpt = image_checkpoint(tmp_path / "act", state_dim=29)

    def init(spec):
        spec["base_policy"] = {"init": str(ckpt)}

    with pytest.raises(
        StageError,
        match=r"base_policy.init .*act takes a camera image \(observation.images.front\), and "
        r"robot.type accrue_sim declares no camera \(its cameras are set in robot.config\)",
    ):
        check(workflow(tmp_path, edit=init), store)

    def with_camera(spec, obs_mode="state"):
        init(spec)
        spec["obs_mode"] = obs_mode
        spec["robot"]["config"].update(render_cameras=["front"], image_size=32)

    with pytest.raises(StageError, match=r"obs_mode: state, but base_policy.init .* takes a camera image"):
        check(workflow(tmp_path, edit=with_camera), store)
    assert check(workflow(tmp_path, edit=lambda s: with_camera(s, "state+image")), store).robots[
        0
    ].mapping.camera_keys == ("front",)


def test_obs_mode_with_images_needs_a_camera_and_q_must_match_the_policy(tmp_path, store):
    def images(spec):
        spec["obs_mode"] = "state+image"

    with pytest.raises(
        StageError, match="obs_mode: state\\+image needs a camera, and robot.type accrue_sim declares none"
    ):
        check(workflow(tmp_path, edit=images), store)
    ckpt = image_checkpoint(tmp_path / "act", state_dim=6)

    def six(spec):
        spec["obs_mode"] = "state+image"
        spec["base_policy"] = {"init": str(ckpt)}
        spec["robot"]["config"].update(render_cameras=["front"], image_size=32)

    with pytest.raises(
        StageError, match=r"robot.state_keys: the robot's q has 29 readings .* takes an observation.state of 6"
    ):
        check(workflow(tmp_path, edit=six), store)


def test_the_learner_address_must_resolve_and_a_token_must_be_there(tmp_path, store):
    """Before: an unresolvable name was found at train, as `UNAVAILABLE`, after the whole warmup."""
    with pytest.raises(StageError, match=r"robot.learner_address: the name 'gpu-box.invalid' does not resolve"):
        check(workflow(tmp_path, learner_address="gpu-box.invalid:50051"), store)
    wf = workflow(tmp_path, learner_address="localhost:50051")
    with pytest.raises(StageError, match=r"robot.learner_address: no link token .* `accrue robot token --out FILE`"):
        check(wf, store)
    from accrue.robot.link_auth import store_token

    store_token(store.root)
    assert check(wf, store).learner.startswith("localhost:50051")


def test_robot_check_reads_one_observation_checks_it_and_sends_no_action(tmp_path, store):
    from stages.steps.robot_preflight import observe_once

    checked = check(workflow(tmp_path), store)
    robot = checked.robots[0]
    sent: list = []
    make = robot.make

    def spied():
        arm = make()
        arm.send_action = lambda action: sent.append(action)
        return arm

    robot.make = spied
    seen = observe_once(load(tmp_path / "hw.yaml"), robot)
    assert sent == [] and seen.findings == [] and len(seen.state) == 29 and seen.cameras == {}


def load(path: Path):
    from stages.workflow import load_workflow

    return load_workflow(path)


def test_accrue_robot_check_says_what_it_read_and_exits_nonzero_out_of_bounds(tmp_path):
    assert accrue(tmp_path, "init").returncode == 0
    good = accrue(tmp_path, "robot", "check", str(workflow(tmp_path)))
    assert good.returncode == 0, good.stderr[-2000:]
    assert "read one observation, sent no action" in good.stdout and "q (29): ee_x_cm=" in good.stdout
    assert "within bounds: robot.safety" in good.stdout and "Traceback" not in good.stderr

    def joints(spec):  # the arm's joint targets, with bounds its resting pose is outside of
        spec["robot"]["config"]["action_mode"] = "joint"
        spec["robot"].update(action_mode="joint", action_bounds=[[10.0, 11.0]] * 6)

    bad = accrue(tmp_path, "robot", "check", str(workflow(tmp_path, edit=joints)))
    assert bad.returncode == 2 and "Traceback" not in bad.stderr, bad.stderr[-2000:]
    assert "out of bounds: robot.action_bounds: x.pos reads " in bad.stdout and "outside [10, 11]" in bad.stdout
    assert bad.stderr.startswith("error: ") and "outside the workflow's bounds (6 findings above)" in bad.stderr


def test_a_broken_base_policy_checkpoint_is_named_by_its_key(tmp_path, store):
    ckpt = image_checkpoint(tmp_path / "act", state_dim=29)
    (ckpt / "model.safetensors").unlink()

    def init(spec):
        spec["base_policy"] = {"init": str(ckpt)}

    with pytest.raises(
        StageError, match=r"hw.yaml: base_policy.init: policy checkpoint .*act is missing model.safetensors"
    ):
        check(workflow(tmp_path, edit=init), store)
