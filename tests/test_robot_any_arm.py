"""An arm that is not six keys and has two cameras, end to end on the simulated robot: a seven-key arm
(tests/fake_arms.py: accrue_sim's joints and a gripper), its front and side cameras, an image ACT that reads
both by name and acts in seven dimensions, and s = (E(I_front), E(I_side), q) through a frozen timm network
whose weights this test makes from a seed. finetune-base (the policy as given), warmup, train with the
scripted operator, handoff, stage 2's warmup, train and evaluate-all, then `accrue report`; a stage whose
cameras differ from the learner it inherits is refused in one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from fake_arms import GRIPPER
from robot_workflow import cli_report_json, robot_events, run_stage

from accrue.robot.sim_robot.accrue_sim import JOINT_KEYS
from accrue.sim import STATE_NAMES

pytestmark = pytest.mark.slow  # three stages of robot episodes and a learner process each: about a minute

ROOT = Path(__file__).resolve().parents[1]
ENCODER = "test_efficientnet"  # timm's small test network (256 features), random weights from a seed
CAMERAS = ("front", "side")
KEYS = (*JOINT_KEYS, GRIPPER)
Q_DIM = len(STATE_NAMES) + len(KEYS)  # the arm's readings: the sim's 29, its six joints and the gripper
BOUNDS = "[[-0.01, 0.01], [-0.01, 0.01], [-0.01, 0.03], [-0.2, 0.2], [-0.2, 0.2], [-0.5, 0.5], [0, 100]]"

WORKFLOW = """
name: any-arm
tasks: [nist/rect_peg, nist/round_peg]
method: accrue
seed: 0
horizon: 4
obs_mode: state+image
encoder: {encoder}
base_policy: {{init: {policy}, finetune: false}}
learner: {{algo: fasttd3, actor_hidden: [32, 32], critic_hidden: [32, 32], projector_dim: 16, batch_size: 16,
          utd: 1, beta: 10.0, std_max: 0.05}}
budgets: {{env_steps: 1000, eval_every: 1000, warmup_episodes: 2, retained_episodes: 2}}
robot:
  type: accrue_sim_gripper
  imports: [fake_arms]
  config: {{render_cameras: [front, side], image_size: 32, calibration_dir: {calib}, estimate_noise: 0.3}}
  action_mode: joint
  action_bounds: {bounds}
  done_key: episode.done
  episode_steps: 16
  control_hz: 40
  safety: {{max_step: {{z.pos: 0.0005}}}}
  stop_window: 3
  stop_successes: 3
  budget_s: 100
  max_episodes: 3
  retention_trials: 2
  checkpoint_every: 5
  publish_every: 2
  operator: scripted
  operator_name: scripted-test
  scripted: {{delay_s: 0.5}}
  handoff_wait_s: 120
  timeouts: {{observation_s: 10, reconnect_wait_s: 0.0}}
{task_config}"""


def two_camera_act(out: Path, size: int = 32, chunk: int = 4) -> Path:
    """A randomly initialised lerobot ACT reading the arm's q and both cameras by name, acting in 7-D."""
    import torch
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.act.modeling_act import ACTPolicy
    from lerobot.policies.factory import make_pre_post_processors

    torch.manual_seed(0)
    images = {f"observation.images.{c}": PolicyFeature(FeatureType.VISUAL, (3, size, size)) for c in CAMERAS}
    config = ACTConfig(
        input_features={"observation.state": PolicyFeature(FeatureType.STATE, (Q_DIM,)), **images},
        output_features={"action": PolicyFeature(FeatureType.ACTION, (len(KEYS),))},
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
        "observation.state": {"mean": torch.zeros(Q_DIM), "std": torch.ones(Q_DIM)},
        **{k: {"mean": torch.full((3, 1, 1), 0.5), "std": torch.full((3, 1, 1), 0.25)} for k in images},
        "action": {"mean": torch.zeros(len(KEYS)), "std": torch.full((len(KEYS),), 0.3)},
    }
    policy = ACTPolicy(config)
    pre, post = make_pre_post_processors(config, dataset_stats=stats)
    for part in (policy, pre, post):
        part.save_pretrained(out)
    return out


def seeded_encoder(path: Path, seed: int = 0) -> str:
    """A frozen timm network initialised from `seed`, saved as the file a lab's DINOv2 download would be."""
    import timm
    import torch
    from safetensors.torch import save_file

    torch.manual_seed(seed)
    save_file(timm.create_model(ENCODER, pretrained=False, num_classes=0).state_dict(), str(path))
    return f"{ENCODER}:{path}"


def write_workflow(root: Path, task_config: str = "") -> Path:
    path = root / "any-arm.yaml"
    path.write_text(
        WORKFLOW.format(
            encoder=(root / "encoder.txt").read_text(),
            policy=root / "act",
            calib=root / "calib",
            bounds=BOUNDS,
            task_config=task_config,
        )
    )
    return path


@pytest.fixture(scope="module")
def arm(tmp_path_factory):
    from artifacts.store import Store

    root = tmp_path_factory.mktemp("arm")
    (root / "encoder.txt").write_text(seeded_encoder(root / "encoder.safetensors"))
    two_camera_act(root / "act")
    Store.init(root / "store")
    wf = write_workflow(root)
    results = {k: run_stage(root / "store", wf, k) for k in (1, 2)}
    return root, wf, results


def materialized(root: Path, artifact_id: str, name: str) -> Path:
    from artifacts.manifests import materialize
    from artifacts.store import Store

    return materialize(Store.open(root / "store"), artifact_id, root / "out" / name)


def test_the_policy_reads_each_camera_by_name_and_acts_in_seven_dimensions(arm):
    from accrue.errors import AccrueError
    from accrue.policy import BasePolicy

    root, _, _ = arm
    policy = BasePolicy.load(root / "act")
    rng = np.random.default_rng(0)
    front, side = (rng.integers(0, 256, (1, 32, 32, 3), dtype=np.uint8) for _ in CAMERAS)
    q = np.zeros((1, Q_DIM), np.float32)

    def chunk(images, cameras=CAMERAS):
        obs = {"state": q, "images": images, "cameras": cameras, "image": images[0]}
        return policy.reference_chunk(obs, "insert", 4)

    first = chunk([front, side])
    assert first.shape == (1, 4, 7)
    assert not np.allclose(chunk([front, 255 - side]), first)  # the second camera is read too
    frames = policy._frames({"images": [side, front], "cameras": ("side", "front"), "image": side})
    assert frames["observation.images.front"] is front and frames["observation.images.side"] is side  # by name
    with pytest.raises(AccrueError, match="no camera 'side'") as info:
        chunk([front], ("front",))
    assert "\n" not in str(info.value)


def test_the_learner_reads_both_cameras_and_acts_in_the_arms_seven_keys(arm):
    from accrue.encoders import make_encoder
    from accrue.learner import ReplayBuffer, load_learner

    root, _, results = arm
    features = make_encoder((root / "encoder.txt").read_text()).feature_dim
    layout = {"action_keys": list(KEYS), "cameras": list(CAMERAS)}
    replay = ReplayBuffer.load(materialized(root, results[1]["train"].outputs["replay"], "replay1"))
    assert (replay.state_dim, replay.action_dim) == (2 * features + Q_DIM, 7) and replay.layout == layout
    s = replay.column("state").numpy()
    front, side = s[:, :features], s[:, features : 2 * features]
    assert np.abs(front).sum() > 0 and not np.allclose(front, side)  # two views, two different E(I)
    assert len(np.unique(front.round(4), axis=0)) > 1  # E(I) follows the scene
    assert np.abs(replay.column("action").numpy()[..., 6]).sum() > 0  # the gripper's column is acted in

    checkpoint = materialized(root, results[1]["train"].outputs["checkpoint"], "ckpt1")
    assert json.loads((checkpoint / "checkpoint.json").read_text())["layout"] == layout
    learner = load_learner(checkpoint / "learner")
    assert (learner.state_dim, learner.action_dim, learner.layout) == (2 * features + Q_DIM, 7, layout)
    assert learner.counters["updates"] > 0  # it trained on the robot's E(I) features
    handoff = materialized(root, results[1]["handoff"].outputs["handoff"], "handoff1")
    assert load_learner(handoff / "learner").layout == layout
    assert ReplayBuffer.load(handoff / "memory").layout == layout
    a = learner.act(s[:2], replay.column("ref").numpy()[:2], explore=False)
    assert np.asarray(a).shape == (2, 4, 7)

    sealed = robot_events(root / "store", "robot-episode-sealed")
    train = [e["weights_version"] or 0 for e in sealed if e["phase"] == "train" and e["stage"] == 1]
    assert max(train) >= 2, train  # an episode acted on weights the learner had updated


def test_stage_two_evaluates_and_reports_on_the_same_arm(arm):
    root, wf, results = arm
    ev = json.loads((materialized(root, results[2]["evaluate-all"].outputs["eval"], "eval2") / "eval.json").read_text())
    assert list(ev["trials"]) == ["nist/rect_peg"] and len(ev["trials"]["nist/rect_peg"]) == 2
    summary = cli_report_json(root / "store", wf, root / "report")
    assert summary["stages"]["2"]["updates"] > 0 and (root / "report" / "fig4.png").is_file()


def test_a_stage_with_other_cameras_than_the_learner_it_inherits_is_refused(arm):
    """Task 2 reads its cameras in another order (robot.task_config keys stage 2 alone): its warmup runs,
    and train refuses before the robot moves for it, in one line naming both layouts."""
    from stages.errors import StageError

    root, _, _ = arm
    swapped = "  task_config:\n    nist/round_peg: {render_cameras: [side, front]}\n"
    wf = write_workflow(root, swapped)
    with pytest.raises(StageError, match=r"cameras \[side, front\].*cameras \[front, side\]") as info:
        run_stage(root / "store", wf, 2)
    assert "\n" not in str(info.value) and "a stage cannot change them" in str(info.value)
