"""Reset to a fixed joint pose before each episode, and a region-of-interest crop per camera (both off unless
the workflow sets robot.reset_pose / robot.crop), on the simulated robot (accrue_sim in joint mode, its front
camera rendered): the arm is at the pose when the episode's first step is taken, having moved no faster than
robot.safety.max_step; E(I) is computed on the cropped frame, and the crop is in the steps' keys."""

from __future__ import annotations

import numpy as np
import pytest
from robot_workflow import write_hw_workflow
from test_robot_any_arm import seeded_encoder

from accrue.errors import AccrueError
from stages.errors import StageError

JOINTS = ("x.pos", "y.pos", "z.pos", "roll.pos", "pitch.pos", "yaw.pos")
STEP = {k: 0.002 for k in JOINTS[:3]} | {k: 0.02 for k in JOINTS[3:]}  # robot.safety.max_step
POSE = {"x.pos": 0.004, "y.pos": -0.003, "z.pos": 0.03, "yaw.pos": 0.0}  # above the socket, square to it
BOUNDS = ((-0.1, 0.1),) * 3 + ((-1.0, 1.0),) * 3


class Recorder:
    def start(self, *a):
        pass

    def log_step(self, *a, **k):
        pass


def sim_bridge(tmp_path, cameras=(), crop=None):
    """accrue_sim in joint mode behind a RobotBridge; every command it is sent is kept in `sent`."""
    from accrue.robot.bridge import RobotBridge
    from accrue.robot.mapping import RobotMapping
    from accrue.robot.robot_types import lerobot_factory
    from accrue.robot.safety import ActionEnvelope

    config = {"calibration_dir": str(tmp_path / "calib"), "action_mode": "joint", "task": "nist/rect_peg", "seed": 3}
    make = lerobot_factory(
        "robot", "accrue_sim", {**config, "render_cameras": list(cameras)}, (), where="robot", type_key="type"
    )
    sent: list[dict] = []

    def built():
        robot = make()
        plain = robot.send_action
        robot.send_action = lambda action: (sent.append(dict(action)), plain(action))[1]
        return robot

    mapping = RobotMapping.from_dict(
        {"action_mode": "joint", "action_bounds": BOUNDS, "done_key": "episode.done", "crop": crop or {}}
    )
    bridge = RobotBridge(built, mapping, actions=ActionEnvelope.from_dict({"max_step": STEP}))
    bridge.connect()
    return bridge, sent


def first_step_joints(bridge, reset) -> tuple[np.ndarray, object]:
    """Run a one-chunk episode (the policy holds the arm where it is) and return q of its first step."""
    from accrue.robot.episode import EpisodeSettings, run_episode

    keys = bridge.mapping.state_keys
    at = [keys.index(k) for k in JOINTS]

    def hold(obs):  # every step of the chunk the joints' observed values
        q = np.asarray(obs["state"][0][at], dtype=np.float64)
        return np.repeat(bridge.mapping.normalise(q)[None, None].astype(np.float32), 2, axis=1)

    settings = EpisodeSettings(horizon=2, max_steps=2, control_hz=15.0, clock=0, reset=reset)
    out = run_episode(bridge, settings, hold, lambda s, ref, fresh: ref, lambda obs: obs["state"], Recorder(), {})
    return out.s[0][at], out


def test_the_arm_is_at_the_reset_pose_when_the_episode_takes_its_first_step(tmp_path):
    """Each episode starts where the scene's reset left the arm (randomised) unless robot.reset_pose is set:
    then the first step's q reads the pose (within its tolerance) for every key it names, the keys it leaves
    out were held, no reset command moved any key more than its max_step, and the reset's control steps are
    not the episode's (control_steps, robot time)."""
    from accrue.robot.bridge import ResetPose

    bridge, sent = sim_bridge(tmp_path)
    reset = ResetPose.from_dict({"pose": POSE, "tolerance": 0.0005})
    named = [JOINTS.index(k) for k in POSE]
    target = np.array(list(POSE.values()))
    try:
        starts = []
        for episode in range(2):
            bridge.robot.reset_scene()  # what the operator's `r` does on the simulated robot
            bridge.observe()
            before = np.array([bridge.last_observation()[k] for k in JOINTS])
            sent.clear()
            q, out = first_step_joints(bridge, reset)
            assert np.abs(q[named] - target).max() <= 0.0005, (episode, q)
            assert np.abs(before[named] - target).max() > 0.005  # the scene's reset did not leave it there
            moves = len(sent) - out.control_steps
            assert moves >= 5 and out.control_steps == 2 and out.robot_time_s == pytest.approx(2 / 15.0)
            last = {k: before[i] for i, k in enumerate(JOINTS)}
            for command in sent[:moves]:  # the reset's commands: rate-limited like any other
                for k in JOINTS:
                    assert abs(command[k] - last[k]) <= STEP[k] + 1e-9, (k, command[k], last[k])
                    if k not in POSE:
                        assert command[k] == pytest.approx(before[JOINTS.index(k)], abs=1e-3)
                last = command
            starts.append(before)

        # off (no reset_pose): the first step reads where the reset left the arm, not the pose
        bridge.robot.reset_scene()
        bridge.observe()
        before = np.array([bridge.last_observation()[k] for k in JOINTS])
        sent.clear()
        q, out = first_step_joints(bridge, None)
        assert np.allclose(q, before, atol=1e-6) and np.abs(q[named] - target).max() > 0.005
        assert len(sent) == out.control_steps
    finally:
        bridge.disconnect()


def test_a_pose_the_arm_does_not_reach_is_one_line(tmp_path):
    from accrue.robot.bridge import ResetPose

    bridge, _ = sim_bridge(tmp_path)
    try:
        with pytest.raises(AccrueError) as err:
            first_step_joints(bridge, ResetPose.from_dict({"pose": POSE, "tolerance": 1e-4, "max_steps": 2}))
        line = str(err.value)
        assert "\n" not in line and line.startswith("robot.reset_pose: the arm did not reach the pose within 2 ")
        with pytest.raises(AccrueError, match="^robot.reset_pose: 'gripper.pos' is not one of the robot's action keys"):
            first_step_joints(bridge, ResetPose.from_dict({"pose": {"gripper.pos": 1.0}, "tolerance": 1e-3}))
    finally:
        bridge.disconnect()


def robot_workflow(tmp_path, extra: str, mode: str = "joint") -> object:
    wf = write_hw_workflow(tmp_path / "hw.yaml", tmp_path / "calib")
    text = wf.read_text()
    if mode == "joint":
        text = text.replace("config: {calibration_dir:", "config: {action_mode: joint, calibration_dir:")
        text += "  action_mode: joint\n"
    wf.write_text(text + extra)
    return wf


@pytest.mark.parametrize(
    "extra, mode, says",
    [
        (
            '  reset_pose: {pose: {"z.pos": 0.03}, tolerance: 0.001}\n',
            "delta",
            "reset_pose needs action_mode joint",
        ),
        (
            '  reset_pose: {pose: {"z.pos": 0.03}, tolerance: 0.001}\n',
            "joint",
            "reset_pose: 'z.pos' has no safety.max_step",
        ),
        (
            '  reset_pose: {pose: {"z.pos": 0.03}, tolerance: 0}\n  safety: {max_step: {"z.pos": 0.002}}\n',
            "joint",
            "tolerance",
        ),
        ("  crop: {front: [0, 0, 0, 10]}\n", "delta", "crop.front: needs [top, left, height, width]"),
        ("  crop: {front: [0, 0, 10]}\n", "delta", "crop.front: needs [top, left, height, width]"),
        ("  camera_keys: [front]\n  crop: {side: [0, 0, 8, 8]}\n", "delta", "crop.side: not one of camera_keys"),
    ],
)
def test_bad_reset_or_crop_settings_are_one_line_when_the_workflow_loads(tmp_path, extra, mode, says):
    from stages.workflow import load_workflow

    with pytest.raises(StageError) as err:
        load_workflow(robot_workflow(tmp_path, extra, mode))
    line = str(err.value)
    assert "\n" not in line and says in line, line


def test_a_crop_box_outside_the_frame_is_one_line_at_preflight(tmp_path):
    """The frame's size is the robot's to declare: a box past it is refused by `accrue robot preflight`'s
    robot check (and by the session's bind, before anything moves), naming the camera and the frame."""
    from stages.steps.robot_preflight import _check_robot
    from stages.workflow import load_workflow

    extra = "  crop: {front: [40, 8, 32, 16]}\n"
    wf = robot_workflow(tmp_path, extra, mode="delta")
    wf.write_text(
        wf.read_text().replace("config: {calibration_dir:", "config: {render_cameras: [front], calibration_dir:")
    )
    with pytest.raises(AccrueError) as err:
        _check_robot(load_workflow(wf), 1)
    line = str(err.value)
    assert "\n" not in line and line == (
        "robot.crop.front: [top 40, left 8, height 32, width 16] reaches row 72, column 24, outside its 64 x 64 frame"
    )
    wf.write_text(wf.read_text().replace("[40, 8, 32, 16]", "[16, 8, 32, 16]"))
    assert dict(_check_robot(load_workflow(wf), 1).mapping.crop) == {"front": (16, 8, 32, 16)}


def test_the_crop_is_what_the_encoder_sees_and_it_keys_the_steps(tmp_path):
    """With robot.crop the frame E(I) is computed on (and cached under) is the region of interest resized to
    the camera's size: E(I) equals the encoder's features of exactly that frame, differs from the uncropped
    frame's, and the robot steps' keys change with the box (a workflow without a crop keeps its keys)."""
    from accrue.encoders import frame_hash, make_encoder
    from accrue.learner_inputs import encoder_features
    from accrue.robot.mapping import crop_frame

    spec = seeded_encoder(tmp_path / "enc.safetensors")
    box = (16, 8, 32, 40)
    full, _ = sim_bridge(tmp_path / "full", cameras=("front",))
    cropped, _ = sim_bridge(tmp_path / "crop", cameras=("front",), crop={"front": list(box)})
    try:
        full.observe()
        cropped.observe()
        raw = np.asarray(cropped.last_observation()["front"])
        assert np.array_equal(raw, full.last_observation()["front"])  # same seed, same scene, same frame
        seen = cropped.frames()[0]
        assert seen.shape == raw.shape and np.array_equal(seen, crop_frame(raw, box))
        assert np.array_equal(full.frames()[0], raw)
        features = encoder_features(spec)
        s_full, s_crop = features(full.observation()), features(cropped.observation())
        encoder = make_encoder(spec)
        width = encoder.feature_dim
        assert np.allclose(s_crop[0, :width], encoder.encode(seen[None])[0], atol=1e-6)
        assert np.allclose(s_full[0, :width], encoder.encode(raw[None])[0], atol=1e-6)
        assert not np.allclose(s_crop[0, :width], s_full[0, :width], atol=1e-3)
        assert np.array_equal(s_crop[0, width:], s_full[0, width:])  # q is not cropped
        assert encoder.cache.get(frame_hash(seen)) is not None  # cached under the cropped frame
    finally:
        full.disconnect()
        cropped.disconnect()

    from stages.steps.robot_plan import robot_config
    from stages.workflow import load_workflow

    base = robot_workflow(tmp_path, "", mode="delta")
    plain = robot_config(load_workflow(base))
    assert "crop" not in plain and "reset_pose" not in plain
    base.write_text(base.read_text() + "  crop: {front: [16, 8, 32, 40]}\n")
    assert robot_config(load_workflow(base))["crop"] == {"front": [16, 8, 32, 40]}
