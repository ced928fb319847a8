"""`accrue report` on a robot workflow names the stop rule that workflow ran with (robot.stop_successes /
robot.stop_window), not the paper's 19/20: in the printed stage lines, in report.json and in Fig. 4's
threshold line. The committed train curves are given to the report directly (stage_curves); everything
else is the real report path through the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

ROOT = Path(__file__).resolve().parents[1]
WINDOW, SUCCESSES = 10, 8  # a stop rule other than the default 19/20


def workflow(tmp_path: Path, window: int = WINDOW, successes: int = SUCCESSES) -> Path:
    """workflows/hardware-sim.yaml with another stop rule."""
    text = (ROOT / "workflows" / "hardware-sim.yaml").read_text()
    old = "  stop_window: 20\n  stop_successes: 19\n"
    assert old in text
    path = tmp_path / "hw.yaml"
    path.write_text(text.replace(old, f"  stop_window: {window}\n  stop_successes: {successes}\n"))
    return path


def curve(labels: list[bool], window: int, successes: int, task: str = "nist/rect_peg") -> dict:
    """A hardware train curve.json as stages.steps.robot_env writes it: 2 s of robot time per episode."""
    rows, reached = [], None
    for i in range(len(labels)):
        last = labels[: i + 1][-window:]
        rows.append(
            {"index": i, "success": labels[i], "cum_robot_time_s": 2.0 * (i + 1)}
            | {"window_success": sum(last), "window_size": len(last)}
        )
        if reached is None and len(last) >= window and sum(last) >= successes:
            reached = 2.0 * (i + 1)
    return {
        "hardware": True,
        "episodes": rows,
        "stop_window": window,
        "stop_successes": successes,
        "reached_robot_time_s": reached,
        "stopped": "stop rule" if reached is not None else "budget",
        "rl_robot_time_s": 2.0 * len(labels),
        "warmup_robot_time_s": 6.0,
        "train_episodes": len(labels),
        "train_successes": sum(labels),
        "task_ids": [task],
    }


LABELS = [False, True] + [True] * 8  # 8 of the last 10 at episode 10, never 19 of 20


@pytest.fixture
def store(tmp_path, monkeypatch):
    from artifacts.store import Store
    from stages.report import hardware

    Store.init(tmp_path / "store")
    monkeypatch.setattr(hardware, "stage_curves", lambda st, wf: {1: curve(LABELS, WINDOW, SUCCESSES)})
    return tmp_path / "store"


def test_the_printed_stage_line_and_report_json_name_the_workflows_stop_rule(tmp_path, store):
    from cli.main import app

    out = tmp_path / "report"
    result = CliRunner().invoke(app, ["report", str(workflow(tmp_path)), "--store", str(store), "--out", str(out)])
    assert result.exit_code == 0, result.output
    line = next(x for x in result.output.splitlines() if x.startswith("stage 1:"))
    assert line.endswith("8/10 reached at 20.0 s of RL robot time") and "19/20" not in result.output
    summary = json.loads((out / "report.json").read_text())
    assert summary["stages"]["1"]["stop_rule"] == {"successes": 8, "window": 10}


def test_fig4s_threshold_line_is_the_stop_rules(tmp_path, store, monkeypatch):
    from artifacts.store import Store
    from stages.report import plots
    from stages.report.hardware import write_hardware_report
    from stages.workflow import load_workflow

    drawn = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: drawn.append(fig) or path)
    write_hardware_report(Store.open(store), load_workflow(workflow(tmp_path)), tmp_path / "report")
    [fig] = drawn
    flat = [list(line.get_ydata()) for line in fig.axes[0].lines if len(set(line.get_ydata())) == 1]
    assert [0.8, 0.8] in flat and [0.95, 0.95] not in flat


def test_a_curve_without_the_rule_takes_the_workflows(tmp_path):
    from stages.report.hardware import stage_summary
    from stages.workflow import load_workflow

    c = curve(LABELS, WINDOW, SUCCESSES)
    del c["stop_window"], c["stop_successes"]
    wf = load_workflow(workflow(tmp_path, window=12, successes=11))
    assert stage_summary(c, wf)["stop_rule"] == {"successes": 11, "window": 12}
