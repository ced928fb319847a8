"""`accrue add DIR --kind demos --workflow WF --task T`: a dataset written by lerobot's own recorder (LeRobotDataset
with hw_to_dataset_features of a robot's features, as lerobot-record writes it) is converted through the
workflow's robot mapping into accrue's demo layout, stored, and trained on; one from another robot is refused
in one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from robot_workflow import write_hw_workflow
from test_cli_store import accrue, one_line_error

pytestmark = pytest.mark.slow  # lerobot writes the datasets and lerobot-train fine-tunes: ~30 s of imports each
LIMITS = [0.5, 0.5, 0.5, 1.0, 1.0, 2.0]  # robot units per unit of normalised action, per axis
EPISODE_FRAMES = (6, 4)


def record(root: Path, robot_type: str, observation: dict, action: dict, seed: int = 0) -> tuple[Path, list]:
    """Episodes written the way lerobot-record writes them (its own frame builders); also the (observation, action) dicts of each frame."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.utils.feature_utils import build_dataset_frame, hw_to_dataset_features

    features = {
        **hw_to_dataset_features(observation, "observation", use_video=False),
        **hw_to_dataset_features(action, "action", use_video=False),
    }
    ds = LeRobotDataset.create(
        repo_id=f"local/{robot_type}", fps=10, features=features, root=root, robot_type=robot_type, use_videos=False
    )
    rng = np.random.default_rng(seed)
    sent = []
    for frames in EPISODE_FRAMES:
        for _ in range(frames):
            obs = {k: float(rng.uniform(-2, 2)) for k in observation}
            act = {k: float(rng.uniform(-1.5, 1.5)) for k in action}  # some beyond the limits: clipped
            ds.add_frame(
                {
                    **build_dataset_frame(ds.features, obs, prefix="observation"),
                    **build_dataset_frame(ds.features, act, prefix="action"),
                    "task": "insert",
                }
            )
            sent.append((obs, act))
        ds.save_episode()
    ds.finalize()
    return root, sent


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    from accrue.robot.sim_robot import AccrueSim, AccrueSimConfig

    root = tmp_path_factory.mktemp("demos")
    sim = AccrueSim(AccrueSimConfig(calibration_dir=root / "calib"))
    ours, sent = record(root / "sim", "accrue_sim", sim.observation_features, sim.action_features)
    joints = {
        f"{j}.pos": float
        for j in ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper")
    }
    theirs, _ = record(root / "so101", "so101_follower", joints, joints)
    wf = write_hw_workflow(root / "hw.yaml", root / "calib")
    wf.write_text(wf.read_text() + f"  action_limits: {LIMITS}\n")
    return root, ours, theirs, sent, wf


def test_dataset_from_another_robot_is_refused_in_one_line(datasets):
    root, ours, theirs, _, wf = datasets
    from artifacts.store import Store

    store = root / "store-refused"
    assert accrue("init", store=store).returncode == 0
    objects = sorted(Store.open(store).iter_object_ids())
    line = one_line_error(accrue("add", str(theirs), "--kind", "demos", "--workflow", str(wf), store=store))
    assert "so101_follower" in line and "robot.state_keys: ee_x_cm" in line
    # lerobot-record's task text ("insert") names neither workflow task: the user must say which
    line = one_line_error(accrue("add", str(ours), "--kind", "demos", "--workflow", str(wf), store=store))
    assert "--task" in line and "nist/rect_peg" in line
    line = one_line_error(
        accrue("add", str(ours), "--kind", "demos", "--workflow", str(wf), "--task", "nist/gear", store=store)
    )
    assert "not one of workflow hw's tasks" in line
    assert "--workflow" in one_line_error(
        accrue("add", str(ours), "--kind", "demos", "--task", "nist/rect_peg", store=store)
    )
    assert sorted(Store.open(store).iter_object_ids()) == objects  # nothing stored by a refusal


def test_recorded_demos_are_converted_stored_and_trained_on(datasets, tmp_path):
    from accrue.policy import FinetuneSettings, finetune
    from accrue.sim import get_task
    from accrue.sim.demos import read_demo_info
    from artifacts.manifests import materialize
    from artifacts.store import Store

    root, ours, _, sent, wf = datasets
    store = tmp_path / "store"
    assert accrue("init", store=store).returncode == 0
    added = accrue(
        "add",
        str(ours),
        "--kind",
        "demos",
        "--workflow",
        str(wf),
        "--task",
        "nist/rect_peg",
        "--ref",
        "robot-demos/rect",
        store=store,
    )
    assert added.returncode == 0, added.stderr
    artifact = added.stdout.strip()
    assert len(artifact) == 64

    demos = materialize(Store.open(store), artifact, tmp_path / "demos")  # what finetune-base is given
    info = read_demo_info(demos)
    assert info.task_id == "nist/rect_peg" and info.num_episodes == len(EPISODE_FRAMES)
    assert info.instruction == get_task("nist/rect_peg").instruction
    meta = json.loads((demos / "meta" / "accrue.json").read_text())
    assert meta["source"] == "lerobot-record" and meta["robot_type"] == "accrue_sim"
    assert meta["successes"] == meta["attempts"] == 2 and meta["frames"] == sum(EPISODE_FRAMES)
    assert meta["recorded_tasks"] == ["insert"] and meta["mapping"]["action_limits"] == LIMITS

    import pandas as pd

    table = pd.concat(pd.read_parquet(p) for p in sorted((demos / "data").rglob("*.parquet")))
    states, actions = np.stack(table["observation.state"]), np.stack(table["action"])
    from accrue.robot.mapping import RobotMapping
    from accrue.robot.sim_robot import DONE_KEY
    from accrue.sim import ACTION_NAMES, STATE_NAMES

    mapping = RobotMapping(action_limits=tuple(LIMITS), done_key=DONE_KEY).bind(
        {n: float for n in STATE_NAMES}, {n: float for n in ACTION_NAMES}, "accrue_sim"
    )
    for i in (0, 3, 5, 9):  # by hand: the mapping applied to what was recorded
        obs, act = sent[i]
        np.testing.assert_allclose(states[i], mapping.state({k: np.float32(v) for k, v in obs.items()}))
        expected = [np.clip(np.float32(act[n]) / lim, -1, 1) for n, lim in zip(ACTION_NAMES, LIMITS)]
        np.testing.assert_allclose(actions[i], expected, rtol=1e-6)
    assert np.abs(actions).max() <= 1.0 and meta["clipped_action_values"] > 0
    ends = np.cumsum(EPISODE_FRAMES) - 1
    success, done = np.asarray(table["next.success"], bool), np.asarray(table["next.done"], bool)
    assert np.flatnonzero(success).tolist() == ends.tolist() == np.flatnonzero(done).tolist()
    reward = np.asarray(table["next.reward"], float)
    assert np.flatnonzero(reward == 1.0).tolist() == [3, 4, 5, 7, 8, 9] and reward.sum() == 6
    assert set(table["task_index"]) == {0}

    # the workflow's base_policy.demos names it: finetune-base of stage 1 takes it as demos-1
    from stages.plan import plan_stage
    from stages.workflow import load_workflow

    text = wf.read_text().replace(
        'base_policy: {init: "scripted-reference:1.0"}',
        "base_policy: {init: embedded-mlp, demos: {nist/rect_peg: robot-demos/rect}}",
    )
    (tmp_path / "hw.yaml").write_text(text)
    plan = plan_stage(load_workflow(tmp_path / "hw.yaml"), 1, Store.open(store))
    ft = next(inv for inv in plan.steps if inv.step.name == "finetune-base")
    assert ft.inputs["demos-1"] == "robot-demos/rect"

    out = finetune(
        "embedded-mlp",
        [demos],
        tmp_path / "policy",
        FinetuneSettings(steps=2, batch_size=4, chunk_size=4, num_workers=0),
    )
    record = json.loads((out / "accrue_finetune.json").read_text())
    assert record["training_set"]["instructions"] == [info.instruction]
    assert (out / "model.safetensors").is_file()


def test_conversion_reads_columns_by_name(datasets, tmp_path):
    """A mapping that reads the state columns in another order gets them in that order."""
    from accrue.errors import AccrueError
    from accrue.robot.demo_convert import convert_robot_dataset, mapped_states
    from accrue.robot.mapping import RobotMapping
    from accrue.sim import STATE_NAMES

    root, ours, _, sent, _ = datasets
    mapping = RobotMapping(state_keys=tuple(reversed(STATE_NAMES)))
    names = list(sent[0][0])
    recorded = np.array([[obs[k] for k in names] for obs, _ in sent])
    states = mapped_states(recorded, names, mapping)
    assert states[2, 0] == np.float32(sent[2][0][STATE_NAMES[-1]])
    assert states[2, -1] == np.float32(sent[2][0][STATE_NAMES[0]])
    with pytest.raises(AccrueError, match="names cannot be matched"):
        mapped_states(recorded[:, :-1], names, mapping)
    meta = convert_robot_dataset(ours, tmp_path / "out", mapping, "accrue_sim", "nist/round_peg", "insert it")
    assert meta["episodes"] == 2 and meta["mapping"]["state_keys"][0] == STATE_NAMES[-1]
    assert meta["clipped_action_values"] > 0  # limits of 1.0: recorded values beyond +-1 are clipped
    with pytest.raises(AccrueError, match="not empty"):
        convert_robot_dataset(ours, tmp_path / "out", mapping, "accrue_sim", "nist/round_peg", "insert it")


def test_robot_dataset_check_reads_only_metadata(datasets):
    from accrue.errors import AccrueError
    from accrue.robot.demos import check_robot_dataset
    from accrue.robot.mapping import RobotMapping

    root, ours, theirs, _, _ = datasets
    info = check_robot_dataset(ours, RobotMapping(), "accrue_sim")
    assert info["episodes"] == 2 and info["frames"] == sum(EPISODE_FRAMES) and info["robot_type"] == "accrue_sim"
    with pytest.raises(AccrueError, match="not a LeRobot dataset"):
        check_robot_dataset(root, RobotMapping(), "accrue_sim")
    assert np.isfinite(info["fps"])


def test_task_comes_from_the_option_or_the_recorded_text(datasets):
    from accrue.sim import get_task
    from cli.hw_demos import _task_of
    from stages.errors import StageError
    from stages.workflow import load_workflow

    wf = load_workflow(datasets[4])
    assert _task_of(wf, ["insert"], "nist/round_peg") == "nist/round_peg"
    assert _task_of(wf, ["nist/round_peg"], None) == "nist/round_peg"
    assert _task_of(wf, [get_task("nist/rect_peg").instruction.upper() + " "], None) == "nist/rect_peg"
    with pytest.raises(StageError, match="--task"):
        _task_of(wf, ["insert"], None)
