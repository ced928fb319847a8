"""robot.task_config: {task id: {field: value}} over robot.config wherever the robot is built for that task
(stages.steps.robot_session.robot_config_for, make_bridge), checked when the workflow loads, and keyed so
that a stage's cache keys hold only its own and earlier tasks' fields; robot.scripted is checked too; the
robot's warmup, train and evaluate-all say what they do on the robot; so101_demos --task records the
task's scene."""

from __future__ import annotations

import copy
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from artifacts.hashing import hash_json
from artifacts.store import Store
from stages.plan import plan_stage
from stages.runner_types import code_version_of
from stages.workflow import load_workflow, parse_workflow

ROOT = Path(__file__).resolve().parents[1]
WORKFLOWS = ROOT / "workflows"
SO101 = WORKFLOWS / "so101-sim.yaml"
ROBOT_STEPS = ("warmup", "train", "evaluate-all")


def sim_workflow(calib: Path, **robot) -> dict:
    """Two tasks on the simulated robot with the scripted stand-in reference (no demos, no fine-tuning)."""
    return {
        "name": "tc",
        "tasks": ["nist/rect_peg", "nist/round_peg"],
        "method": "accrue",
        "seed": 3,
        "horizon": 4,
        "base_policy": {"init": "scripted-reference:1.0"},
        "learner": {"algo": "fasttd3", "actor_hidden": [32, 32], "critic_hidden": [32, 32], "projector_dim": 16},
        "budgets": {"env_steps": 1000, "eval_every": 1000, "warmup_episodes": 2, "retained_episodes": 2},
        "robot": {
            "type": "accrue_sim",
            "config": {"calibration_dir": str(calib), "estimate_noise": 0.3},
            "operator": "scripted",
            **robot,
        },
    }


@pytest.fixture
def store(tmp_path):
    return Store.init(tmp_path / "store")[0]


def steps_of(wf, stage: int, store) -> dict:
    return {inv.step.name: inv for inv in plan_stage(wf, stage, store).steps}


def keys_of(wf, store) -> dict:
    """{(stage, step): digest of what its cache key hashes} (inputs of later stages are still refs here)."""
    out = {}
    for k in range(1, wf.num_stages + 1):
        for name, inv in steps_of(wf, k, store).items():
            inputs = {role: repr(src) for role, src in inv.inputs.items()}
            out[k, name] = hash_json(
                {"step": name, "cv": code_version_of(inv.step), "config": dict(inv.config), "inputs": inputs}
            )
    return out


def test_each_task_gets_its_own_fields_on_the_robot_built_for_it(tmp_path, store):
    from stages.steps.robot_plan import session_settings
    from stages.steps.robot_session import make_bridge

    per_task = {"nist/round_peg": {"estimate_noise": 0.9}}
    wf = parse_workflow(sim_workflow(tmp_path / "calib", task_config=per_task), "tc.yaml")
    settings = session_settings(wf)
    stage2 = steps_of(wf, 2, store)
    built = {}
    for name, task in (("evaluate-all", "nist/rect_peg"), ("warmup", "nist/round_peg")):
        bridge = make_bridge(dict(stage2[name].config), settings, task, lambda line: None)
        built[task] = bridge.make_robot().config
    assert built["nist/round_peg"].estimate_noise == 0.9  # its own field
    assert built["nist/rect_peg"].estimate_noise == 0.3  # robot.config, not the other task's
    assert {c.task for c in built.values()} == {"nist/rect_peg", "nist/round_peg"}
    # the seeds accrue_sim always had: workflow seed * 1000 + stage * 10 + phase (evaluate 3, warmup 1)
    assert built["nist/rect_peg"].seed == 3 * 1000 + 2 * 10 + 3
    assert built["nist/round_peg"].seed == 3 * 1000 + 2 * 10 + 1


def test_the_so101_tasks_get_their_scenes_and_seeds(store):
    from stages.steps.robot_session import robot_config_for

    wf = load_workflow(SO101)
    assert wf.tasks == ["so101/reach_close", "so101/pick_place"]
    stage2 = steps_of(wf, 2, store)
    train = robot_config_for(dict(stage2["train"].config), "so101/pick_place")
    retention = robot_config_for(dict(stage2["evaluate-all"].config), "so101/reach_close")
    assert train["scene"] == "pick_place" and retention["scene"] == "reach_close"
    assert train["image_size"] == retention["image_size"] == 64  # robot.config, shared
    # a robot whose config class has a `seed` field gets one per stage and phase, as accrue_sim does
    assert (train["seed"], retention["seed"]) == (0 * 1000 + 2 * 10 + 2, 0 * 1000 + 2 * 10 + 3)


def test_a_later_tasks_fields_leave_the_earlier_stages_keys_alone(store):
    data = yaml.safe_load(SO101.read_text())
    before = keys_of(parse_workflow(copy.deepcopy(data), "a.yaml"), store)
    data["robot"]["task_config"]["so101/pick_place"]["image_size"] = 32
    after = keys_of(parse_workflow(copy.deepcopy(data), "b.yaml"), store)
    for step in ROBOT_STEPS:
        assert before[1, step] == after[1, step]  # stage 1 is so101/reach_close's
        assert before[2, step] != after[2, step]  # stage 2 is pick_place's: its fields are in its keys
    data["robot"]["task_config"]["so101/reach_close"]["image_size"] = 48
    first = keys_of(parse_workflow(copy.deepcopy(data), "c.yaml"), store)
    assert all(first[k, step] != after[k, step] for k in (1, 2) for step in ROBOT_STEPS)


@pytest.mark.parametrize(
    "name", ["hardware-sim.yaml", "hardware-sim-single.yaml", "hardware-sim-camera.yaml", "so101-sim-ci.yaml"]
)
def test_workflows_without_task_config_keep_their_keys(store, name):
    """No task_config, or an empty one: the same keys, and none of the robot steps' configs names it (these
    workflows planned to the same step digests before robot.task_config existed)."""
    data = yaml.safe_load((WORKFLOWS / name).read_text())
    plain = load_workflow(WORKFLOWS / name)
    empty = parse_workflow({**data, "robot": {**data["robot"], "task_config": {}}}, name)
    assert keys_of(plain, store) == keys_of(empty, store)
    for k in range(1, plain.num_stages + 1):
        for step, inv in steps_of(plain, k, store).items():
            if step in ROBOT_STEPS:
                assert "task_config" not in inv.config["robot"]


def test_the_robot_steps_describe_the_robot(store):
    from stages.steps.evaluate_all import STEP as SIM_EVALUATE
    from stages.steps.train import STEP as SIM_TRAIN
    from stages.steps.warmup import STEP as SIM_WARMUP

    steps = steps_of(load_workflow(WORKFLOWS / "hardware-sim.yaml"), 2, store)
    for sim in (SIM_WARMUP, SIM_TRAIN, SIM_EVALUATE):
        assert "on the robot" in steps[sim.name].step.description
        assert steps[sim.name].step.description != sim.description
    assert steps["finetune-base"].step.description  # the other steps keep theirs


def accrue(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1", "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-m", "cli.main", *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=300
    )


def test_bad_task_config_and_scripted_keys_are_one_line_refusals(tmp_path):
    calib = tmp_path / "calib"
    cases = {
        "task.yaml": (
            {"task_config": {"nist/gear": {"estimate_noise": 0.5}}},
            "robot.task_config: 'nist/gear' is not one of the workflow's tasks (nist/rect_peg, nist/round_peg)",
        ),
        "field.yaml": (
            {"task_config": {"nist/round_peg": {"estimate_nose": 0.5}}},
            "robot.task_config.nist/round_peg: 'estimate_nose' is not a field of AccrueSimConfig, robot.type "
            "accrue_sim's config (fields: ",
        ),
        "value.yaml": (  # a value the config class refuses: at load, not when stage 2 builds the robot
            {"task_config": {"nist/round_peg": {"estimate_noise": "half"}}},
            "robot.task_config.nist/round_peg: not a valid AccrueSimConfig (",
        ),
        "scripted.yaml": ({"scripted": {"mistake": [1]}}, "robot.scripted.mistake: unknown field"),
    }
    for name, (robot, line) in cases.items():
        path = tmp_path / name
        path.write_text(yaml.safe_dump(sim_workflow(calib, **robot)))
        result = accrue("stage", "status", str(path), cwd=tmp_path)
        assert result.returncode == 2, (name, result.stderr[-2000:])
        assert "Traceback" not in result.stderr
        [said] = result.stderr.strip().splitlines()
        assert said.startswith(f"error: {path}: {line}"), said


def test_so101_demos_record_the_named_tasks_scene(tmp_path, capsys):
    from accrue.errors import AccrueError
    from accrue.robot.sim_robot.so101_demos import _workflow_robot, main, task_robot_config

    robot, tasks = _workflow_robot(SO101)
    assert task_robot_config(SO101, robot, tasks, "so101/pick_place") == {"image_size": 64, "scene": "pick_place"}
    assert task_robot_config(SO101, robot, tasks, "so101/reach_close")["scene"] == "reach_close"
    with pytest.raises(AccrueError, match="name the task to record with --task"):
        task_robot_config(SO101, robot, tasks, None)  # two tasks: which one
    swapped = {**robot, "task_config": {"so101/pick_place": {"scene": "reach_close"}}}
    with pytest.raises(AccrueError, match="whose demos are so101/reach_close's"):
        task_robot_config(SO101, swapped, tasks, "so101/pick_place")
    assert main([str(tmp_path / "d"), "--workflow", str(SO101), "--task", "so101/gear"]) == 2
    said = capsys.readouterr().err.strip()
    assert said == f"error: --task 'so101/gear': not one of {SO101}'s tasks (so101/reach_close, so101/pick_place)"
    assert not (tmp_path / "d").exists()
