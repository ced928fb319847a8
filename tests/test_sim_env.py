"""Vectorised env: determinism, chunk == single steps, per-env reset, rewards, success detection."""

import numpy as np
import pytest

from accrue.errors import AccrueError
from accrue.sim import STATE_DIM, make_expert, make_vec_env
from accrue.sim.observation import FORCE_SCALE, IDX
from accrue.sim.tasks import DEG, MM, get_task
from accrue.sim.vec_env import is_success


def _random_actions(n, h, seed):
    return np.random.default_rng(seed).uniform(-1, 1, (n, h, 6)).astype(np.float32)


def test_reset_shapes_and_dtype():
    env = make_vec_env("plugs/hexagon", num_envs=3, seed=0)
    obs = env.reset()
    assert obs["state"].shape == (3, STATE_DIM) and obs["state"].dtype == np.float32
    assert np.isfinite(obs["state"]).all()
    assert not np.allclose(obs["state"][0], obs["state"][1])  # envs are randomised differently


def test_fixed_seed_is_bit_identical_and_seed_matters():
    runs = []
    for seed in (7, 7, 8):
        env = make_vec_env("nist/rect_peg", num_envs=4, seed=seed)
        states = [env.reset()["state"]]
        for k in range(4):
            states.append(env.step_chunk(_random_actions(4, 5, k), gamma=0.9).obs["state"])
        runs.append(np.stack(states))
    assert np.array_equal(runs[0], runs[1])
    assert not np.array_equal(runs[0], runs[2])


def test_thread_count_does_not_change_results():
    finals = []
    for threads in (1, 2):
        env = make_vec_env("plugs/star", num_envs=5, seed=4, nthread=threads)
        env.reset()
        finals.append(env.step_chunk(_random_actions(5, 8, 9), 0.9).obs["state"])
    assert np.array_equal(finals[0], finals[1])


def test_chunk_equals_h_single_steps():
    h, gamma = 6, 0.9
    a = make_vec_env("plugs/cross", num_envs=3, seed=3)
    b = make_vec_env("plugs/cross", num_envs=3, seed=3)
    a.reset(), b.reset()
    acts = _random_actions(3, h, 11)
    acts[:, :, 2] = -1.0  # push down so contacts happen inside the chunk
    res = a.step_chunk(acts, gamma)
    singles = [b.step(acts[:, k]) for k in range(h)]
    assert np.array_equal(res.obs["state"], singles[-1].obs["state"])
    assert np.array_equal(a._qpos, b._qpos)
    per_step = np.concatenate([s.rewards for s in singles], axis=1)
    assert np.array_equal(res.rewards, per_step)
    assert np.allclose(res.reward, per_step @ gamma ** np.arange(h))
    assert np.array_equal(res.steps, np.full(3, h))


def test_per_env_reset_leaves_other_envs_untouched():
    acts = _random_actions(2, 3, 5)
    a = make_vec_env("plugs/star", num_envs=2, seed=1)
    b = make_vec_env("plugs/star", num_envs=2, seed=1)
    a.reset(), b.reset()
    a.step_chunk(acts, 1.0), b.step_chunk(acts, 1.0)
    obs_a = a.reset(np.array([False, True]))
    assert a.episode.tolist() == [0, 1] and a.t.tolist() == [3, 0]
    assert np.array_equal(obs_a["state"][0], b.step_chunk(np.zeros((2, 0, 6)), 1.0).obs["state"][0])
    ra, rb = a.step_chunk(acts, 1.0), b.step_chunk(acts, 1.0)
    assert np.array_equal(ra.obs["state"][0], rb.obs["state"][0])  # env 0 unaffected by env 1's reset
    assert not np.array_equal(ra.obs["state"][1], rb.obs["state"][1])


def test_success_terminates_and_last_three_steps_carry_reward():
    env = make_vec_env("plugs/triangle", num_envs=4, seed=2)
    expert = make_expert("plugs/triangle", 1.0, seed=0)
    obs = env.reset()
    rewards, done = np.zeros((4, 0)), np.zeros(4, bool)
    for _ in range(env.task.max_steps):
        res = env.step(expert.act(obs["state"]))
        obs, rewards, done = res.obs, np.concatenate([rewards, res.rewards], axis=1), done | res.done
        if done.all():
            break
    assert done.all()
    assert env.done.all()
    won = np.flatnonzero([r.any() for r in rewards])
    assert len(won) >= 3
    for i in won:  # H=1 steps: only the success step itself is inside the call
        assert rewards[i].sum() == 1.0
    # once done, a chunk executes nothing and pays nothing
    res = env.step_chunk(np.zeros((4, 50, 6), dtype=np.float32), 0.9)
    assert res.steps.sum() == 0 and res.rewards.sum() == 0


def test_final_three_steps_labelled_inside_a_chunk():
    task = get_task("plugs/hexagon")
    env = make_vec_env(task.task_id, num_envs=1, seed=0)
    env.reset()
    # start right above an aligned socket so a straight push succeeds inside one chunk
    env._qpos[0] = [0.0, 0.0, -task.depth + 7 * MM, 0.0, 0.0, 0.0]
    env.target[0] = env._qpos[0]
    env.batch.forward()
    acts = np.zeros((1, 10, 6), dtype=np.float32)
    acts[0, :, 2] = -1.0
    res = env.step_chunk(acts, 0.5)
    assert res.success[0] and res.terminated[0] and not res.truncated[0]
    k = int(res.steps[0])
    assert k >= 3
    assert res.rewards[0].tolist() == [0.0] * (k - 3) + [1.0] * 3 + [0.0] * (10 - k)
    assert res.reward[0] == pytest.approx(sum(0.5**j for j in range(k - 3, k)))


def test_time_limit_truncates():
    env = make_vec_env("nist/round_peg", num_envs=2, seed=0)
    env.reset()
    up = np.zeros((2, env.task.max_steps + 5, 6), dtype=np.float32)
    up[:, :, 2] = 1.0  # move away: never succeeds
    res = env.step_chunk(up, 1.0)
    assert res.truncated.all() and not res.terminated.any()
    assert res.steps.tolist() == [env.task.max_steps] * 2


@pytest.mark.parametrize("case", ["partial", "wrong_yaw", "off_centre", "tilted"])
def test_success_rejects_near_misses(case):
    task = get_task("plugs/cross")
    good = np.array([[0.0, 0.0, -task.depth, 0.0, 0.0, 0.0]])
    assert is_success(task, good)[0]
    bad = good.copy()
    if case == "partial":
        bad[0, 2] = -task.depth + 3 * MM
    elif case == "wrong_yaw":
        bad[0, 5] = 45 * DEG  # a cross is 4-fold: 45 degrees is the worst orientation
    elif case == "off_centre":
        bad[0, 0] = 2 * MM
    else:
        bad[0, 3] = 8 * DEG
    assert not is_success(task, bad)[0]
    assert is_success(task, good + [[0, 0, 0, 0, 0, 90 * DEG]])[0]  # symmetric equivalent is fine


def test_plug_resting_on_socket_is_not_a_success():
    task = get_task("nist/rect_peg")
    env = make_vec_env(task.task_id, num_envs=1, seed=0)
    env.reset()
    env._qpos[0] = [2.5 * MM, 0.0, 2 * MM, 0.0, 0.0, 0.0]  # beside the hole: lands on the rim
    env.target[0] = env._qpos[0]
    acts = np.zeros((1, 20, 6), dtype=np.float32)
    acts[0, :, 2] = -1.0
    res = env.step_chunk(acts, 1.0)
    assert not res.success[0]
    assert -1.5 * MM < env._qpos[0, 2] < 0.5 * MM  # it sits on the rim/chamfer, not in the hole
    force_z = res.obs["state"][0, IDX["wrist_fz"]] / FORCE_SCALE
    assert abs(force_z) > 1.0  # and the wrist feels it


def test_bad_inputs_raise_one_line_errors():
    with pytest.raises(AccrueError) as e:
        make_vec_env("plugs/no_such_plug", num_envs=1)
    assert "\n" not in str(e.value) and "plugs/no_such_plug" in str(e.value)
    env = make_vec_env("plugs/cross", num_envs=2)
    env.reset()
    with pytest.raises(AccrueError):
        env.step_chunk(np.zeros((3, 2, 6)), 0.9)
    with pytest.raises(AccrueError):
        make_vec_env("plugs/cross", num_envs=1, obs_mode="pixels")


def test_image_observations():
    env = make_vec_env("plugs/l_shape", num_envs=2, seed=0, obs_mode="state+image", image_size=64)
    obs = env.reset()
    img = obs["image"]
    assert img.shape == (2, 64, 64, 3) and img.dtype == np.uint8
    assert img.std() > 5  # a real scene, not a blank frame
    acts = np.zeros((2, 5, 6), dtype=np.float32)
    acts[:, :, 2] = -1.0
    moved = env.step_chunk(acts, 0.9).obs["image"]
    assert moved.shape == img.shape and not np.array_equal(moved, img)


def test_gymnasium_wrapper_passes_checker():
    from gymnasium.utils.env_checker import check_env

    from accrue.sim.gym_env import AssemblyEnv

    env = AssemblyEnv("plugs/d_shape")
    check_env(env, skip_render_check=True)
    obs, _ = env.reset(seed=3)
    assert obs.shape == (STATE_DIM,)
    obs2, reward, terminated, truncated, info = env.step(np.zeros(6, dtype=np.float32))
    assert obs2.shape == (STATE_DIM,) and reward == 0.0 and "success" in info


def test_gymnasium_registered_ids():
    import gymnasium as gym

    from accrue.sim.gym_env import register_gym_ids

    register_gym_ids()
    env = gym.make("accrue/plugs-twin_pins-v0")
    obs, _ = env.reset(seed=0)
    assert obs.shape == (STATE_DIM,) and env.unwrapped.task.task_id == "plugs/twin_pins"
