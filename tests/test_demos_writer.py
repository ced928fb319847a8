"""Demo writing logic against a tiny fake simulator: kept/dropped episodes, retries, lengths, validation.

The fake follows the accrue.sim contract (docs/INTERFACES.md) so the writer's bookkeeping can be
checked exactly; tests/test_demos_sim.py runs the same writer on the real simulator.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from accrue.errors import AccrueError
from accrue.sim import demos

STATE_NAMES = ["x", "y", "z", "fz", "t"]


@dataclass
class _Step:
    obs: dict
    reward: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    success: np.ndarray


class FakeVecEnv:
    """Episodes of 3..6 steps; success drawn per episode with probability `p_success`.

    state = [episode serial, 0, 0, 0, step]: the serial says which episode a frame came from.
    """

    def __init__(self, num_envs: int, seed: int, obs_mode: str, p_success: float, image_hw: tuple[int, int]) -> None:
        self.n, self.obs_mode, self.p, self.image_hw = num_envs, obs_mode, p_success, image_hw
        self.rng = np.random.default_rng(seed)
        self.serial = 0
        self.ep = np.zeros(num_envs, int)
        self.t = np.zeros(num_envs, int)
        self.length = np.zeros(num_envs, int)
        self.will_succeed = np.zeros(num_envs, bool)
        self.log: list[tuple[int, int, bool]] = []  # (serial, length, success) of every episode begun

    def _begin(self, i: int) -> None:
        self.ep[i], self.t[i] = self.serial, 0
        self.length[i] = self.rng.integers(3, 7)
        self.will_succeed[i] = self.rng.random() < self.p
        self.log.append((self.serial, int(self.length[i]), bool(self.will_succeed[i])))
        self.serial += 1

    def _obs(self) -> dict:
        state = np.zeros((self.n, len(STATE_NAMES)), np.float32)
        state[:, 0], state[:, 4] = self.ep, self.t
        obs = {"state": state}
        if self.obs_mode == "state+image":
            obs["image"] = np.broadcast_to(
                (self.ep % 256).astype(np.uint8)[:, None, None, None], (self.n, *self.image_hw, 3)
            ).copy()
        return obs

    def reset(self, mask: np.ndarray | None = None) -> dict:
        for i in range(self.n):
            if mask is None or mask[i]:
                self._begin(i)
        return self._obs()

    def step(self, actions: np.ndarray) -> _Step:
        assert actions.shape == (self.n, 6) and np.abs(actions).max() <= 1.0
        self.t += 1
        end = self.t >= self.length
        success = end & self.will_succeed
        return _Step(self._obs(), success.astype(np.float32), success, end & ~self.will_succeed, success)


def fake_sim(p_success: float = 1.0, image_hw: tuple[int, int] = (8, 10)) -> SimpleNamespace:
    envs: list[FakeVecEnv] = []
    spec = SimpleNamespace(
        task_id="fake/peg",
        family="fake",
        instruction="insert the fake peg",
        control_hz=20.0,
        max_steps=6,
        clearance=0.0003,
    )

    def get_task(task_id: str):
        if task_id != "fake/peg":
            raise AccrueError(f"unknown task id {task_id!r}")
        return spec

    def make_vec_env(task_id: str, num_envs: int, seed: int, obs_mode: str) -> FakeVecEnv:
        envs.append(FakeVecEnv(num_envs, seed, obs_mode, p_success, image_hw))
        return envs[-1]

    expert = SimpleNamespace(act=lambda state: np.full((len(state), 6), 2.0, np.float32))  # clipped by writer
    return SimpleNamespace(
        get_task=get_task,
        make_vec_env=make_vec_env,
        list_tasks=lambda: ["fake/peg"],
        make_expert=lambda task_id, quality, seed, **kind: expert,
        STATE_NAMES=STATE_NAMES,
        STATE_DIM=len(STATE_NAMES),
        ACTION_DIM=6,
        envs=envs,
    )


def _frames(root: Path):
    import pandas as pd

    return pd.concat(pd.read_parquet(p) for p in sorted((root / "data").rglob("*.parquet")))


def test_only_successes_kept_with_retries(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    sim = fake_sim(p_success=0.5)
    monkeypatch.setattr(demos, "_sim_api", lambda: sim)
    out = tmp_path / "demos"
    summary = demos.write_demos("fake/peg", 5, out, seed=3, progress=False, num_envs=3)
    log = sim.envs[0].log
    assert summary.complete and summary.episodes == 5
    # every kept episode was a success; attempts counts finished expert episodes, successes among them
    df = _frames(out)
    kept = sorted(set(df["observation.state"].map(lambda s: int(s[0]))))
    assert all(log[s][2] for s in kept) and len(kept) == 5
    assert summary.frames == len(df) == sum(log[s][1] for s in kept)
    assert summary.successes >= 5 and summary.attempts > summary.successes
    assert summary.expert_success_rate == pytest.approx(summary.successes / summary.attempts)
    # per-episode frame layout: done and success only on the last frame, reward follows success
    for _, ep in df.groupby("episode_index"):
        assert list(ep["frame_index"]) == list(range(len(ep)))
        assert list(ep["next.done"]) == [False] * (len(ep) - 1) + [True]
        assert list(ep["next.success"]) == list(ep["next.done"])
        assert list(ep["next.reward"]) == [0.0] * (len(ep) - 3) + [1.0] * 3  # the success tail
        assert [int(s[4]) for s in ep["observation.state"]] == list(range(len(ep)))  # obs before the action
    assert np.allclose(np.stack(df["action"]), 1.0)  # expert output clipped to [-1, 1]
    meta = json.loads((out / "meta" / "accrue.json").read_text())
    assert meta["task_id"] == "fake/peg" and meta["instruction"] == "insert the fake peg"
    assert meta["attempts"] == summary.attempts and meta["state_names"] == STATE_NAMES


def test_failures_kept_when_asked(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    sim = fake_sim(p_success=0.0)
    monkeypatch.setattr(demos, "_sim_api", lambda: sim)
    summary = demos.write_demos("fake/peg", 4, tmp_path / "d", only_successful=False, progress=False, num_envs=2)
    assert (summary.episodes, summary.attempts, summary.successes) == (4, 4, 0)
    df = _frames(tmp_path / "d")
    assert not df["next.success"].any() and df["next.done"].sum() == 4


def test_attempt_bound_gives_partial_dataset_or_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(demos, "_sim_api", lambda: fake_sim(p_success=0.0))
    with pytest.raises(AccrueError, match="succeeded in none of 6 episodes"):
        demos.write_demos("fake/peg", 2, tmp_path / "none", max_attempts=6, progress=False)
    assert not (tmp_path / "none").exists()

    sim = fake_sim(p_success=0.5)
    monkeypatch.setattr(demos, "_sim_api", lambda: sim)
    summary = demos.write_demos("fake/peg", 50, tmp_path / "some", seed=1, max_attempts=10, progress=False)
    assert summary.attempts == 10 and not summary.complete
    assert summary.episodes == summary.successes == sum(s for _, _, s in sim.envs[0].log[:10])
    info = demos.read_demo_info(tmp_path / "some", state_dim=5)
    assert info.num_episodes == summary.episodes


def test_images_and_info(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(demos, "_sim_api", lambda: fake_sim())
    # frames too small for the video encoder are stored as images even though video was asked for
    demos.write_demos("fake/peg", 2, tmp_path / "img", obs_mode="state+image", use_video=True, progress=False)
    task_id, instruction, n, features = demos.read_demo_info(tmp_path / "img")
    assert (task_id, instruction, n) == ("fake/peg", "insert the fake peg", 2)
    assert features["observation.images.wrist"]["dtype"] == "image"
    assert features["observation.images.wrist"]["shape"] == [8, 10, 3]
    assert features["observation.state"]["names"] == STATE_NAMES


def test_refuses_nonempty_out_dir_and_bad_args(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(demos, "_sim_api", lambda: fake_sim())
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "keep.txt").write_text("mine")
    with pytest.raises(AccrueError, match="exists and is not empty"):
        demos.write_demos("fake/peg", 1, tmp_path / "full", progress=False)
    assert (tmp_path / "full" / "keep.txt").read_text() == "mine"
    with pytest.raises(AccrueError, match="unknown task id 'nope/x'"):
        demos.write_demos("nope/x", 1, tmp_path / "a", progress=False)
    with pytest.raises(AccrueError, match="obs_mode"):
        demos.write_demos("fake/peg", 1, tmp_path / "b", obs_mode="pixels", progress=False)
    (tmp_path / "empty").mkdir()  # an existing empty directory is fine
    assert demos.write_demos("fake/peg", 1, tmp_path / "empty", progress=False).episodes == 1


def _edit_info(root: Path, change) -> None:
    path = root / "meta" / "info.json"
    info = json.loads(path.read_text())
    change(info["features"])
    path.write_text(json.dumps(info))


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda f: f.pop("action"), "lacks feature 'action'"),
        (
            lambda f: f["observation.state"].update(shape=[7]),
            r"feature 'observation.state' has shape \[7\], expected \[5\]",
        ),
        (lambda f: f["next.reward"].update(dtype="float64"), "feature 'next.reward' has dtype float64"),
        (lambda f: f.pop("next.success"), "lacks feature 'next.success'"),
    ],
)
def test_read_demo_info_names_the_wrong_feature(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, change, message
) -> None:
    monkeypatch.setattr(demos, "_sim_api", lambda: fake_sim())
    root = tmp_path / "d"
    demos.write_demos("fake/peg", 1, root, progress=False)
    _edit_info(root, change)
    with pytest.raises(AccrueError, match=message) as err:
        demos.read_demo_info(root)
    assert "\n" not in str(err.value)


def test_read_demo_info_rejects_other_format_versions(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(demos, "_sim_api", lambda: fake_sim())
    demos.write_demos("fake/peg", 1, tmp_path / "d", progress=False)
    path = tmp_path / "d" / "meta" / "info.json"
    path.write_text(path.read_text().replace('"v3.0"', '"v2.1"'))
    with pytest.raises(AccrueError, match="is LeRobotDataset v2.1; accrue reads v3.0"):
        demos.read_demo_info(tmp_path / "d")


def test_read_demo_info_needs_a_dataset_and_the_task_record(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(demos, "_sim_api", lambda: fake_sim())
    with pytest.raises(AccrueError, match="not a LeRobot dataset"):
        demos.read_demo_info(tmp_path)
    demos.write_demos("fake/peg", 1, tmp_path / "d", progress=False)
    (tmp_path / "d" / "meta" / "accrue.json").unlink()
    with pytest.raises(AccrueError, match="accrue task is unknown"):
        demos.read_demo_info(tmp_path / "d")


def test_interrupted_run_leaves_nothing_behind(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    sim = fake_sim()
    calls = {"n": 0}

    def act(state):
        calls["n"] += 1
        if calls["n"] == 9:  # some episodes are already saved by then
            raise KeyboardInterrupt
        return np.zeros((len(state), 6), np.float32)

    sim.make_expert = lambda task_id, quality, seed, **kind: SimpleNamespace(act=act)
    monkeypatch.setattr(demos, "_sim_api", lambda: sim)
    with pytest.raises(KeyboardInterrupt):
        demos.write_demos("fake/peg", 5, tmp_path / "d", progress=False, num_envs=1)
    assert list(tmp_path.iterdir()) == []  # neither the dataset nor its staging directory


def test_staging_left_by_a_killed_run_is_cleaned(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import subprocess
    import sys

    monkeypatch.setattr(demos, "_sim_api", lambda: fake_sim())
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    stale = tmp_path / f".d.partial-{dead.stdout.strip()}"
    (stale / "meta").mkdir(parents=True)
    alive = tmp_path / f".d.partial-{os.getppid()}"  # a running process (our parent) may still be writing
    alive.mkdir()
    demos.write_demos("fake/peg", 1, tmp_path / "d", progress=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["d", alive.name])
