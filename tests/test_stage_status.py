"""`accrue stage status`: steps in the order the stage runs them (record-demos first), each with
when it started, how long it took and the host it ran on, in the table and in --json; a store that
holds only the step records (pulled, no attempt files) still shows them."""

from __future__ import annotations

import json
import os
import shutil
import socket
import sys
from pathlib import Path

from rich.console import Console

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_cli_store import accrue, workflow_file  # noqa: E402

from artifacts.store import Store
from stages.runner import Runner
from stages.runner_types import StagePlan, StepDef, StepInvocation

ORDER = ["record-demos", "finetune-base", "cache-teacher", "warmup", "train", "evaluate-all", "handoff"]


def _ran(store: Path, names: list[str]) -> None:
    """Commit stage 1's first steps with stand-in bodies, in run order."""
    steps = tuple(StepInvocation(StepDef(n, "1", lambda ctx: None), {"step": n}) for n in names)
    Runner(Store.open(store), console=Console(file=open(os.devnull, "w"))).run_plan(StagePlan("wf", 1, steps))


def _status(store: Path, wf: Path) -> list[dict]:
    out = accrue("stage", "status", str(wf), "--json", store=store)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def test_status_lists_steps_in_run_order_with_start_duration_and_host(tmp_path):
    store, wf = tmp_path / "store", workflow_file(tmp_path)
    assert accrue("init", "--store", str(store)).returncode == 0
    _ran(store, ["record-demos", "finetune-base"])
    rows = _status(store, wf)
    assert [(r["stage"], r["step"]) for r in rows] == [(k, s) for k in (1, 2) for s in ORDER]
    by = {(r["stage"], r["step"]): r for r in rows}
    for name in ("record-demos", "finetune-base"):
        row = by[(1, name)]
        assert row["state"] == "committed" and row["host"] == socket.gethostname()
        assert row["started"] < row["finished"] or row["started"] == row["finished"]
        assert isinstance(row["duration_s"], float) and 0 <= row["duration_s"] < 60
    assert by[(1, "record-demos")]["started"] <= by[(1, "finetune-base")]["started"]
    assert by[(1, "train")]["state"] == "not run" and by[(1, "train")]["host"] is None
    table = accrue("stage", "status", str(wf), store=store).stdout
    header = next(line for line in table.splitlines() if "step" in line and "host" in line)
    assert header.index("started") < header.index("took") < header.index("host")
    assert table.index("record-demos") < table.index("finetune-base") < table.index("cache-teacher")
    assert socket.gethostname() in table and " s " in table

    # a pulled store has the step records and refs but not this store's attempt files
    shutil.rmtree(store / "records")
    again = {(r["stage"], r["step"]): r for r in _status(store, wf)}
    assert again[(1, "record-demos")]["host"] == socket.gethostname()
    assert again[(1, "record-demos")]["duration_s"] == by[(1, "record-demos")]["duration_s"]


def test_a_stage_whose_demos_are_given_has_no_record_demos_step(tmp_path):
    store = tmp_path / "store"
    assert accrue("init", "--store", str(store)).returncode == 0
    wf = workflow_file(tmp_path, base_policy={"init": "scripted-reference:0.5"})
    assert [r["step"] for r in _status(store, wf) if r["stage"] == 1] == ORDER[1:]
