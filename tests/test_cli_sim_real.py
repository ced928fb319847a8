"""`accrue sim` on the real MuJoCo tasks: demos load with lerobot, watch writes .rrd + MCAP, errors are one line."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app

TASK = "plugs/cross"


def test_tasks_json_lists_the_registry() -> None:
    from accrue.sim import get_task, list_tasks

    result = CliRunner().invoke(app, ["sim", "tasks", "--json"])
    assert result.exit_code == 0, result.output
    rows = json.loads(result.stdout)
    assert [r["task_id"] for r in rows] == list_tasks()
    cross = next(r for r in rows if r["task_id"] == TASK)
    spec = get_task(TASK)
    assert cross["role"] == "negative-control" and cross["noise"]["estimate_bias_mm_deg"][0] == 1.4
    assert {k: cross[k] for k in ("family", "task_id", "instruction", "clearance_mm", "max_steps", "control_hz")} == {
        "family": spec.family,
        "task_id": TASK,
        "instruction": spec.instruction,
        "clearance_mm": round(spec.clearance * 1e3, 3),
        "max_steps": spec.max_steps,
        "control_hz": spec.control_hz,
    }
    nist = CliRunner().invoke(app, ["sim", "tasks", "--json", "--family", "nist"])
    assert {r["family"] for r in json.loads(nist.stdout)} == {"nist"}


def test_demos_command_writes_a_lerobot_dataset(tmp_path: Path) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from accrue.sim import STATE_DIM, STATE_NAMES, get_task
    from accrue.sim.demos import read_demo_info

    out = tmp_path / "cross_demos"
    result = CliRunner().invoke(app, ["sim", "demos", TASK, "--episodes", "2", "--out", str(out), "--seed", "1", "-q"])
    assert result.exit_code == 0, result.output
    assert "wrote 2 episodes" in result.stdout and "expert success rate" in result.stdout

    spec = get_task(TASK)
    ds = LeRobotDataset("accrue/plugs_cross", root=out, video_backend="pyav")
    features = ds.meta.features
    assert features["observation.state"]["shape"] == (STATE_DIM,)
    assert features["observation.state"]["names"] == list(STATE_NAMES)
    assert features["action"]["shape"] == (6,) and features["action"]["dtype"] == "float32"
    for key, dtype in (("next.reward", "float32"), ("next.done", "bool"), ("next.success", "bool")):
        assert features[key]["dtype"] == dtype and features[key]["shape"] == (1,)
    assert ds.num_episodes == 2 and ds.fps == int(spec.control_hz)
    lengths = [int(n) for n in ds.meta.episodes["length"]]
    assert sum(lengths) == len(ds) and all(3 <= n <= spec.max_steps for n in lengths)
    last = ds[lengths[0] - 1]
    assert last["task"] == spec.instruction and bool(last["next.done"]) and bool(last["next.success"])
    assert float(last["next.reward"]) == 1.0 and not bool(ds[0]["next.done"])
    actions = np.stack([ds[i]["action"].numpy() for i in range(lengths[0])])
    assert np.abs(actions).max() <= 1.0 and np.abs(actions).sum() > 0

    task_id, instruction, n, _ = read_demo_info(out)
    assert (task_id, instruction, n) == (TASK, spec.instruction, 2)


def test_watch_writes_rerun_and_mcap(tmp_path: Path) -> None:
    from accrue.logs.mcap_episodes import read_episode
    from accrue.logs.rerun_log import read_rrd_table

    rrd, logs = tmp_path / "w.rrd", tmp_path / "mcap"
    result = CliRunner().invoke(
        app,
        ["sim", "watch", TASK, "--policy", "random", "--seed", "2", "--images", "--out", str(rrd), "--mcap", str(logs)],
    )
    assert result.exit_code == 0, result.output
    table = read_rrd_table(rrd)
    steps = table["step"]
    assert steps == list(range(len(steps))) and len(steps) > 1
    assert "/wrench/fz:Scalars:scalars" in table and "/world/ee:Transform3D:translation" in table
    assert all(v is not None for v in table["/camera/front:EncodedImage:blob"])
    (episode_file,) = sorted(logs.glob("episode-*.mcap"))
    log = read_episode(episode_file)
    assert len(log.messages["/state"]) == len(steps)
    assert (
        log.image(0, "/camera/front").shape == (64, 64, 3)
        and log.schemas["/camera/front"] == "foxglove.CompressedImage"
    )
    assert log.schemas["/ee/pose"] == "foxglove.PoseInFrame" and log.schemas["/wrist/wrench"] == "accrue.Wrench"
    assert log.episode["task_id"] == TASK and log.episode["policy"] == "random"
    assert json.loads(log.episode["length"]) == len(steps)
    label = log.messages["/episode/label"][0]
    assert f"after {len(steps)} steps" in result.stdout
    assert ("no success" in result.stdout) == (not label["success"])


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["sim", "demos", "nope/x", "--episodes", "1", "--out", "{tmp}/d"], "error: unknown task id 'nope/x'"),
        (["sim", "watch", "nope/x", "--out", "{tmp}/w.rrd"], "error: unknown task id 'nope/x'"),
        (["sim", "watch", TASK, "--policy", "genius", "--out", "{tmp}/w.rrd"], "error: unknown policy 'genius'"),
    ],
)
def test_bad_ids_are_one_line_errors_from_the_console_script(tmp_path: Path, args: list[str], message: str) -> None:
    argv = [a.replace("{tmp}", str(tmp_path)) for a in args]
    proc = subprocess.run([sys.executable, "-m", "cli.main", *argv], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.startswith(message) and proc.stderr.count("\n") == 1, proc.stderr
    assert "Traceback" not in proc.stderr and list(tmp_path.iterdir()) == []
