"""The simulated lerobot robot with cameras and joint-space actions behind the bridge, and s = (E(I), q)
computed on the actor host from the robot's declared features through a frozen (randomly initialised,
offline) timm encoder, stored with each transition of a hardware warmup."""

from __future__ import annotations

import numpy as np
import pytest

from accrue.robot.mapping import RobotMapping
from accrue.robot.sim_robot.accrue_sim import DONE_KEY, JOINT_KEYS
from accrue.sim import STATE_NAMES

MODEL = "vit_tiny_patch16_224"


def sim(tmp_path, **config):
    from accrue.robot.bridge import robot_factory

    return robot_factory("accrue_sim", {"task": "nist/rect_peg", "calibration_dir": str(tmp_path), **config})


def test_sim_robot_declares_cameras_and_joints_like_a_lerobot_arm(tmp_path):
    from accrue.robot.bridge import RobotBridge
    from accrue.robot.safety import ActionEnvelope

    bridge = RobotBridge(
        sim(tmp_path, render_cameras=["front"], image_size=32, action_mode="joint"),
        RobotMapping(done_key=DONE_KEY, action_mode="joint", action_bounds=((-0.02, 0.02),) * 3 + ((-0.5, 0.5),) * 3),
        actions=ActionEnvelope.from_dict({"max_step": {"z.pos": 0.0005}}),
    )
    bridge.connect()
    features = bridge.robot.observation_features
    assert features["front"] == (32, 32, 3) and all(features[k] is float for k in JOINT_KEYS)
    assert bridge.mapping.camera_keys == ("front",) and bridge.mapping.action_keys == JOINT_KEYS
    assert bridge.mapping.state_keys == (*STATE_NAMES, *JOINT_KEYS)  # as declared; the done flag is not q
    q, done = bridge.observe()
    obs = bridge.observation()
    assert obs["state"].shape == (1, 35) and obs["image"].shape == (1, 32, 32, 3) and obs["image"].dtype == np.uint8
    assert obs["image"].std() > 0  # a rendered scene, not a blank frame
    start = dict(zip(JOINT_KEYS, q[29:].tolist()))
    # joint targets: z 10 mm lower, x +2 mm; the envelope lets z move 0.5 mm per control step
    want = {**start, "z.pos": start["z.pos"] - 0.01, "x.pos": start["x.pos"] + 0.002}
    a = bridge.mapping.normalise(np.array([[want[k] for k in JOINT_KEYS]]))[0]
    zs = []
    for _ in range(4):
        bridge.act(a)
        zs.append(bridge.observe()[0][29 + JOINT_KEYS.index("z.pos")])
    assert bridge.limited == 4
    assert np.diff([start["z.pos"], *zs]) == pytest.approx([-0.0005] * 4, abs=2e-4)  # rate-limited descent
    for _ in range(20):
        bridge.act(a)
    q = bridge.observe()[0]
    assert q[29 + JOINT_KEYS.index("x.pos")] == pytest.approx(want["x.pos"], abs=3e-4)  # where it was told
    assert q[29 + JOINT_KEYS.index("z.pos")] == pytest.approx(want["z.pos"], abs=3e-4)
    moved = bridge.observation()["image"].astype(int)
    assert np.abs(moved - obs["image"]).sum() > 0  # the camera sees the plug 10 mm lower
    bridge.disconnect()


def test_connect_starts_the_renderer_so_the_first_observation_only_draws(tmp_path, monkeypatch):
    """The renderer's start-up (GL context, model upload, shaders: the first frame) belongs to connect; a first
    get_observation that paid it once outlasted the bridge's 1 s observation timeout on a loaded machine."""
    import mujoco

    from accrue.sim.vec_env import VecAssemblyEnv

    made, drawn = [], []
    real_renderer, real_render = mujoco.Renderer, VecAssemblyEnv.render

    def renderer(*args, **kw):
        made.append(args[1:])
        return real_renderer(*args, **kw)

    def render(env, camera="front"):
        drawn.append((camera, real_render(env, camera)))
        return drawn[-1][1]

    monkeypatch.setattr(mujoco, "Renderer", renderer)
    monkeypatch.setattr(VecAssemblyEnv, "render", render)
    robot = sim(tmp_path, render_cameras=["front"], image_size=32, action_mode="joint")()
    robot.connect()
    assert made == [(32, 32)] and [c for c, _ in drawn] == ["front"]  # made and drawn before any observation
    first, second = robot.get_observation()["front"], robot.get_observation()["front"]
    assert len(made) == 1 and len(drawn) == 3  # observations only draw
    np.testing.assert_array_equal(first, drawn[0][1][0])  # the warm-up frame is the scene as it stands
    np.testing.assert_array_equal(first, second)
    robot.disconnect()  # closes the renderer; the next connect starts it again
    robot.connect()
    assert len(made) == 2 and len(drawn) == 4
    robot.get_observation()
    assert len(made) == 2 and len(drawn) == 5
    robot.disconnect()
    blind = sim(tmp_path)()  # no render_cameras: connect makes no renderer
    blind.connect()
    assert len(made) == 2 and len(drawn) == 5
    blind.disconnect()


def test_delta_mode_is_unchanged_and_has_no_joint_keys(tmp_path):
    robot = sim(tmp_path)()
    assert "x.pos" not in robot.observation_features and len(robot.action_features) == 6
    assert not any(isinstance(v, tuple) for v in robot.observation_features.values())


@pytest.fixture(scope="module")
def tiny_encoder(tmp_path_factory):
    import timm
    import torch
    from safetensors.torch import save_file

    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("enc") / "vit_tiny.safetensors"
    save_file(timm.create_model(MODEL, pretrained=False, num_classes=0).state_dict(), str(path))
    return f"{MODEL}:{path}"


def test_hardware_warmup_stores_encoder_features_with_each_transition(tmp_path, tiny_encoder):
    from robot_workflow import run_stage, write_hw_workflow

    from accrue.encoders import make_encoder
    from artifacts.manifests import materialize
    from artifacts.store import Store

    Store.init(tmp_path / "store")
    wf = write_hw_workflow(tmp_path / "hw.yaml", tmp_path / "calib")
    text = wf.read_text().replace(
        "config: {calibration_dir:", "config: {render_cameras: [front], image_size: 32, calibration_dir:"
    )
    text = text.replace("observation_s: 0.5", "observation_s: 10")  # a busy CI machine renders slowly
    wf.write_text(text.replace("horizon: 4\n", f"horizon: 4\nencoder: {tiny_encoder}\n"))
    results = run_stage(tmp_path / "store", wf, 1, step="warmup")
    replay = materialize(Store.open(tmp_path / "store"), results["warmup"].outputs["replay"], tmp_path / "replay")
    from accrue.learner import ReplayBuffer

    buffer = ReplayBuffer.load(replay)
    s = buffer._data["state"][: len(buffer)].numpy()
    dim = make_encoder(tiny_encoder).feature_dim
    assert s.shape[1] == dim + len(STATE_NAMES)  # s = (E(I), q): the ViT's features, then the robot's 29 readings
    assert np.abs(s[:, :dim]).sum() > 0 and len(np.unique(s[:, :dim].round(4), axis=0)) > 1


def test_encoder_identity_is_in_every_cache_key(tmp_path, tiny_encoder):
    """A new weights file under the same path is a new encoder: every step that computes s re-keys."""
    import shutil

    from robot_workflow import write_hw_workflow

    from stages.plan import plan_stage
    from stages.workflow import load_workflow

    path = tmp_path / "enc.safetensors"
    shutil.copyfile(tiny_encoder.split(":", 1)[1], path)
    wf_path = write_hw_workflow(tmp_path / "hw.yaml", tmp_path / "calib")
    wf_path.write_text(wf_path.read_text().replace("horizon: 4\n", f"horizon: 4\nencoder: {MODEL}:{path}\n"))

    def keys():
        wf = load_workflow(wf_path)
        return {inv.step.name: inv.config.get("encoder_id") for inv in plan_stage(wf, 1, None).steps}

    first = keys()
    assert {first[s] is not None for s in ("warmup", "train", "evaluate-all")} == {True}
    with open(path, "r+b") as f:  # other weights, same path
        f.seek(-4, 2)
        f.write(b"\x01\x02\x03\x04")
    second = keys()
    assert all(second[s] != first[s] for s in ("warmup", "train", "evaluate-all"))


def random_image_act(out, state_dim: int = 29, size: int = 32, chunk: int = 4):
    """A randomly initialised lerobot ACT that reads a camera and q (no download: no pretrained backbone),
    saved as a lerobot checkpoint directory with its processors."""
    import torch
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.act.modeling_act import ACTPolicy
    from lerobot.policies.factory import make_pre_post_processors

    torch.manual_seed(0)
    config = ACTConfig(
        input_features={
            "observation.state": PolicyFeature(FeatureType.STATE, (state_dim,)),
            "observation.image": PolicyFeature(FeatureType.VISUAL, (3, size, size)),
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
        "observation.state": {"mean": torch.zeros(state_dim), "std": torch.ones(state_dim)},
        "observation.image": {"mean": torch.full((3, 1, 1), 0.5), "std": torch.full((3, 1, 1), 0.25)},
        "action": {"mean": torch.zeros(6), "std": torch.full((6,), 0.3)},
    }
    policy = ACTPolicy(config)
    pre, post = make_pre_post_processors(config, dataset_stats=stats)
    for part in (policy, pre, post):
        part.save_pretrained(out)
    return out


@pytest.mark.parametrize("mode", ["delta", "joint"])
def test_an_image_policy_is_pi_base_on_the_robot(tmp_path, tiny_encoder, mode):
    """π_base = a lerobot ACT reading the robot's camera, loaded by accrue's own loader (BasePolicy.load via
    finetune-base), drives warmup on the simulated robot; E(I) through the frozen encoder goes with each row."""
    from robot_workflow import robot_events, run_stage, write_hw_workflow

    from accrue.policy import BasePolicy
    from artifacts.store import Store

    ckpt = random_image_act(tmp_path / "act", state_dim=29 + (6 if mode == "joint" else 0))
    policy = BasePolicy.load(ckpt)
    assert policy.image_keys == ["observation.image"]
    frame = np.random.default_rng(0).integers(0, 256, (1, 32, 32, 3), dtype=np.uint8)
    q = np.zeros((1, policy.state_dim), np.float32)
    chunk = policy.reference_chunk({"state": q, "image": frame}, "insert", 4)
    other = policy.reference_chunk({"state": q, "image": 255 - frame}, "insert", 4)
    assert chunk.shape == (1, 4, 6) and not np.allclose(chunk, other)  # the chunk depends on the image

    Store.init(tmp_path / "store")
    wf = write_hw_workflow(tmp_path / "hw.yaml", tmp_path / "calib")
    text = wf.read_text().replace(
        "config: {calibration_dir:", "config: {render_cameras: [front], image_size: 32, calibration_dir:"
    )
    text = text.replace(
        'base_policy: {init: "scripted-reference:1.0"}', f"base_policy: {{init: {ckpt}, finetune: false}}"
    )
    text = text.replace("observation_s: 0.5", "observation_s: 10")  # a busy CI machine renders slowly
    if mode == "joint":  # π_base's chunk is joint targets: the sim arm's six joints within these bounds
        text = text.replace(
            "  operator: scripted\n",
            "  operator: scripted\n  action_mode: joint\n  action_bounds: [[-0.01, 0.01], [-0.01, 0.01], [-0.01, 0.03], "
            "[-0.2, 0.2], [-0.2, 0.2], [-0.5, 0.5]]\n  safety: {max_step: {z.pos: 0.0005}}\n",
        ).replace("config: {render_cameras", "config: {action_mode: joint, render_cameras")
    wf.write_text(text.replace("horizon: 4\n", f"horizon: 4\nencoder: {tiny_encoder}\n"))
    results = run_stage(tmp_path / "store", wf, 1, step="warmup")
    sealed = robot_events(tmp_path / "store", "robot-episode-sealed")
    assert len(sealed) == 3 and all(e["robot_time_s"] > 0 for e in sealed)
    limited = sum(e.get("limited_commands") or 0 for e in sealed)  # the envelope's clips are on record
    assert (limited > 0) == (mode == "joint")
    from accrue.learner import ReplayBuffer
    from artifacts.manifests import materialize

    replay = materialize(Store.open(tmp_path / "store"), results["warmup"].outputs["replay"], tmp_path / "replay")
    q_dim = 29 + (6 if mode == "joint" else 0)  # the joint readings join q where the arm takes joint targets
    assert ReplayBuffer.load(replay).state_dim == 192 + q_dim


def test_joint_targets_refuse_an_end_effector_base_policy(tmp_path):
    from robot_workflow import write_hw_workflow

    from stages.errors import StageError
    from stages.plan import plan_stage
    from stages.workflow import load_workflow

    wf = write_hw_workflow(tmp_path / "hw.yaml", tmp_path / "calib")
    bounds = "[[-0.01, 0.01], [-0.01, 0.01], [-0.01, 0.03], [-0.2, 0.2], [-0.2, 0.2], [-0.5, 0.5]]"
    wf.write_text(wf.read_text() + f"  action_mode: joint\n  action_bounds: {bounds}\n")
    with pytest.raises(StageError, match="acts in end-effector deltas; robot.action_mode joint needs"):
        plan_stage(load_workflow(wf), 1, None)


def test_the_camera_workflow_plans_an_image_policy_on_the_camera_robot():
    """workflows/hardware-sim-camera.yaml: demos with the front camera, an image ACT from scratch, and the
    robot's front camera in the hardware steps' keys."""
    from pathlib import Path

    from stages.plan import plan_stage
    from stages.workflow import load_workflow

    wf = load_workflow(Path(__file__).resolve().parents[1] / "workflows" / "hardware-sim-camera.yaml")
    steps = {inv.step.name: inv for inv in plan_stage(wf, 1, None).steps}
    assert steps["record-demos"].config["obs_mode"] == "state+image"
    assert steps["warmup"].config["robot"]["config"]["render_cameras"] == ["front"]
    assert wf.base_policy.init == "act"


def test_the_encoder_workflow_puts_both_cameras_features_into_s(tmp_path, tiny_encoder):
    """workflows/hardware-sim-encoder.yaml: the robot renders front and side, both are camera_keys, and the
    encoder (here the test's seeded weights in place of the DINOv2 file a lab downloads) keys every step
    that computes s."""
    from pathlib import Path

    import yaml

    from stages.plan import plan_stage
    from stages.workflow import load_workflow

    spec = yaml.safe_load((Path(__file__).resolve().parents[1] / "workflows" / "hardware-sim-encoder.yaml").read_text())
    assert spec["encoder"].startswith("dinov2-small:")
    spec["encoder"] = tiny_encoder
    path = tmp_path / "hardware-sim-encoder.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    steps = {inv.step.name: inv for inv in plan_stage(load_workflow(path), 1, None).steps}
    for name in ("warmup", "train"):
        robot = steps[name].config["robot"]
        assert robot["config"]["render_cameras"] == ["front", "side"] and robot["camera_keys"] == ["front", "side"]
        assert steps[name].config["encoder"] == tiny_encoder and steps[name].config["encoder_id"].startswith(MODEL)
