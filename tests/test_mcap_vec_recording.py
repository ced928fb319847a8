"""Recording a real vectorised accrue.sim loop (single steps and action chunks) as MCAP episodes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from accrue.logs.mcap_episodes import EpisodeRecorder, list_episodes, read_episode
from accrue.logs.sim_fields import euler_to_quat_xyzw, state_fields
from accrue.logs.vec_recording import VecEpisodeLogger

TASK = "plugs/cross"


def test_expert_steps_are_sealed_per_episode_with_labels(tmp_path: Path) -> None:
    from accrue.sim import get_task, make_expert, make_vec_env

    env = make_vec_env(TASK, num_envs=2, seed=4)
    expert = make_expert(TASK, seed=4)
    logger = VecEpisodeLogger(
        EpisodeRecorder(tmp_path, control_hz=get_task(TASK).control_hz), 2, {"task_id": TASK, "policy": "expert"}
    )
    obs = env.reset()
    logger.begin()
    ends: list[tuple[Path, bool, int]] = []  # (file, success, length) of each ended episode
    lengths = np.zeros(2, int)
    while len(ends) < 3:
        actions = expert.act(obs["state"])
        res = env.step(actions)
        lengths += 1
        sealed = logger.log(obs["state"], actions, res)
        assert len(sealed) == int(res.done.sum())
        for path, i in zip(sealed, np.flatnonzero(res.done)):  # both in env order
            ends.append((path, bool(res.success[i]), int(lengths[i])))
            lengths[i] = 0
        obs = env.reset(res.done) if res.done.any() else res.obs
        logger.begin(res.done)
    logger.close()
    assert sorted(p for p, _, _ in ends) == list_episodes(tmp_path)
    assert any(success for _, success, _ in ends)
    for path, success, length in ends:
        log = read_episode(path)
        assert len(log.messages["/state"]) == len(log.messages["/action"]) == length
        assert log.messages["/episode/label"][0]["success"] == success
        assert log.episode["task_id"] == TASK
        if success:
            assert log.messages["/reward"][-1]["reward"] == 1.0
        pose = log.messages["/ee/pose"][0]["pose"]["position"]
        assert pose["z"] == pytest.approx(state_fields(np.array(log.messages["/state"][0]["values"]))["ee_pose"][2])
    assert not any(p.name.endswith(".partial") for p in tmp_path.iterdir())  # close() dropped the unfinished ones


def test_chunks_log_every_executed_step_but_state_once(tmp_path: Path) -> None:
    from accrue.sim import get_task, make_vec_env

    spec = get_task(TASK)
    env = make_vec_env(TASK, num_envs=2, seed=1)
    logger = VecEpisodeLogger(EpisodeRecorder(tmp_path), 2, {"task_id": TASK})
    rng = np.random.default_rng(0)
    horizon = 7  # does not divide max_steps, so the last chunk of a truncated episode is cut short
    obs = env.reset()
    logger.begin()
    chunks_run = 0
    sealed: list[Path] = []
    while not sealed:
        chunk = rng.uniform(-0.3, 0.3, (2, horizon, 6)).astype(np.float32)
        reference = np.zeros((2, horizon, 6), np.float32)
        res = env.step_chunk(chunk, gamma=0.9)
        sealed += logger.log(obs["state"], chunk, res, reference=reference)
        chunks_run += 1
        obs = res.obs
    log = read_episode(sealed[0])
    length = json.loads(log.episode["length"])
    assert length == len(log.messages["/action"]) <= spec.max_steps
    assert len(log.messages["/state"]) == len(log.messages["/reference"]) == chunks_run
    assert [m["t"] for m in log.messages["/state"]] == list(range(0, length, horizon))
    assert [m["t"] for m in log.messages["/reward"]] == list(range(length))


def test_euler_quaternion_matches_rotation_order() -> None:
    q = euler_to_quat_xyzw(0.0, 0.0, np.pi / 2)
    assert q == pytest.approx([0, 0, np.sqrt(0.5), np.sqrt(0.5)])
    # R = Rz Ry Rx: rotate (1,0,0) by roll then pitch then yaw
    roll, pitch, yaw = 0.3, -0.2, 1.1
    x, y, z, w = euler_to_quat_xyzw(roll, pitch, yaw)
    rot = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    c, s = np.cos, np.sin
    rz = np.array([[c(yaw), -s(yaw), 0], [s(yaw), c(yaw), 0], [0, 0, 1]])
    ry = np.array([[c(pitch), 0, s(pitch)], [0, 1, 0], [-s(pitch), 0, c(pitch)]])
    rx = np.array([[1, 0, 0], [0, c(roll), -s(roll)], [0, s(roll), c(roll)]])
    assert rot == pytest.approx(rz @ ry @ rx)
