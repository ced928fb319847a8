"""MCAP episode logs: topics/schemas as documented, metadata, sealing, and crash safety."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from accrue.errors import AccrueError
from accrue.logs import mcap_episodes as me
from accrue.logs.mcap_episodes import EpisodeRecorder, list_episodes, read_episode


def _record(rec: EpisodeRecorder, env: int, steps: int, *, image: bool = False, success: bool = True) -> Path:
    rec.start(env, {"task_id": "plugs/cross", "seed": 7, "policy": "expert"})
    for t in range(steps):
        img = np.full((12, 16, 3), 40 * env + t, dtype=np.uint8) if image else None
        rec.log_step(
            env,
            t,
            state=np.arange(4) + t,
            action=np.full(6, 0.1 * env),
            reference=np.zeros((3, 6)) + t,
            reward=1.0 if t == steps - 1 else 0.0,
            image=img,
            ee_pose=[0.1, 0.2, 0.3 + t, 0, 0, 0, 1],
            socket_pose=[0.0, 0.0, 0.0],
            wrench=[1, 2, 3, 4, 5, 6],
        )
    return rec.end(env, success=success)


def test_topics_schema_names_and_metadata(tmp_path: Path) -> None:
    with EpisodeRecorder(tmp_path, control_hz=20, state_names=["a", "b", "c", "d"], image_format="png") as rec:
        path = _record(rec, 0, 5, image=True)
    assert path.name == "episode-000000.mcap"
    log = read_episode(path)
    assert log.schemas == {
        "/state": "accrue.State",
        "/action": "accrue.Action",
        "/reward": "accrue.Reward",
        "/reference": "accrue.ReferenceChunk",
        "/ee/pose": "foxglove.PoseInFrame",
        "/socket/pose": "foxglove.PoseInFrame",
        "/wrist/wrench": "accrue.Wrench",
        "/camera/wrist": "foxglove.CompressedImage",
        "/episode/label": "accrue.EpisodeLabel",
    }
    assert log.schemas == {t: me.SCHEMA_NAMES[t] for t in log.schemas}
    assert [m["t"] for m in log.messages["/state"]] == [0, 1, 2, 3, 4]
    assert log.messages["/state"][2]["values"] == [2.0, 3.0, 4.0, 5.0]
    assert log.messages["/reward"][-1] == {"t": 4, "reward": 1.0, "return": 1.0}
    assert np.array(log.messages["/reference"][1]["chunk"]).shape == (3, 6)
    pose = log.messages["/ee/pose"][3]
    assert pose["frame_id"] == "world" and pose["pose"]["position"]["z"] == pytest.approx(3.3)
    assert pose["timestamp"] == {"sec": 0, "nsec": 150_000_000}  # step 3 at 20 Hz
    assert log.messages["/wrist/wrench"][0]["torque"] == {"x": 4.0, "y": 5.0, "z": 6.0}
    assert log.messages["/camera/wrist"][0]["format"] == "png"
    assert (log.image(4) == 4).all()  # png is lossless: the pixels come back exactly
    assert json.loads(log.channel_metadata["/state"]["state_names"]) == ["a", "b", "c", "d"]
    assert log.messages["/episode/label"] == [{"success": True, "length": 5, "return": 1.0, "truncated": False}]
    ep = log.episode
    assert ep["task_id"] == "plugs/cross" and json.loads(ep["seed"]) == 7 and ep["policy"] == "expert"
    assert json.loads(ep["success"]) is True and json.loads(ep["length"]) == 5


def test_optional_topics_absent_and_rotation_vector_pose(tmp_path: Path) -> None:
    rec = EpisodeRecorder(tmp_path)
    rec.start(0)
    rec.log_step(0, 0, state=[0.0], action=np.zeros(6), ee_pose=[0, 0, 0, 0, 0, np.pi])
    log = read_episode(rec.end(0, success=False, truncated=True))
    assert set(log.messages) == {"/state", "/action", "/reward", "/ee/pose", "/episode/label"}
    named = EpisodeRecorder(tmp_path / "front", camera="front")
    named.start(0)
    named.log_step(0, 0, state=[0.0], action=np.zeros(6), image=np.zeros((4, 4, 3), np.uint8))
    front = read_episode(named.end(0, success=True))
    assert front.schemas["/camera/front"] == "foxglove.CompressedImage"
    assert front.messages["/camera/front"][0]["frame_id"] == "front_camera"
    with pytest.raises(AccrueError, match="camera name"):
        EpisodeRecorder(tmp_path, camera="../x")
    q = log.messages["/ee/pose"][0]["pose"]["orientation"]
    assert q["z"] == pytest.approx(1.0) and q["w"] == pytest.approx(0.0, abs=1e-9)
    assert log.messages["/episode/label"][0]["truncated"] is True


def test_interleaved_envs_get_separate_files_in_start_order(tmp_path: Path) -> None:
    rec = EpisodeRecorder(tmp_path)
    rec.start(0, {"policy": "a"})
    rec.start(1, {"policy": "b"})
    for t in range(3):
        rec.log_step(1, t, [t], np.zeros(6))
        rec.log_step(0, t, [10 + t], np.zeros(6))
    p1 = rec.end(1, success=True)
    rec.log_step(0, 3, [13], np.zeros(6))
    p0 = rec.end(0, success=False)
    assert (p0.name, p1.name) == ("episode-000000.mcap", "episode-000001.mcap")
    assert [m["values"][0] for m in read_episode(p0).messages["/state"]] == [10, 11, 12, 13]
    assert read_episode(p1).episode["policy"] == "b"
    assert list_episodes(tmp_path) == [p0, p1]
    # a new recorder in the same directory continues the numbering instead of overwriting
    rec2 = EpisodeRecorder(tmp_path)
    rec2.start(0)
    rec2.log_step(0, 0, [0], np.zeros(6))
    assert rec2.end(0, success=True).name == "episode-000002.mcap"


def test_unsealed_episode_never_appears_under_final_name(tmp_path: Path) -> None:
    rec = EpisodeRecorder(tmp_path)
    rec.start(0)
    rec.log_step(0, 0, [0], np.zeros(6))
    assert list_episodes(tmp_path) == []
    assert [p.name for p in tmp_path.iterdir()] == [".episode-000000.mcap.partial"]
    rec.close()
    assert list(tmp_path.iterdir()) == []


def test_misuse_is_a_one_line_error(tmp_path: Path) -> None:
    rec = EpisodeRecorder(tmp_path)
    with pytest.raises(AccrueError, match="before start"):
        rec.log_step(3, 0, [0], np.zeros(6))
    with pytest.raises(AccrueError, match="no episode in progress"):
        rec.end(3, success=True)
    rec.start(0)
    rec.log_step(0, 2, [0], np.zeros(6))
    with pytest.raises(AccrueError, match="step 2 logged after step 2"):
        rec.log_step(0, 2, [0], np.zeros(6))
    (tmp_path / "episode-000099.mcap").write_bytes(b"not an mcap file at all")
    with pytest.raises(AccrueError, match="episode-000099.mcap"):
        read_episode(tmp_path / "episode-000099.mcap")


_CRASHING_WRITER = textwrap.dedent(
    """
    import os, signal, sys
    import numpy as np
    from accrue.logs.mcap_episodes import EpisodeRecorder
    rec = EpisodeRecorder(sys.argv[1], control_hz=10)
    for ep in range(2):
        rec.start(0, {"episode_in_test": ep})
        for t in range(50):
            rec.log_step(0, t, np.ones(8) * t, np.zeros(6), reward=0.0, image=np.zeros((16, 16, 3), np.uint8))
        rec.end(0, success=True)
    rec.start(0, {"episode_in_test": 2})
    for t in range(5000):  # big enough that several chunks hit the disk before the crash
        rec.log_step(0, t, np.ones(8) * t, np.zeros(6), image=np.zeros((16, 16, 3), np.uint8))
    print("about to crash", flush=True)
    os.kill(os.getpid(), signal.SIGKILL)
    """
)


def test_killed_recorder_keeps_sealed_episodes_and_no_half_file(tmp_path: Path) -> None:
    out = tmp_path / "logs"
    proc = subprocess.run(
        [sys.executable, "-c", _CRASHING_WRITER, str(out)], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    assert "about to crash" in proc.stdout
    sealed = list_episodes(out)
    assert [p.name for p in sealed] == ["episode-000000.mcap", "episode-000001.mcap"]
    for i, path in enumerate(sealed):
        log = read_episode(path)
        assert len(log.messages["/state"]) == 50
        assert json.loads(log.episode["episode_in_test"]) == i
    # the episode in progress exists only under its temporary name, with data but no footer
    partial = out / ".episode-000002.mcap.partial"
    assert partial.exists() and partial.stat().st_size > 0
    assert not (out / "episode-000002.mcap").exists()
    with pytest.raises(AccrueError):
        read_episode(partial)
    # a recorder started after the crash does not reuse the crashed episode's number
    rec = EpisodeRecorder(out)
    rec.start(0)
    rec.log_step(0, 0, [0], np.zeros(6))
    assert rec.end(0, success=True).name == "episode-000003.mcap"
    assert os.listdir(out).count("episode-000002.mcap") == 0


def test_module_docstring_documents_every_topic_and_schema() -> None:
    rows = [line.split("|") for line in me.__doc__.splitlines() if line.startswith("| /")]
    documented = {cells[1].strip(): cells[2].strip() for cells in rows}
    expected = {topic: name for topic, name in me.SCHEMA_NAMES.items() if topic != me.TOPIC_WRIST_IMAGE}
    expected["/camera/<name>"] = "foxglove.CompressedImage"
    assert documented == expected
    assert me.METADATA_NAME == "episode" and f"one named `{me.METADATA_NAME}`" in me.__doc__
