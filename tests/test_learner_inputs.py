"""Opt-in learner inputs for a contact skill: control-step history, a fixed-scale geometry descriptor that
the normaliser passes through, and their wiring from the workflow; the defaults keep today's s."""

from pathlib import Path

import numpy as np
import pytest
import torch

from accrue.errors import AccrueError
from accrue.learner import LearnerConfig
from accrue.learner.networks import RunningNorm
from accrue.learner_inputs import GEOMETRY_NAMES, geometry_descriptor, per_task_features
from accrue.sim import STATE_DIM, list_tasks, make_expert, make_vec_env
from accrue.sim.observation import HISTORY_DIM, HISTORY_STEPS
from artifacts.store import Store
from stages.plan import apply_budget, plan_stage
from stages.workflow import load_workflow

WORKFLOWS = Path(__file__).resolve().parents[1] / "workflows"
TASK = "contact/round_peg"


def _rollout(task_id, steps, n=3, seed=2):
    env = make_vec_env(task_id, num_envs=n, seed=seed)
    expert = make_expert(task_id)
    obs = env.reset()
    first = obs
    act = None
    for _ in range(steps):
        act = expert.act(obs["state"])
        obs = env.step(act).obs
    return first, obs, act


def test_defaults_give_todays_state():
    _, obs, _ = _rollout("nist/rect_peg", 3)
    s = per_task_features("none", 0, ["nist/rect_peg"])["nist/rect_peg"](obs)
    np.testing.assert_array_equal(s, obs["state"])


def test_history_holds_the_last_control_steps_newest_first():
    first, obs, act = _rollout(TASK, 6)
    f = per_task_features("none", 0, [TASK], history=4)[TASK]
    assert not f(first)[:, STATE_DIM:].any()  # nothing before the episode's first step
    s = f(obs)
    assert s.shape == (3, STATE_DIM + 4 * HISTORY_DIM)
    newest = s[:, STATE_DIM : STATE_DIM + HISTORY_DIM]
    np.testing.assert_array_equal(newest[:, :6], obs["state"][:, 13:19])  # wrist force/torque of this step
    np.testing.assert_array_equal(newest[:, 6:9], obs["state"][:, 25:28])  # socket estimate - tip
    np.testing.assert_array_equal(newest[:, 9:], act)  # the action that led here
    with pytest.raises(AccrueError):
        per_task_features("none", 0, [TASK], history=HISTORY_STEPS + 1)


def test_geometry_descriptor_is_last_fixed_scaled_and_tells_the_family_apart():
    _, obs, _ = _rollout(TASK, 1)
    contact = list_tasks("contact")
    feats = per_task_features("none", 0, contact, history=2, descriptor="geometry")
    codes = {t: feats[t](obs)[:, -len(GEOMETRY_NAMES) :] for t in contact}
    for t, code in codes.items():
        np.testing.assert_array_equal(code, np.broadcast_to(geometry_descriptor(t), code.shape))
    assert len({tuple(c[0]) for c in codes.values()}) == len(contact)
    # a fixed scale every built-in part lands within: a part left out of training is not out of range
    assert max(np.abs(geometry_descriptor(t)).max() for t in list_tasks()) <= 2.0
    with pytest.raises(AccrueError):
        per_task_features("none", 0, [TASK], descriptor="hashed")


def test_a_descriptor_constant_in_stage_one_is_not_blown_up_at_stage_two():
    # stage 1 sees one task: its descriptor columns have zero variance; stage 2's descriptor must arrive as
    # itself (fixed tail), where the plain floored standardisation sends it to the clip
    torch.manual_seed(0)
    stage1 = torch.randn(256, 6)
    stage1[:, 4:] = torch.tensor([-1.0, 0.5])
    stage2 = torch.cat([torch.randn(1, 4), torch.tensor([[1.0, -1.0]])], dim=1)
    today = RunningNorm(6, min_std=0.1, clip=10.0)
    fixed = RunningNorm(6, min_std=0.1, clip=10.0, fixed_tail=2)
    for norm in (today, fixed):
        norm.update(stage1)
        norm.freeze()
    assert today(stage2)[0, 4:].abs().min() == 10.0
    np.testing.assert_array_equal(fixed(stage2)[0, 4:].numpy(), [1.0, -1.0])
    np.testing.assert_array_equal(fixed(stage2)[0, :4].numpy(), today(stage2)[0, :4].numpy())
    assert set(fixed.state_dict()) == set(today.state_dict())  # checkpoints keep their keys


def test_the_learner_builds_its_normaliser_with_the_fixed_tail():
    from accrue.learner.agent import ChunkLearner

    cfg = LearnerConfig(obs_norm_fixed_tail=4, actor_hidden=[16], critic_hidden=[16], projector_dim=8)
    cfg.validate()
    assert ChunkLearner(cfg, state_dim=12, horizon=2).actor.obs_norm.fixed_tail == 4
    with pytest.raises(AccrueError):
        LearnerConfig(obs_norm_fixed_tail=-1).validate()


def test_contact_workflow_turns_the_inputs_on_and_demos_come_from_the_limited_demonstrator(tmp_path):
    store = Store.init(tmp_path / "store")[0]
    wf = load_workflow(WORKFLOWS / "contact-quickstart.yaml")
    assert wf.tasks == ["contact/round_peg", "contact/keyed_peg", "contact/gear_mesh"]
    for k in range(1, wf.num_stages + 1):
        plan_stage(apply_budget(wf, "0.01"), k, store)
    steps = {inv.step.name: inv.config for inv in plan_stage(wf, 1, store).steps}
    assert steps["record-demos"]["search"] is False
    assert steps["train"]["history"] == 4 and steps["train"]["task_descriptor"] == "geometry"
    assert steps["train"]["learner"]["obs_norm_fixed_tail"] == len(GEOMETRY_NAMES)
    # existing workflows: none of the new keys, so their cache keys stay as they were
    old = {
        inv.step.name: inv.config for inv in plan_stage(load_workflow(WORKFLOWS / "quickstart.yaml"), 1, store).steps
    }
    for name in ("warmup", "train", "evaluate-all"):
        assert "history" not in old[name] and "task_descriptor" not in old[name]
    assert "obs_norm_fixed_tail" not in old["train"]["learner"]
