"""`accrue sim` through the real CLI entry (cli.main) with the small fake simulator of test_demos_writer."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from test_demos_writer import fake_sim  # tests/ is on sys.path (rootdir conftest, no package)
from typer.testing import CliRunner

from accrue.sim import demos


@pytest.fixture
def fake(monkeypatch: pytest.MonkeyPatch):
    sim = fake_sim(p_success=0.5, image_hw=(32, 40))
    monkeypatch.setattr(demos, "_sim_api", lambda: sim)
    return sim


def run_main(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture, *args: str) -> tuple[int, str, str]:
    """Run `accrue ARGS` through cli.main.main(), the console-script entry that formats errors."""
    from cli.main import main

    monkeypatch.setattr(sys, "argv", ["accrue", *args])
    with pytest.raises(SystemExit) as exit_info:
        main()
    out, err = capsys.readouterr()
    code = exit_info.value.code
    return (0 if code is None else code), out, err


def test_tasks_json_and_table(fake) -> None:
    from cli.main import app

    result = CliRunner().invoke(app, ["sim", "tasks", "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout) == [
        {
            "family": "fake",
            "task_id": "fake/peg",
            "instruction": "insert the fake peg",
            "clearance_mm": 0.3,
            "max_steps": 6,
            "control_hz": 20.0,
        }
    ]
    table = CliRunner().invoke(app, ["sim", "tasks"], env={"COLUMNS": "200"})
    assert table.exit_code == 0
    assert "fake/peg" in table.stdout and "0.30 mm" in table.stdout and "6 (0.3 s)" in table.stdout


def test_demos_through_cli_load_with_lerobot(fake, tmp_path: Path) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from cli.main import app

    out = tmp_path / "demos"
    result = CliRunner().invoke(
        app, ["sim", "demos", "fake/peg", "--episodes", "3", "--out", str(out), "--seed", "2", "--images", "--quiet"]
    )
    assert result.exit_code == 0, result.output
    assert "wrote 3 episodes" in result.stdout and "expert success rate:" in result.stdout
    ds = LeRobotDataset("accrue/fake_peg", root=out, video_backend="pyav")
    assert ds.num_episodes == 3 and ds.fps == 20
    assert ds.meta.features["observation.images.wrist"]["dtype"] == "video"
    item = ds[len(ds) - 1]
    assert item["task"] == "insert the fake peg"
    assert tuple(item["observation.images.wrist"].shape) == (3, 32, 40)
    assert tuple(item["observation.state"].shape) == (5,) and tuple(item["action"].shape) == (6,)
    assert bool(item["next.done"]) and bool(item["next.success"])
    lengths = [int(e["length"]) for e in ds.meta.episodes]
    assert sum(lengths) == len(ds) and all(3 <= n <= 6 for n in lengths)


def test_demos_shortfall_exits_1_with_warning(fake, tmp_path: Path) -> None:
    from cli.main import app

    result = CliRunner().invoke(
        app, ["sim", "demos", "fake/peg", "-n", "40", "-o", str(tmp_path / "d"), "--max-attempts", "6", "-q"]
    )
    assert result.exit_code == 1
    assert "attempt bound reached" in result.output


def test_user_mistakes_are_one_line_errors(fake, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    code, out, err = run_main(
        monkeypatch, capsys, "sim", "demos", "nope/x", "--episodes", "1", "--out", str(tmp_path / "a")
    )
    assert code == 2 and err.startswith("error: unknown task id 'nope/x'") and err.count("\n") == 1
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("x")
    code, _, err = run_main(monkeypatch, capsys, "sim", "demos", "fake/peg", "-n", "1", "-o", str(tmp_path / "full"))
    assert code == 2 and "exists and is not empty" in err and err.count("\n") == 1
    code, _, err = run_main(monkeypatch, capsys, "sim", "tasks", "--family", "moon")
    assert code == 2 and err == "error: no task family 'moon'; families: fake\n"
