"""The benchmark scripts of the performance table run on CPU at small sizes and write what they measured,
with the command that made it (figures are not asserted: speed belongs to the scripts, not to tests)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

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


def test_paper_stage_accounts_for_its_time_part_by_part(tmp_path):
    out = tmp_path / "stage.json"
    _run(
        "benchmarks/paper_stage.py",
        *("--device", "cpu", "--small", "--task", "nist/rect_peg", "--env-steps", "1024", "--num-envs", "4"),
        *("--batch", "64", "--eval-every", "512", "--eval-episodes", "4", "--warmup-episodes", "4", "--out", str(out)),
    )
    report = json.loads(out.read_text())
    assert report["env_steps"] >= 1024 and report["horizon"] == 16 and report["updates"] > 0
    assert report["learner"]["algo"] == "fastsac" and report["learner"]["batch_size"] == 64
    parts = report["seconds"]
    assert {"physics", "reference", "act", "store", "update", "evaluate", "other"} <= set(parts)
    assert all(parts[k] > 0 for k in ("physics", "update", "evaluate"))
    assert abs(sum(parts.values()) - report["total_s"]) < 0.05  # every second is in one part
    assert len(report["eval_curve"]) == 3  # points 0, 512, 1024


def test_perf_report_eval_row_keeps_other_rows_and_records_its_command(tmp_path):
    out = tmp_path / "perf.json"
    out.write_text(json.dumps({"finetune": {"kept": True}}))
    _run("benchmarks/perf_report.py", "--row", "eval", "--episodes", "4", "--note", "ci", "--out", str(out))
    rows = json.loads(out.read_text())
    assert rows["finetune"] == {"kept": True}
    row = rows["eval"]
    assert row["command"] == "python benchmarks/perf_report.py --row eval --episodes 4"  # --out changes no figure
    assert row["note"] == "ci" and row["machine_before"]["cores"] == os.cpu_count()
    assert row["episodes_per_s"] > 0 and row["ratio"] > 0 and row["chunks_stepped"] > 0


def _perf_report():
    import importlib.util

    spec = importlib.util.spec_from_file_location("perf_report", ROOT / "benchmarks" / "perf_report.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_grid_projection_costs_each_cell_from_its_own_method_then_its_spec_then_every_run_cell():
    from types import SimpleNamespace as NS

    pr = _perf_report()
    cells = lambda *pairs: [NS(name=n, method=m) for n, m in pairs]  # noqa: E731
    head = NS(name="head", cells=cells(("h.a.0", "accrue"), ("h.a.1", "accrue"), ("h.s.0", "single"), ("h.e.0", "ewc")))
    abl = NS(name="abl", cells=cells(("x.b.0", "beta0"), ("x.b.1", "beta0")))
    done = {"h.a.0": True, "h.a.1": True, "h.s.0": True}
    # h.s.0 is done but ran nothing itself (every step was in the cache): it measures nothing
    spent = {"h.a.0": 3600.0, "h.a.1": 7200.0, "h.s.0": 0.0}
    g = pr.project_grid([head, abl], done, spent, cores=2)
    # accrue 1.5 h each; single-task, ewc (own method unmeasured) and the ablations (spec unmeasured) borrow it
    assert g["mean_cell_min"] == {"head/accrue": 90.0}
    assert g["costed_from_other_methods"] == ["abl/beta0", "head/ewc", "head/single"]
    assert (g["cells"], g["cells_done"], g["cells_measured"]) == (6, 3, 2)
    assert g["full_grid_h"] == 4.5 and g["remaining_h"] == round(3 * 1.5 / 2, 1)  # done cells cost no more
    assert g["cores_for_8h"] == round(6 * 1.5 / 8, 1) and g["measured_core_h"] == 3.0


def test_grid_projection_refuses_a_store_where_no_cell_ran():
    from types import SimpleNamespace as NS

    pr = _perf_report()
    spec = NS(name="head", cells=[NS(name="h.a.0", method="accrue")])
    with pytest.raises(SystemExit, match="no cell of the grid has run"):
        pr.project_grid([spec], {}, {}, cores=2)


def test_committed_attempts_cost_a_cell_only_what_it_ran(tmp_path):
    pr = _perf_report()
    (tmp_path / "log").mkdir()
    events = [
        {
            "event": "step-started",
            "cache_key": "k1",
            "attempt": 1,
            "workflow": "w",
            "stage": 1,
            "step": "train",
            "ts": "2026-12-03T10:00:00+00:00",
        },
        {
            "event": "step-started",
            "cache_key": "k2",
            "attempt": 1,
            "workflow": "w",
            "stage": 2,
            "step": "train",
            "ts": "2026-12-03T10:00:05+00:00",
        },
        {
            "event": "step-committed",
            "cache_key": "k1",
            "attempt": 1,
            "step": "train",
            "ts": "2026-12-03T10:01:30+00:00",
        },
        # k2's attempt was cut off (never committed); k1's second attempt never started: neither counts
        {
            "event": "step-committed",
            "cache_key": "k1",
            "attempt": 2,
            "step": "train",
            "ts": "2026-12-03T10:02:00+00:00",
        },
    ]
    (tmp_path / "log" / "events.jsonl").write_text("".join(json.dumps(e) + "\n" for e in events))
    assert pr.committed_attempts(tmp_path) == [{"workflow": "w", "stage": 1, "step": "train", "seconds": 90.0}]
    assert pr.step_seconds(tmp_path) == [["train", 90.0]]
    # w has a cut-off attempt (k2): its committed 90 s under-state what it cost, so it measures nothing
    assert pr.cell_costs(pr.step_attempts(tmp_path)) == ({}, {"w"})
    whole = [{"workflow": "v", "seconds": 30.0}, {"workflow": "v", "seconds": 12.0}]
    assert pr.cell_costs(whole + pr.step_attempts(tmp_path)) == ({"v": 42.0}, {"w"})


def test_why_not_met_is_met_or_a_reason_from_the_stored_figures():
    pr = _perf_report()
    cell = {"step_seconds": [["finetune-base", 10.0], ["train", 30.0]]}
    assert pr.why_not_met({"cell": cell}, "cell", 40.0, 60) == "met"
    assert pr.why_not_met({"cell": cell}, "cell", 90.0, 60).startswith("`train` (the RL budget itself) is 75% of")
    assert pr.why_not_met({}, "eval", 0.7, 0.8, higher_is_better=True) == "not met"
    assert pr.why_not_met({}, "eval", None, 0.8) == "not measured"


def test_actor_step_offset_shows_a_shared_offset_that_the_anchor_holds_down():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from actor_step_offset import offsets

    free = offsets(lr=3e-4, beta=0.0, seed=0, last=50)
    anchored = offsets(lr=3e-4, beta=1.0, seed=0, last=50)
    assert [r["actor_updates"] for r in free] == [10, 50]
    assert free[1]["mean_abs_delta"] > 5 * free[0]["mean_abs_delta"]  # the offset grows with every update
    assert free[1]["shared"] > 0.9  # one offset for every state: the critic's slope knows no state yet
    assert anchored[1]["mean_abs_delta"] < 0.2 * free[1]["mean_abs_delta"]
