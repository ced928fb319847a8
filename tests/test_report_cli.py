"""`accrue report` over a store holding a synthetic 3-stage run committed through the real Runner:
metric values, per-task base vs after-RL, figures, the rerun recording, partial runs and errors."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_report_support import (  # noqa: E402
    BASE_SUCCESS,
    CURVES,
    EPISODES,
    EVAL_SUCCESS,
    GRID,
    TASKS,
    commit_stage,
    curve_json,
    write_workflow,
)

from accrue.metrics import continual_metrics
from artifacts.store import Store
from cli.main import app
from stages.report.summary import PER_TASK_KEYS, REPORT_KEYS

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def store(tmp_path: Path) -> Store:
    return Store.init(tmp_path / "store")[0]


def invoke(*args: str, store: Store) -> tuple[int, str]:
    result = CliRunner().invoke(app, ["report", *args, "--store", str(store.root)], env={"COLUMNS": "200"})
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result.exit_code, result.output


def report_json(tmp_path: Path, store: Store, workflow: Path) -> dict:
    code, out = invoke(str(workflow), "--json", "--out", str(tmp_path / "out"), store=store)
    assert code == 0, out
    return json.loads(out)


def png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR", path
    return struct.unpack(">II", data[16:24])


def accrue_main(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "ACCRUE_STORE"}
    env["PYTHONPATH"] = str(ROOT)
    code = "import sys; sys.argv[0] = 'accrue'; from cli.main import main; main()"
    return subprocess.run(
        [sys.executable, "-c", code, *args], capture_output=True, text=True, cwd=cwd, env=env, timeout=120
    )


# ----------------------------------------------------------------------------- a complete run
def test_complete_run_metrics_per_task_figures_and_recording(tmp_path, store):
    for k in (1, 2, 3):
        commit_stage(store, k)
    rep = report_json(tmp_path, store, write_workflow(tmp_path))

    assert set(REPORT_KEYS) <= set(rep) and {"files", "out_dir"} <= set(rep)
    expected = continual_metrics(CURVES)
    for name in ("FWT", "NBT", "AUC", "ACC_final", "F_final"):
        assert rep["metrics"][name] == pytest.approx(expected[name], abs=1e-12), name
    # the same numbers by hand, so a wrong matrix construction cannot agree with itself
    assert [b["index"] for b in rep["best_checkpoint"]] == [2, 3, 1]
    assert [b["env_steps"] for b in rep["best_checkpoint"]] == [200, 300, 100]
    assert rep["success_matrix"] == [[0.9, None, None], [0.7, 0.95, None], [0.7, 0.9, 1.0]]
    assert rep["metrics"]["ACC_final"] == pytest.approx((0.7 + 0.9 + 1.0) / 3)
    assert rep["metrics"]["F_final"] == pytest.approx(((0.9 - 0.7) + (0.95 - 0.9)) / 2)
    assert rep["metrics"]["NBT"] == pytest.approx((((0.9 - 0.7) + (0.9 - 0.7)) / 2 + (0.95 - 0.9)) / 2)
    assert rep["stages_reported"] == 3 and rep["complete"] and rep["missing"] == []

    assert [row["task"] for row in rep["per_task"]] == TASKS
    for j, row in enumerate(rep["per_task"]):
        assert set(PER_TASK_KEYS) <= set(row)
        assert row["base_success"] == BASE_SUCCESS[2][j] and row["after_rl_success"] == EVAL_SUCCESS[2][j]
        assert row["eval_stage"] == 3 and row["episodes"] == EPISODES and row["stage"] == j + 1
        assert row["best_in_own_stage"] == max(CURVES[j][j])
    assert [e["stage"] for e in rep["evaluations"]] == [1, 2, 3]

    files = rep["files"]
    for name in ("curves", "success_matrix", "base_vs_rl"):
        path = Path(files[name])
        assert path.parent == tmp_path / "out" and path.stat().st_size > 10_000, name
        width, height = png_size(path)
        assert width > 300 and height > 250, (name, width, height)
    assert json.loads(Path(files["summary"]).read_text())["metrics"] == rep["metrics"]

    from accrue.logs.rerun_log import read_rrd_table

    table = read_rrd_table(files["recording"], contents="/success/nist/gear", index="env_steps")
    points = {
        int(t): v for t, v in zip(table["env_steps"], table["/success/nist/gear:Scalars:scalars"]) if v is not None
    }
    # the gear is learned in stage 3, which starts after two stages of GRID[-1] env steps
    assert points == {2 * GRID[-1] + g: pytest.approx([c]) for g, c in zip(GRID, CURVES[2][2])}
    deployment = read_rrd_table(files["recording"], contents="/deployment/base/nist/rect_peg", index="env_steps")
    got = {
        int(t): v[0]
        for t, v in zip(deployment["env_steps"], deployment["/deployment/base/nist/rect_peg:Scalars:scalars"])
        if v
    }
    assert got == {(k + 1) * GRID[-1]: pytest.approx(BASE_SUCCESS[k][0]) for k in range(3)}


def test_human_output_table_and_default_out_dir(tmp_path, store, monkeypatch):
    for k in (1, 2, 3):
        commit_stage(store, k)
    workflow = write_workflow(tmp_path)
    monkeypatch.chdir(tmp_path)
    code, out = invoke(str(workflow), store=store)
    assert code == 0, out
    expected = continual_metrics(CURVES)
    for name in ("FWT", "NBT", "AUC", "ACC_final", "F_final"):
        line = next(ln for ln in out.splitlines() if f" {name} " in ln)
        assert f"{expected[name]:.3f}" in line, (name, line)
    assert "all 3 stages" in out and "not committed" not in out
    gear = next(ln for ln in out.splitlines() if "nist/gear" in ln and "stage 3" in ln and "0.350" in ln)
    assert "0.950" in gear
    written = tmp_path / "store-report" / "rep"  # beside the store it reports on (not the default ./.accrue)
    for name in ("curves.png", "success_matrix.png", "base_vs_rl.png", "report.rrd", "report.json"):
        assert (written / name).is_file(), name
        assert str(written / name) in out.replace("\n", "")
    assert not Path("runs").exists()


def test_two_stores_reports_do_not_overwrite_each_other(tmp_path, monkeypatch):
    """Without --out the report is keyed by its store: runs/<workflow>/report for ./.accrue, beside any other."""
    monkeypatch.chdir(tmp_path)
    default, _ = Store.init(tmp_path / ".accrue")
    other, _ = Store.init(tmp_path / "elsewhere" / "second")
    commit_stage(default, 1)
    for k in (1, 2, 3):
        commit_stage(other, k)
    workflow = write_workflow(tmp_path)
    assert invoke(str(workflow), store=default)[0] == 0
    assert invoke(str(workflow), store=other)[0] == 0
    first = json.loads(Path("runs/rep/report/report.json").read_text())
    second = json.loads((tmp_path / "elsewhere" / "second-report" / "rep" / "report.json").read_text())
    assert (first["stages_reported"], first["complete"]) == (1, False) and second["complete"] is True


# ----------------------------------------------------------------------------- partial runs
def test_one_stage_without_evaluation_reports_what_exists(tmp_path, store):
    commit_stage(store, 1, evaluate=False)
    rep = report_json(tmp_path, store, write_workflow(tmp_path))
    assert rep["stages_reported"] == 1 and not rep["complete"]
    assert rep["metrics"]["NBT"] is None and rep["metrics"]["F_final"] is None
    assert rep["metrics"]["FWT"] == pytest.approx(sum(CURVES[0][0]) / len(GRID))
    assert rep["metrics"]["ACC_final"] == pytest.approx(0.9)
    assert [(m["stage"], m["step"]) for m in rep["missing"]] == [
        (1, "evaluate-all"),
        (2, "train"),
        (2, "evaluate-all"),
        (3, "train"),
        (3, "evaluate-all"),
    ]
    assert rep["missing"][0]["ref"] == "workflow/rep/stage/1/evaluate-all"
    row = rep["per_task"][0]
    assert row["base_success"] is None and row["after_rl_success"] is None
    assert rep["files"]["base_vs_rl"] is None and not (tmp_path / "out" / "base_vs_rl.png").exists()
    assert png_size(Path(rep["files"]["curves"]))[0] > 300


def test_two_of_three_stages_human_output_says_what_is_missing(tmp_path, store):
    commit_stage(store, 1)
    commit_stage(store, 2)
    code, out = invoke(str(write_workflow(tmp_path)), "--out", str(tmp_path / "o"), store=store)
    assert code == 0, out
    assert "stages 1..2 of 3" in out and "not committed yet: stage 3 train, evaluate-all" in out
    nbt_line = next(ln for ln in out.splitlines() if " NBT " in ln)
    assert f"{continual_metrics(CURVES[:2])['NBT']:.3f}" in nbt_line
    assert (tmp_path / "o" / "base_vs_rl.png").stat().st_size > 10_000


# ----------------------------------------------------------------------------- errors
def test_nothing_run_is_a_one_line_error_exit_2(tmp_path, store):
    workflow = write_workflow(tmp_path)
    proc = accrue_main("report", str(workflow), "--store", str(store.root), cwd=tmp_path)
    assert proc.returncode == 2, (proc.stdout, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert lines[0].startswith("error: workflow rep has no committed evaluations yet: stage 1 step train")
    assert "workflow/rep/stage/1/train" in lines[0]
    assert not (tmp_path / "runs").exists()


def test_mismatched_curve_file_names_the_ref_and_field(tmp_path, store):
    bad = curve_json(1)
    bad["task_ids"] = ["nist/gear"]
    commit_stage(store, 1, curve=bad)
    from stages.errors import StageError

    with pytest.raises(StageError, match=r"workflow/rep/stage/1/train: task_ids: expected"):
        invoke(str(write_workflow(tmp_path)), "--out", str(tmp_path / "o"), store=store)


def test_short_curve_is_refused(tmp_path, store):
    bad = curve_json(1)
    bad["success"]["nist/rect_peg"] = [0.1, 0.2]
    commit_stage(store, 1, curve=bad)
    from stages.errors import StageError

    with pytest.raises(StageError, match=r"success\[nist/rect_peg\]: expected 5 values"):
        invoke(str(write_workflow(tmp_path)), "--out", str(tmp_path / "o"), store=store)


def test_stages_on_different_grids_are_refused(tmp_path, store):
    commit_stage(store, 1)
    other = curve_json(2)
    other["grid"] = GRID[:3]
    other["success"] = {t: c[:3] for t, c in other["success"].items()}
    commit_stage(store, 2, curve=other)
    from stages.errors import StageError

    with pytest.raises(StageError, match="stage 2 was evaluated at 3 grid points but stage 1 at 5"):
        invoke(str(write_workflow(tmp_path)), "--out", str(tmp_path / "o"), store=store)


@pytest.mark.parametrize(
    "grid, ok",
    [
        ([0.0, 100.0, 200.0, 300.0, 400.0], True),
        ([0, 100, 100, 300, 400], False),
        ([50, 100, 200, 300, 400], False),
        ([0, 100.5, 200, 300, 400], False),
    ],
)
def test_grid_must_count_env_steps_from_zero(grid, ok):
    from stages.errors import StageError
    from stages.report.data import parse_curves
    from stages.workflow import parse_workflow

    wf = parse_workflow(
        {"name": "rep", "tasks": TASKS, "method": "accrue", "budgets": {"env_steps": 400, "eval_every": 100}},
        "rep.yaml",
    )
    data = dict(curve_json(1), grid=grid)
    if ok:
        assert parse_curves(data, 1, wf, "here", "r", "a").grid == [0, 100, 200, 300, 400]
    else:
        with pytest.raises(StageError, match="here: grid: expected increasing env-step counts starting at 0"):
            parse_curves(data, 1, wf, "here", "r", "a")
