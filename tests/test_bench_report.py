"""The bench report and status on a store holding known cell results (written through the runner by
stand-in steps, so no RL runs): aggregates equal a hand computation, missing cells are listed, never
dropped, and scripts/bench_tables.py writes the tables into marked blocks of a documentation page."""

from __future__ import annotations

import csv
import io
import json
import sys
from pathlib import Path

import pytest
import yaml

from artifacts.store import Store
from stages.bench.report import build_report, markdown, missing_lines, write_report
from stages.bench.spec import load_spec
from stages.bench.state import cell_states, counts, record_outcome
from stages.report.data import EVALUATE, SOURCES, TRAIN
from stages.runner import Runner
from stages.runner_types import STEP_NAMES, StagePlan, StepDef, StepInvocation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))
import bench_tables  # noqa: E402

BASE = {
    "name": "base",
    "tasks": ["nist/rect_peg", "nist/gear"],
    "method": "accrue",
    "horizon": 4,
    "base_policy": {"init": "scripted-reference:0.0"},
    "budgets": {"env_steps": 100, "eval_every": 100, "eval_episodes": 10, "num_envs": 2},
}
SPEC = {
    "name": "known",
    "base": "base.yaml",
    "methods": {"accrue": {}, "sequential": {}},
    "orderings": {"S1": ["nist/rect_peg", "nist/gear"], "S2": ["nist/gear", "nist/rect_peg"]},
    "seeds": [0, 1],
}
# (method, ordering, seed) -> (stage-1 best, task 1 after stage 2, stage-2 best); None = not finished
VALUES = {
    ("accrue", "S1", 0): (0.8, 0.7, 0.6),
    ("accrue", "S1", 1): (0.6, 0.6, 1.0),
    ("accrue", "S2", 0): (1.0, 0.9, 0.8),
    ("accrue", "S2", 1): None,  # failed
    ("sequential", "S1", 0): (0.8, 0.2, 0.6),
    ("sequential", "S1", 1): (0.8, 0.2, 0.6),
    ("sequential", "S2", 0): (0.8, 0.2, 0.6),
    ("sequential", "S2", 1): (0.8, 0.2, 0.6),
}


def hand_metrics(first: float, kept: float, second: float) -> dict:
    """Sec. V-A on two stages of grid [0, 100] with curves [0, first] and [0, second] (e* = 1)."""
    fwt1, fwt2 = first / 2, second / 2
    return {
        "FWT": (fwt1 + fwt2) / 2,
        "NBT": first - kept,
        "AUC": ((fwt1 + kept) / 2 + fwt2) / 2,
        "ACC_final": (kept + second) / 2,
        "F_final": first - kept,
    }


def stand_in(name: str, files) -> StepDef:
    role, filename = SOURCES.get(name, ("out", "out.json"))

    def run(ctx):
        out = ctx.new_output(role, "eval" if name in SOURCES else "checkpoint")
        (out / filename).write_text(json.dumps(files(ctx.config)))

    return StepDef(
        name=name, code_version="stand-in-1", run=run, outputs={role: "eval" if name in SOURCES else "checkpoint"}
    )


def commit_cell(store: Store, cell, values, stages: int | None = None) -> None:
    first, kept, second = values
    tasks = cell.tasks
    rates = {1: {tasks[0]: [0.0, first]}, 2: {tasks[0]: [kept, kept], tasks[1]: [0.0, second]}}

    def files_for(step):
        def files(config):
            k = config["stage"]
            if step == TRAIN:
                return {
                    "stage": k,
                    "task_ids": tasks[:k],
                    "grid": [0, 100],
                    "success": rates[k],
                    "episodes_per_point": 10,
                }
            if step == EVALUATE:
                last = {t: c[-1] for t, c in rates[k].items()}
                return {"stage": k, "task_ids": tasks[:k], "success": last, "base_success": last, "episodes": 10}
            return {"stage": k}

        return files

    runner = Runner(store)
    for k in range(1, (stages or 2) + 1):
        steps = tuple(
            StepInvocation(step=stand_in(s, files_for(s)), config={"cell": cell.name, "stage": k}) for s in STEP_NAMES
        )
        runner.run_plan(StagePlan(workflow=cell.name, stage=k, steps=steps))


@pytest.fixture
def bench(tmp_path):
    (tmp_path / "base.yaml").write_text(yaml.safe_dump(BASE))
    path = tmp_path / "known.yaml"
    path.write_text(yaml.safe_dump(SPEC))
    spec = load_spec(path)
    store = Store.init(tmp_path / "store")[0]
    for cell in spec.cells:
        v = VALUES[(cell.method, cell.ordering, cell.seed)]
        if v is not None:
            commit_cell(store, cell, v)
    failed = spec.cell("accrue", "S2", 1)
    commit_cell(store, failed, (0.5, 0.5, 0.5), stages=1)  # got through stage 1, then failed
    record_outcome(store, spec, failed, "failed", tries=2, seconds=3.0, error="step train: boom")
    return spec, store, path


def test_status_from_the_store(bench):
    spec, store, _ = bench
    states = cell_states(store, spec)
    assert counts(states) == {"done": 7, "running": 0, "failed": 1, "partial": 0, "pending": 0}
    failed = states[spec.cell("accrue", "S2", 1).name]
    assert failed.error == "step train: boom" and failed.stages_done == 1 and failed.tries == 2


def test_aggregates_equal_a_hand_computation(bench):
    spec, store, _ = bench
    report = build_report(store, spec)
    agg = {m["method"]: m for m in report["aggregate"]["methods"]}
    done = [v for (m, _, _), v in VALUES.items() if m == "accrue" and v is not None]
    for name in ("FWT", "NBT", "AUC", "ACC_final", "F_final"):
        want = sum(hand_metrics(*v)[name] for v in done) / len(done)
        s = agg["accrue"]["metrics"][name]
        assert s["mean"] == pytest.approx(want) and s["n"] == 3
        assert s["ci_low"] <= s["mean"] <= s["ci_high"]
    assert agg["accrue"]["metrics"]["NBT"]["ci_low"] < agg["accrue"]["metrics"]["NBT"]["ci_high"]
    seq = agg["sequential"]["metrics"]["NBT"]  # four identical runs: a degenerate interval
    assert seq["mean"] == seq["ci_low"] == seq["ci_high"] == pytest.approx(0.6)
    s2 = next(o for o in agg["accrue"]["orderings"] if o["ordering"] == "S2")
    assert s2["seeds"] == [0] and s2["metrics"]["FWT"]["mean"] == pytest.approx(hand_metrics(1.0, 0.9, 0.8)["FWT"])
    [diff] = report["differences"]  # sequential − accrue, paired by ordering and seed
    assert diff["method"] == "sequential" and diff["pairs"] == 3  # accrue S2 seed 1 has no result
    assert diff["metrics"]["NBT"]["mean"] == pytest.approx(((0.6 - 0.1) + (0.6 - 0.0) + (0.6 - 0.1)) / 3)
    assert [m["cell"] for m in report["missing"]] == [spec.cell("accrue", "S2", 1).name]
    assert report["missing"][0]["state"] == "failed" and report["missing"][0]["error"] == "step train: boom"
    # mean stage curves over the three finished accrue runs (the failed cell's stage 1 is not averaged)
    stage1, stage2 = report["stage_curves"]["accrue"]
    assert stage1["runs"] == stage2["runs"] == 3 and stage1["grid"] == [0, 100] and stage1["earlier"] is None
    assert [p["mean"] for p in stage2["current"]] == pytest.approx([0.0, (0.6 + 1.0 + 0.8) / 3])
    assert [p["mean"] for p in stage2["earlier"]] == pytest.approx([(0.7 + 0.6 + 0.9) / 3] * 2)
    assert stage2["earlier"][0]["ci_low"] < stage2["earlier"][0]["mean"] < stage2["earlier"][0]["ci_high"]


def test_markdown_csv_and_plots_show_missing_cells(bench, tmp_path):
    spec, store, _ = bench
    report = build_report(store, spec)
    text = markdown(report, command="accrue bench report known.yaml")
    assert "| accrue | 3 of 4 |" in text and "| sequential | 4 |" in text
    assert "| accrue | S2 | 0 (1 of 2) |" in text
    assert "accrue · S2 · seed 1 — failed (stages done: 1): step train: boom" in text
    assert "Difference from `accrue`" in text and "| sequential | 3 | +0.533 [+0.500, +0.600] |" in text
    assert "seeds 0, 1" in text and "S2 = nist/gear → nist/rect_peg" in text and "4000 resamples" in text
    assert "| accrue | 3 | 0.00 → 0.80 | 0.00 → 0.80 |" in text  # stage start → end, mean over runs
    assert "| sequential | 4 | 0.00 → 0.80 | 0.00 → 0.60 |" in text
    files = write_report(report, tmp_path / "out")
    for path in files.values():
        assert path and Path(path).stat().st_size > 0
    rows = list(csv.DictReader(io.StringIO(Path(files["cells_csv"]).read_text())))
    assert len(rows) == 8 and {r["state"] for r in rows} == {"done", "failed"}
    failed = next(r for r in rows if r["state"] == "failed")
    assert failed["NBT"] == "" and failed["error"] == "step train: boom"
    summary = list(csv.DictReader(io.StringIO(Path(files["summary_csv"]).read_text())))
    nbt = next(r for r in summary if r["method"] == "accrue" and r["ordering"] == "all" and r["metric"] == "NBT")
    assert float(nbt["mean"]) == pytest.approx((0.1 + 0.0 + 0.1) / 3) and nbt["n"] == "3"
    assert json.loads(Path(files["json"]).read_text())["cells_done"] == 7
    curve = list(csv.DictReader(io.StringIO(Path(files["stage_curves_csv"]).read_text())))
    end2 = next(r for r in curve if r["method"] == "sequential" and r["stage"] == "2" and r["env_step"] == "100")
    assert float(end2["current_mean"]) == pytest.approx(0.6) and float(end2["earlier_mean"]) == pytest.approx(0.2)
    assert end2["runs"] == "4" and len(curve) == 2 * 2 * 2  # methods x stages x grid points


def test_learning_curves_table_is_asked_for_and_shows_every_point(bench):
    spec, store, _ = bench
    report = build_report(store, spec)
    assert "Learning curves" not in markdown(report)
    text = markdown(report, curves=True)
    assert "| sequential · S1 | 1 | 2 | 0–100 every 100 | 0.00 · 0.80 |" in text
    assert "| sequential · S2 | 2 | 2 | 0–100 every 100 | 0.00 · 0.60 |" in text
    assert "| accrue · S2 | 2 | 1 | 0–100 every 100 | 0.00 · 0.80 |" in text


def test_a_method_with_no_finished_run_keeps_its_row(bench, tmp_path):
    spec, store, path = bench
    data = yaml.safe_load(path.read_text())
    data["methods"]["ewc"] = {}
    path.write_text(yaml.safe_dump(data))
    report = build_report(store, load_spec(path))
    text = markdown(report)
    assert "| ewc | 0 of 4 | — | — | — | — | — |" in text
    assert "| ewc | 0 | — | — | — | — | — |" in text  # and its row of differences
    assert sum(m["method"] == "ewc" for m in report["missing"]) == 4


def test_bench_tables_script_fills_marked_blocks_of_a_page(bench, tmp_path, capsys):
    spec, store, path = bench
    page = tmp_path / "nist.md"
    page.write_text("intro\n<!-- bench:known -->\nold table\n<!-- /bench:known -->\noutro\n")
    assert bench_tables.main([str(path), "--store", str(store.root), "--doc", str(page)]) == 0
    text = page.read_text()
    assert "old table" not in text and text.startswith("intro\n<!-- bench:known -->\n### bench `known`")
    assert text.endswith("<!-- /bench:known -->\noutro\n") and "| accrue | 3 of 4 |" in text
    assert f"python scripts/bench_tables.py {path} --store" in text and "Learning curves" not in text
    assert bench_tables.main([str(path), "--store", str(store.root), "--doc", str(page), "--curves"]) == 0
    assert "| sequential · S2 | 2 | 2 | 0–100 every 100 | 0.00 · 0.60 |" in page.read_text()
    page.write_text("no markers\n")
    assert bench_tables.main([str(path), "--store", str(store.root), "--doc", str(page)]) == 2
    assert "no <!-- bench:known -->" in capsys.readouterr().err


CLAIMS = [
    {"claim": "forgets less", "metric": "NBT", "reference_is": "lower", "than": ["sequential"]},
    {"claim": "learns more", "metric": "AUC", "reference_is": "higher", "than": ["sequential"]},
    {"claim": "transfers no worse", "metric": "FWT", "reference_is": "not-lower", "than": ["sequential"]},
    {"claim": "transfers better", "metric": "FWT", "reference_is": "higher", "than": ["sequential"]},
    {"claim": "forgets more", "metric": "F_final", "reference_is": "higher", "than": ["sequential"]},
]


def test_claims_are_judged_on_the_paired_differences(bench):
    """By hand (sequential − accrue over the three pairs): NBT +0.5, +0.6, +0.5; AUC −0.125, −0.175, −0.25;
    FWT 0, −0.05, −0.1 (CI [−0.1, 0]: accrue is not shown lower, nor resolved higher)."""
    spec, store, path = bench
    data = yaml.safe_load(path.read_text())
    data["reference"] = "accrue"
    data["claims"] = CLAIMS
    path.write_text(yaml.safe_dump(data))
    report = build_report(store, load_spec(path))
    got = {c["claim"]: c["verdict"] for c in report["claims"]}
    assert got == {
        "forgets less": "holds",
        "learns more": "holds",
        "transfers no worse": "holds",
        "transfers better": "not resolved",
        "forgets more": "contradicted",
    }
    fwt = next(c for c in report["claims"] if c["claim"] == "transfers better")["against"][0]
    assert fwt["pairs"] == 3 and fwt["difference"]["ci_high"] == pytest.approx(0.0)
    text = markdown(report)
    assert "| forgets less | accrue lower on NBT | sequential | +0.533 [+0.500, +0.600] | holds | **holds** |" in text


@pytest.mark.parametrize(
    "claims, message",
    [
        ([{**CLAIMS[0], "metric": "SPEED"}], r"claims\[0\].metric: 'SPEED' is not one of"),
        ([{**CLAIMS[0], "than": ["accrue"]}], r"claims\[0\].than: .*other than accrue"),
        ([{**CLAIMS[0], "reference_is": "better"}], r"claims\[0\].reference_is: 'better' is not one of"),
        ([{"claim": "x"}], r"claims\[0\]: expected exactly the fields claim, metric, reference_is, than"),
    ],
)
def test_a_bad_claim_names_its_field(bench, claims, message):
    from stages.errors import StageError

    _, _, path = bench
    data = yaml.safe_load(path.read_text())
    data["claims"] = claims
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(StageError, match=message):
        load_spec(path)


def test_a_comparison_on_fewer_than_three_pairs_is_not_judged():
    """Two pairs bootstrap to their own range, which would call any consistent pair of runs resolved."""
    from stages.bench.claims import Claim, judge

    two = {"mean": 0.5, "ci_low": 0.4, "ci_high": 0.6, "n": 2, "undefined": 0}
    three = {**two, "n": 3}
    diffs = [{"method": "a", "metrics": {"NBT": two}}, {"method": "b", "metrics": {"NBT": three}}]
    [judged] = judge([Claim("x", "NBT", "lower", ("a", "b"))], diffs)
    assert [a["verdict"] for a in judged["against"]] == ["too few pairs", "holds"]
    assert judged["verdict"] == "not resolved"


def test_missing_cells_not_started_are_one_line_per_method():
    """A grid run in parts: the cells that have something to say (started, failed) keep a line each;
    those not started yet are one line per method, orderings that miss the same seeds grouped."""

    def cell(method, ordering, seed, state="pending", stages_done=0, error=None):
        return dict(method=method, ordering=ordering, seed=seed, state=state, stages_done=stages_done, error=error)

    missing = [
        cell("accrue", "A", 0, "running", 1),
        cell("accrue", "A", 1),
        cell("accrue", "B", 0),
        cell("accrue", "B", 1),
        cell("accrue", "C", 0),
        cell("accrue", "C", 1),
        cell("ewc", "A", 0, "failed", 2, "step train: boom"),
        cell("ewc", "B", 2),
    ]
    assert missing_lines(missing) == [
        "- accrue · A · seed 0 — running (stages done: 1)",
        "- ewc · A · seed 0 — failed (stages done: 2): step train: boom",
        "- accrue — not started: 5 cells (A × seeds 1; B, C × seeds 0, 1)",
        "- ewc — not started: 1 cell (B × seeds 2)",
    ]


def test_a_spec_not_run_yet_shows_its_predictions_without_tables_of_dashes(tmp_path):
    """bias-control before any cell: no metric table, every declared prediction listed as not resolved,
    and the missing cells summed up per method."""
    store = Store.init(tmp_path / "store")[0]
    text = markdown(build_report(store, load_spec(ROOT / "workflows" / "bench" / "bias-control.yaml")))
    assert "0 of 48 cells done" in text and "No cell is done yet" in text
    assert "| method | runs | NBT" not in text and "Difference from" not in text
    assert text.count("**not resolved**") == 3
    assert "- accrue — not started: 24 cells (ROG, RGO, ORG, OGR, GRO, GOR × seeds 0, 1, 2, 3)" in text
