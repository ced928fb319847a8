"""`accrue add DIR --kind demos --workflow WF` carries the robot's camera for an image workflow: a dataset
written the way lerobot-record writes it (hw_to_dataset_features of the SO-101's declared features, the front
camera included) becomes accrue demos whose `observation.images.front` holds the recorded frames at the
shape the workflow's robot declares (workflows/so101-sim-ci.yaml: 32x32), resized from another size of the
same aspect; a dataset without that camera, or with frames that are not RGB at that aspect, is refused in
one line and nothing is stored."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from test_cli_store import accrue, one_line_error

from accrue.robot.sim_robot.so101_env import DONE_KEY, JOINT_KEYS

pytestmark = pytest.mark.slow  # lerobot writes and reads the datasets: ~30 s of imports

ROOT = Path(__file__).resolve().parents[1]
WORKFLOW = ROOT / "workflows" / "so101-sim-ci.yaml"  # obs_mode state+image, so101_env's front camera at 32 px
EPISODE_FRAMES = (4, 3)
A, B = (200, 30, 90), (10, 180, 250)  # the two halves of a resized frame

FRONT = "observation.images.front"  # the SO-101's camera, as its robot and lerobot-record name it


def record(root: Path, camera: tuple | None, pattern: str = "noise", seed: int = 0) -> tuple[Path, list]:
    """SO-101 episodes written the way lerobot-record writes them (its own frame builders), with the front
    camera of shape `camera` (None: no camera) stored as PNG images; also each frame's camera image."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.utils.feature_utils import build_dataset_frame, hw_to_dataset_features

    observation = {**{k: float for k in JOINT_KEYS}, DONE_KEY: float}
    if camera is not None:
        observation["front"] = camera
    action = {k: float for k in JOINT_KEYS}
    features = {
        **hw_to_dataset_features(observation, "observation", use_video=False),
        **hw_to_dataset_features(action, "action", use_video=False),
    }
    ds = LeRobotDataset.create(
        repo_id="local/so101", fps=10, features=features, root=root, robot_type="so101_env", use_videos=False
    )
    rng = np.random.default_rng(seed)
    images = []
    for frames in EPISODE_FRAMES:
        for _ in range(frames):
            obs = {k: float(rng.uniform(-1.5, 1.5)) for k in JOINT_KEYS} | {DONE_KEY: 0.0}
            if camera is not None:
                if pattern == "halves":  # left half A, right half B: resizing keeps both away from the seam
                    image = np.empty(camera, dtype=np.uint8)
                    image[:, : camera[1] // 2], image[:, camera[1] // 2 :] = A, B
                elif camera[2] == 1:  # a depth camera: lerobot stores its frames as float32
                    image = rng.uniform(0.2, 2.0, camera).astype(np.float32)
                else:
                    image = rng.integers(0, 256, camera, dtype=np.uint8)
                obs["front"] = image
                images.append(image)
            act = {k: float(rng.uniform(-1.5, 1.5)) for k in JOINT_KEYS}
            ds.add_frame(
                {
                    **build_dataset_frame(ds.features, obs, prefix="observation"),
                    **build_dataset_frame(ds.features, act, prefix="action"),
                    "task": "reach the cube",
                }
            )
        ds.save_episode()
    ds.finalize()
    return root, images


def converted(store: Path, ref: str, tmp_path: Path, dataset: Path, workflow: Path = WORKFLOW) -> Path:
    """`accrue add` of dataset through the workflow; the stored demos as finetune-base is given them."""
    from artifacts.manifests import materialize
    from artifacts.store import Store

    added = accrue("add", str(dataset), "--kind", "demos", "--workflow", str(workflow), "--ref", ref, store=store)
    assert added.returncode == 0, added.stderr
    return materialize(Store.open(store), added.stdout.strip(), tmp_path / ref)


def frames_of(demos: Path) -> np.ndarray:
    """The converted camera frames, (N, h, w, 3) uint8, decoded by lerobot."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    ds = LeRobotDataset("local/demos", root=demos, video_backend="pyav")
    chw = np.stack([np.asarray(ds[i][FRONT]) for i in range(len(ds))])
    return np.clip(np.rint(chw.transpose(0, 2, 3, 1) * 255.0), 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    path = tmp_path_factory.mktemp("camera-store") / "store"
    assert accrue("init", store=path).returncode == 0
    return path


def test_the_recorded_camera_becomes_the_demos_image(store, tmp_path):
    from test_so101_env import small_image_act

    from accrue.policy import FinetuneSettings, finetune
    from accrue.sim.demos import read_demo_info

    dataset, images = record(tmp_path / "recorded", (32, 32, 3))
    demos = converted(store, "so101-demos/camera", tmp_path, dataset)
    info = read_demo_info(demos, state_dim=len(JOINT_KEYS))
    assert info.task_id == "so101/reach_close" and info.num_episodes == len(EPISODE_FRAMES)
    # the robot's front camera, by its own name (was observation.images.wrist whatever the camera)
    assert info.features[FRONT]["shape"] == [32, 32, 3] and info.features[FRONT]["dtype"] == "image"
    meta = json.loads((demos / "meta" / "accrue.json").read_text())
    assert meta["obs_mode"] == "state+image" and meta["mapping"]["camera_keys"] == ["front"]
    assert meta["recorded_camera"] == {"key": "observation.images.front", "shape": [32, 32, 3]}
    frames = frames_of(demos)
    assert frames.shape == (sum(EPISODE_FRAMES), 32, 32, 3)
    np.testing.assert_array_equal(frames, np.stack(images))  # frame t is the frame recorded with frame t

    # finetune-base fine-tunes the workflow's image policy (a small ACT reading the camera) on these demos
    act = small_image_act(tmp_path / "act", size=32)
    out = finetune(str(act), [demos], tmp_path / "policy", FinetuneSettings(steps=2, batch_size=4, num_workers=0))
    trained = json.loads((out / "accrue_finetune.json").read_text())
    assert trained["training_set"]["image_keys"] == [FRONT]
    assert trained["training_set"]["total_frames"] == sum(EPISODE_FRAMES)
    assert (out / "model.safetensors").is_file()


def test_a_camera_recorded_at_another_size_is_resized_to_the_robots(store, tmp_path):
    dataset, _ = record(tmp_path / "recorded", (64, 64, 3), pattern="halves")
    demos = converted(store, "so101-demos/resized", tmp_path, dataset)
    frames = frames_of(demos)
    assert frames.shape == (sum(EPISODE_FRAMES), 32, 32, 3)  # the workflow's robot declares 32x32
    assert (frames[:, :, :14] == A).all() and (frames[:, :, 18:] == B).all()
    meta = json.loads((demos / "meta" / "accrue.json").read_text())
    assert meta["recorded_camera"]["shape"] == [64, 64, 3]


def test_the_tasks_own_robot_config_sets_the_camera(store, tmp_path):
    """robot.task_config over robot.config here too, as where the stages build the task's robot: the task's
    camera is 16 px, so the demos are 16 px (they were 32, robot.config's, before the rule applied here)."""
    line = "  config: {scene: reach_close, image_size: 32}\n"
    text = WORKFLOW.read_text()
    assert line in text
    workflow = tmp_path / "per-task.yaml"
    workflow.write_text(text.replace(line, line + "  task_config: {so101/reach_close: {image_size: 16}}\n"))
    dataset, _ = record(tmp_path / "recorded", (64, 64, 3), pattern="halves")
    frames = frames_of(converted(store, "so101-demos/per-task", tmp_path, dataset, workflow))
    assert frames.shape == (sum(EPISODE_FRAMES), 16, 16, 3)
    assert (frames[:, :, :7] == A).all() and (frames[:, :, 9:] == B).all()


@pytest.mark.parametrize(
    "camera, said",
    [
        (None, "has no camera 'front' (observation.images.front)"),
        ((32, 32, 1), "not RGB frames"),
        ((32, 48, 3), "without distorting it"),
    ],
    ids=["missing", "depth", "aspect"],
)
def test_a_dataset_without_the_workflows_camera_is_refused_in_one_line(store, tmp_path, camera, said):
    from artifacts.store import Store

    dataset, _ = record(tmp_path / "recorded", camera)
    objects = sorted(Store.open(store).iter_object_ids())
    line = one_line_error(accrue("add", str(dataset), "--kind", "demos", "--workflow", str(WORKFLOW), store=store))
    assert said in line, line
    assert sorted(Store.open(store).iter_object_ids()) == objects  # nothing stored by a refusal
