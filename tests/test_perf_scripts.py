"""The benchmark scripts of the performance table run on CPU at small sizes and write what they measured,
with the command that made it (figures are not asserted: speed belongs to the scripts, not to tests)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "OMP_NUM_THREADS": "1", "HF_HUB_OFFLINE": "1", "MUJOCO_GL": "egl", "RERUN": "off"}


def _run(*args: str) -> None:
    subprocess.run([sys.executable, *args], cwd=ROOT, env=ENV, check=True, capture_output=True, text=True)


def test_gpu_path_runs_on_cpu_and_says_what_it_could_not_run(tmp_path):
    out = tmp_path / "gpu.json"
    _run("benchmarks/gpu_path.py", "--small", "--no-compile", "--out", str(out))
    report = json.loads(out.read_text())
    assert report["command"].endswith(f"--small --no-compile --out {out}")
    (eager,) = report["learner"]
    assert eager["variant"] == "eager" and eager["accrue_vs_reference"] > 0
    assert len(eager["updates_per_s"]) == 3 and all(v > 0 for v in eager["updates_per_s"].values())
    assert [row["task"] for row in report["env"]] == ["nist/rect_peg", "plugs/cross", "contact/keyed_peg"]
    for row in report["env"]:
        assert row["cpu"]["raw_physics_steps_per_s_one_core"] > 0
        assert "physics_steps_per_s" in row["warp"] or row["warp"]["not_run"]


def test_perf_report_eval_row_keeps_other_rows_and_records_its_command(tmp_path):
    out = tmp_path / "perf.json"
    out.write_text(json.dumps({"finetune": {"kept": True}}))
    _run("benchmarks/perf_report.py", "--row", "eval", "--episodes", "4", "--note", "ci", "--out", str(out))
    rows = json.loads(out.read_text())
    assert rows["finetune"] == {"kept": True}
    row = rows["eval"]
    assert row["command"] == f"python benchmarks/perf_report.py --row eval --episodes 4 --out {out}"
    assert row["note"] == "ci" and row["machine_before"]["cores"] == os.cpu_count()
    assert row["episodes_per_s"] > 0 and row["ratio"] > 0 and row["chunks_stepped"] > 0
