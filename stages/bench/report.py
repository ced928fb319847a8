"""A bench's report from the store: per method, the mean over orderings x seeds of FWT, NBT, AUC,
ACC_final and F_final with 95% bootstrap CIs; the per-ordering breakdown; the transfer figures (FWT
without step 0, jumpstart, env steps to the success threshold) with means and IQMs; the spec's claims
and its predictions, each judged; every cell that is not done (or cannot be read) listed as missing,
with why. Runs with a disjoint report set are scored on it (best checkpoint chosen on the selection
set); older runs, on the one set they have, and the report counts which is which.

With cell records (stages/bench/records.py), a cell the store has not done is taken from its record
(state `recorded`) and counts like a store cell everywhere; the report's "records" part says how many
came from records and from where, which store cells' records disagree with the store (the store wins),
and which records are not this spec's. `fresh` holds a record of every done store cell, to be written.

    report = build_report(store, spec)                   # JSON-able dict
    report, fresh = report_and_records(store, spec, load_records(dir, spec))   # with cell records (above)
    files = write_report(report, out_dir)                # report.md, summary.csv, cells.csv, stage_curves.csv,
                                                         # report.json, PNGs
    text = markdown(report, command=...)                 # what scripts/bench_tables.py pastes into the README
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

from accrue.metrics import METRICS, aggregate_runs, paired_differences, run_record
from artifacts.errors import StoreError
from artifacts.store import Store
from stages.bench.claims import MIN_PAIRS, claims_markdown, judge, judge_against
from stages.bench.curves import mean_stage_curves, stage_curve_rows, stage_curves_csv, stage_success_rows
from stages.bench.records import Recorded, load_records, metric_differences, provenance_label, store_record
from stages.bench.spec import BenchSpec
from stages.bench.state import cell_states
from stages.errors import StageError
from stages.report.data import load_run
from stages.report.summary import curve_tensor, report_tensor
from stages.report.tables import (
    ARROWS,
    METHOD_HEADER,
    ORDERING_HEADER,
    TABLE_METRICS,
    TRANSFER_METRICS,
    fmt_ci,
    markdown_table,
    method_rows,
    ordering_rows,
    summary_csv,
)

FILES = {
    "markdown": "report.md",
    "summary_csv": "summary.csv",
    "cells_csv": "cells.csv",
    "stage_curves_csv": "stage_curves.csv",
    "json": "report.json",
    "metric_bars": "metrics.png",
    "stage_curves": "stage_curves.png",
}


def default_out_dir(spec: BenchSpec) -> Path:
    return Path("runs") / "bench" / spec.name / "report"


def _stage_curves(run) -> list[dict]:
    """Per stage k: its grid, the success of the task learned in k, and the mean over earlier tasks (on the
    disjoint report set when the run has one; None unless they were scored at every point: full_curves)."""
    out = []
    for sc in run.curves:
        success = sc.report if sc.report is not None else sc.success
        current = success[sc.task_ids[-1]]
        earlier = sc.task_ids[:-1]
        scored = earlier and all(v is not None for t in earlier for v in success[t])  # full_curves runs only
        mean_earlier = (
            [sum(success[t][e] for t in earlier) / len(earlier) for e in range(len(sc.grid))] if scored else None
        )
        out.append({"grid": sc.grid, "current": current, "earlier": mean_earlier})
    return out


def _stage_artifacts(run) -> list[dict]:
    """Per stage, the committed train step record and its curve artifact: what the metrics were read from."""
    return [{"stage": sc.stage, "train_record": sc.record, "curve_artifact": sc.artifact} for sc in run.curves]


def build_report(store: Store, spec: BenchSpec, recorded: Recorded | None = None) -> dict:
    """The report: tables, paired differences, claims and mean stage curves, all JSON-able. With
    `recorded` (stages.bench.records.load_records), a cell the store has not done is taken from its record."""
    return report_and_records(store, spec, recorded)[0]


def report_and_records(store: Store, spec: BenchSpec, recorded: Recorded | None = None) -> tuple[dict, list[dict]]:
    """The report, and a cell record for every cell the store has done (for write_records); without
    `recorded` the report is exactly the store's."""
    states = cell_states(store, spec)
    cells, records, missing, fresh = [], [], [], []
    unasked = 0  # runs without a report set because their cell's workflow asks for none (report_episodes 0)
    curves: dict[str, list] = {m: [] for m in spec.methods}
    by_ordering: dict[str, list] = {}  # "method · ordering" -> runs: a learner's curve on each task apart
    used, compared = [], []  # records that stand in for a cell; (cell, record file, differences) checks
    for cell in spec.cells:
        st = states[cell.name]
        row = {
            "cell": cell.name,
            "method": cell.method,
            "ordering": cell.ordering,
            "seed": cell.seed,
            "state": st.state,
            "stages_done": st.stages_done,
            "error": st.error,
            "metrics": None,
            "disjoint_report": None,  # True / False once the run is read
        }
        if st.state == "done":
            try:
                run = load_run(store, cell.workflow)
                rec = run_record(
                    curve_tensor(run),
                    method=cell.method,
                    tasks=cell.tasks,
                    ordering=cell.ordering,
                    seed=cell.seed,
                    report=report_tensor(run),
                    grids=[sc.grid for sc in run.curves],
                    threshold=spec.success_threshold,
                )
            except (StageError, StoreError) as exc:
                row.update(state="unreadable", error=str(exc))
            else:
                row["metrics"] = rec["metrics"]
                row["disjoint_report"] = rec["disjoint_report"]
                records.append(rec)
                curves[cell.method].append(_stage_curves(run))
                by_ordering.setdefault(f"{cell.method} · {cell.ordering}", []).append(curves[cell.method][-1])
                if recorded is not None:
                    fresh.append(
                        store_record(spec, cell, rec, curves[cell.method][-1], _stage_artifacts(run), str(store.root))
                    )
                    if cell.name in recorded.by_cell:
                        diff = metric_differences(fresh[-1], recorded.by_cell[cell.name])
                        compared.append({"cell": cell.name, "file": str(recorded.files[cell.name]), "differ": diff})
        if row["metrics"] is None and recorded is not None and cell.name in recorded.by_cell:
            saved = recorded.by_cell[cell.name]
            rec = saved["run_record"]
            row.update(state="recorded", error=None, metrics=rec["metrics"], disjoint_report=rec["disjoint_report"])
            row["record"] = {"file": str(recorded.files[cell.name]), "provenance": provenance_label(saved)}
            records.append(rec)
            used.append(saved)
            if saved["stage_curves"] is not None:
                curves[cell.method].append(saved["stage_curves"])
                by_ordering.setdefault(f"{cell.method} · {cell.ordering}", []).append(saved["stage_curves"])
        if row["metrics"] is not None and not row["disjoint_report"] and not cell.workflow.budgets.report_episodes:
            unasked += 1
        if row["metrics"] is None:
            missing.append({k: row[k] for k in ("cell", "method", "ordering", "seed", "state", "stages_done", "error")})
        cells.append(row)
    agg = aggregate_runs(records)
    present = {m["method"] for m in agg["methods"]}
    # a method without a single finished run still gets its row (all "—"), never dropped
    nothing = {"mean": None, "ci_low": None, "ci_high": None, "n": 0, "undefined": 0}
    for method in spec.methods:
        if method not in present:
            agg["methods"].append(
                {
                    "method": method,
                    "runs": 0,
                    "orderings": [],
                    "metrics": {name: dict(nothing) for name in METRICS},
                    "iqm": {name: dict(nothing) for name in METRICS},
                }
            )
    agg["methods"].sort(key=lambda m: spec.methods.index(m["method"]))
    expected = {m: sum(1 for c in spec.cells if c.method == m) for m in spec.methods}
    differences = paired_differences(records, spec.reference, spec.methods) if spec.reference else []
    report = {
        "spec": spec.name,
        "spec_file": str(spec.path),
        "description": spec.description,
        "base": str(spec.base),
        "methods": spec.methods,
        "orderings": spec.orderings,
        "seeds": spec.seeds,
        "reference": spec.reference,
        "cells_total": len(spec.cells),
        "cells_done": len(records),
        "cells": cells,
        "missing": missing,
        "expected_runs": expected,
        "aggregate": agg,
        "differences": differences,
        "claims": judge(spec.claims, differences),
        "predictions": judge_against(spec.predictions, records, spec.reference, spec.methods),
        "success_threshold": spec.success_threshold,
        "runs_with_report_set": sum(1 for r in records if r["disjoint_report"]),
        "runs_without_report_set_asked": unasked,
        "stage_curves": mean_stage_curves(curves),
        "stage_curves_by_ordering": mean_stage_curves(by_ordering),
    }
    if recorded is not None:
        report["records"] = _records_summary(recorded, used, compared, fresh, curves)
    return report, fresh


def report_with_records(store: Store, spec: BenchSpec, directory: Path | None) -> tuple[dict, list[dict]]:
    """`bench report --records` and bench_tables' one path: the records in `directory` checked before
    anything is written (None: the store's report, nothing to record); a directory inside the store is
    refused, since records must outlive it."""
    if directory is None:
        return build_report(store, spec), []
    if Path(directory).resolve().is_relative_to(store.root.resolve()):
        raise StageError(
            f"--records {directory}: inside the store {store.root}; records go beside it (they outlive it)"
        )
    return report_and_records(store, spec, load_records(Path(directory), spec))


def _records_summary(recorded: Recorded, used: list, compared: list, fresh: list, curves: dict) -> dict:
    """What the cell records added to the report and what checking them against the store found."""
    by_origin: dict[str, int] = {}
    for r in used:
        by_origin[provenance_label(r)] = by_origin.get(provenance_label(r), 0) + 1
    return {
        "directory": str(recorded.directory),
        "cells_from_records": len(used),
        "from": [{"provenance": k, "cells": n} for k, n in by_origin.items()],
        "cells_recorded_from_store": len(fresh),
        "checked_against_store": len(compared),
        "differ": [c for c in compared if c["differ"]],
        "ignored": recorded.ignored,
        "runs_with_stage_curves": sum(len(runs) for runs in curves.values()),
        "runs_without_stage_curves": sum(1 for r in used if r["stage_curves"] is None),
    }


def cells_csv(report: dict) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    extra = [n for n in METRICS if n not in TABLE_METRICS]
    w.writerow(["cell", "method", "ordering", "seed", "state", *TABLE_METRICS, "error", *extra, "disjoint_report"])
    for c in report["cells"]:
        m = c["metrics"] or {}
        disjoint = c.get("disjoint_report")
        w.writerow(
            [
                c["cell"],
                c["method"],
                c["ordering"],
                c["seed"],
                c["state"],
                *("" if m.get(n) is None else repr(float(m[n])) for n in TABLE_METRICS),
                c["error"] or "",
                *("" if m.get(n) is None else repr(float(m[n])) for n in extra),
                "" if disjoint is None else str(disjoint).lower(),
            ]
        )
    return buf.getvalue()


def markdown(report: dict, command: str | None = None, heading_level: int = 3, curves: bool = False) -> str:
    """The report as Markdown; `curves` adds every method's whole learning curve per stage (long for a grid
    of many stages and points, so asked for: scripts/bench_tables.py --curves)."""
    agg = report["aggregate"]
    h = "#" * heading_level
    expected_o = {}
    for c in report["cells"]:
        key = (c["method"], c["ordering"])
        expected_o[key] = expected_o.get(key, 0) + 1
    orderings = "; ".join(f"{name} = {' → '.join(tasks)}" for name, tasks in report["orderings"].items())
    lines = [f"{h} bench `{report['spec']}`", ""]
    if report["description"]:
        lines += [report["description"], ""]
    lines += [
        f"Cells run by `accrue bench {report['spec_file']}`; this table by "
        f"`{command or 'accrue bench report ' + report['spec_file']}`. "
        f"{report['cells_done']} of {report['cells_total']} cells done "
        f"({len(report['methods'])} methods × {len(report['orderings'])} orderings × {len(report['seeds'])} seeds); "
        f"seeds {', '.join(map(str, report['seeds']))}; orderings: {orderings}.",
        f"Each entry: mean over runs (orderings × seeds) [{round(agg['confidence'] * 100)}% percentile-bootstrap CI "
        f"of the mean, {agg['resamples']} resamples, numpy seed {agg['bootstrap_seed']}]; — = undefined or no run.",
        "",
    ]
    lines += _records_lines(report)
    if not report["cells_done"]:  # a spec not run yet: its declared predictions, without tables of dashes
        lines += ["No cell is done yet: the metric tables appear as cells finish.", ""]
    else:
        lines += [
            markdown_table(METHOD_HEADER, method_rows(agg, report["expected_runs"])),
            "Per ordering (mean [CI] over its seeds):",
            "",
            markdown_table(ORDERING_HEADER, ordering_rows(agg, expected_o)),
        ]
        lines += _transfer_lines(report)
    if report.get("differences") and report["cells_done"]:
        ref = report["reference"]
        lines += [
            f"Difference from `{ref}`, paired by ordering and seed (mean [CI] of method − {ref}; "
            f"for NBT and F_final a positive difference is worse, for the others better):",
            "",
            markdown_table(
                ["method", "pairs", *(f"Δ{m}" for m in TABLE_METRICS)],
                [
                    [d["method"], str(d["pairs"]), *(fmt_ci(d["metrics"][m], signed=True) for m in TABLE_METRICS)]
                    for d in report["differences"]
                ],
            ),
        ]
        extra = [m for m in TRANSFER_METRICS if m not in TABLE_METRICS]
        if all(m in d["metrics"] for d in report["differences"] for m in extra):
            lines += [
                f"The transfer figures, paired the same way (method − {ref}; for T_thr a positive difference "
                "is slower, for the others worse when negative):",
                "",
                markdown_table(
                    ["method", "pairs", *(f"Δ{m}" for m in extra)],
                    [
                        [
                            d["method"],
                            str(d["pairs"]),
                            *(fmt_ci(d["metrics"][m], digits=0 if m == "T_thr" else 3, signed=True) for m in extra),
                        ]
                        for d in report["differences"]
                    ],
                ),
            ]
    if report.get("claims"):
        lines += [
            f"Claims the spec makes about `{report['reference']}` (mostly the paper's), judged on the paired "
            "differences above: *holds* when the 95% CI of the difference excludes 0 on the claimed side, "
            "*contradicted* when it excludes 0 on the other side, *not resolved* when it contains 0 (for "
            '"not lower" / "not higher" claims, only a resolved difference the wrong way contradicts); a '
            f"comparison on fewer than {MIN_PAIRS} pairs is not judged:",
            "",
            claims_markdown(report["claims"], report["reference"]),
        ]
    if report.get("predictions"):
        lines += [
            "Predictions the spec declared before its runs (committed ahead of any result), judged the same "
            "way; every verdict is shown, whichever way it goes:",
            "",
            claims_markdown(report["predictions"], report["reference"], what="prediction"),
        ]
    if report.get("stage_curves"):
        header, rows = stage_success_rows(report["stage_curves"])
        lines += [
            "Success on the task of each stage at its first and last evaluation, start → end (mean over runs; "
            "the start is the inherited actor, or a fresh one, on the new task before any update):",
            "",
            markdown_table(header, rows),
        ]
        if curves:
            header, rows = stage_curve_rows(report["stage_curves_by_ordering"])
            lines += [
                "Learning curves, per method and ordering: success on the task of each stage at every evaluation "
                "of that stage (report set where the run has one, mean over the ordering's seeds):",
                "",
                markdown_table(header, rows),
            ]
    if report["missing"]:
        lines += [f"Missing cells ({len(report['missing'])}):", "", *missing_lines(report["missing"]), ""]
    return "\n".join(lines)


def _records_lines(report: dict) -> list[str]:
    """With cell records: how many cells came from them and from where, the store-vs-record check, and
    the records left out; nothing without records (the report is then exactly the store's)."""
    rec = report.get("records")
    if rec is None:
        return []
    origins = "; ".join(f"{o['cells']} from {o['provenance']}" for o in rec["from"])
    lines = [
        f"Cell records (`{rec['directory']}`): {rec['cells_from_records']} of the {report['cells_done']} done "
        f"cells come from records{' (' + origins + ')' if origins else ''}"
        f"{', the others from the store' if rec['cells_from_records'] < report['cells_done'] else ''}; "
        f"{rec['cells_recorded_from_store']} store cells recorded there. "
        + (
            f"Store cells that also had a record: {rec['checked_against_store']}, metrics equal in "
            f"{rec['checked_against_store'] - len(rec['differ'])}"
            f"{', differ in ' + str(len(rec['differ'])) + ' (below)' if rec['differ'] else ''} (the store's are used)."
            if rec["checked_against_store"]
            else "No store cell had a record to check against."
        )
    ]
    if rec["runs_without_stage_curves"]:
        lines[-1] += (
            f" Stage curves are means over the {rec['runs_with_stage_curves']} runs that kept them "
            f"({rec['runs_without_stage_curves']} recorded cells hold metrics only)."
        )
    lines.append("")
    for d in rec["differ"]:
        values = ", ".join(f"{name} store {v['store']!r} record {v['record']!r}" for name, v in d["differ"].items())
        lines.append(f"- differs: {d['cell']} ({d['file']}): {values}")
    for i in rec["ignored"]:
        lines.append(f"- ignored: {i['file']} (cell {i['cell']} of spec {i['spec']} is not a cell of this spec)")
    if rec["differ"] or rec["ignored"]:
        lines.append("")
    return lines


def missing_lines(missing: list[dict]) -> list[str]:
    """One line per missing cell that has something to say (started, failed, unreadable); the cells not
    started yet, per method, on one line by ordering and seeds: a large grid run in parts would otherwise
    list every cell it has not reached."""
    lines, untouched = [], {}
    for m in missing:
        if m["state"] == "pending" and not m["stages_done"] and not m["error"]:
            untouched.setdefault(m["method"], {}).setdefault(m["ordering"], []).append(m["seed"])
            continue
        why = f": {m['error']}" if m["error"] else ""
        lines.append(
            f"- {m['method']} · {m['ordering']} · seed {m['seed']} — {m['state']} (stages done: {m['stages_done']}){why}"
        )
    for method, orderings in untouched.items():
        by_seeds = {}  # orderings that miss the same seeds share one entry
        for o, seeds in orderings.items():
            by_seeds.setdefault(tuple(sorted(seeds)), []).append(o)
        parts = "; ".join(f"{', '.join(os)} × seeds {', '.join(map(str, seeds))}" for seeds, os in by_seeds.items())
        n = sum(len(v) for v in orderings.values())
        lines.append(f"- {method} — not started: {n} cell{'s' if n != 1 else ''} ({parts})")
    return lines


def _transfer_lines(report: dict) -> list[str]:
    """The transfer figures per method, mean [CI] and IQM [CI], and which episode set the numbers are on."""
    agg = report["aggregate"]
    if "iqm" not in (agg["methods"][0] if agg["methods"] else {}):
        return []
    done, disjoint = report["cells_done"], report.get("runs_with_report_set", 0)
    unasked = report.get("runs_without_report_set_asked", 0)
    older = done - disjoint - unasked
    chosen_on = "the episodes their best checkpoint was chosen on"
    if done and disjoint == done:
        sets = "every run's numbers are on a disjoint report set (best checkpoint chosen on the selection set)"
    elif done and unasked == done:
        sets = f"the spec sets no budgets.report_episodes, so every run's numbers are on {chosen_on}"
    else:
        parts = [f"{disjoint} of {done} runs have a disjoint report set"]
        if unasked:
            parts.append(f"{unasked} ask for none (budgets.report_episodes 0): their numbers are on {chosen_on}")
        if older:
            parts.append(f"{older} ran before report sets existed: their numbers are on {chosen_on}")
        sets = "; ".join(parts)
    thr = report.get("success_threshold")
    header = [
        "method",
        "runs",
        *(f"{m} {ARROWS[m]}" for m in TRANSFER_METRICS),
        *(f"{m} IQM" for m in TRANSFER_METRICS),
    ]
    rows = [
        [
            m["method"],
            str(m["runs"]),
            *(fmt_ci(m["metrics"][n]) if n != "T_thr" else fmt_ci(m["metrics"][n], digits=0) for n in TRANSFER_METRICS),
            *(fmt_ci(m["iqm"][n]) if n != "T_thr" else fmt_ci(m["iqm"][n], digits=0) for n in TRANSFER_METRICS),
        ]
        for m in agg["methods"]
    ]
    return [
        f"Transfer: FWT with and without the step-0 point, jumpstart (success on the new task at step 0) and "
        f"T_thr (env steps until success ≥ {thr}; a stage that never gets there counts as its budget, so T_thr "
        f"is then a lower bound), each averaged over stages; mean [CI] and IQM [CI] over runs; {sets}:",
        "",
        markdown_table(header, rows),
    ]


def write_report(report: dict, out_dir: Path, command: str | None = None) -> dict[str, str | None]:
    from stages.report.bench_plots import plot_metric_bars, plot_stage_curves

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / FILES["markdown"]).write_text(markdown(report, command, heading_level=1), encoding="utf-8")
    (out / FILES["summary_csv"]).write_text(summary_csv(report["aggregate"]), encoding="utf-8")
    (out / FILES["cells_csv"]).write_text(cells_csv(report), encoding="utf-8")
    (out / FILES["stage_curves_csv"]).write_text(stage_curves_csv(report["stage_curves"]), encoding="utf-8")
    written = ("markdown", "summary_csv", "cells_csv", "stage_curves_csv", "json")
    files: dict[str, str | None] = {k: str(out / FILES[k]) for k in written}
    files["metric_bars"] = str(plot_metric_bars(report["aggregate"], out / FILES["metric_bars"]))
    stage = plot_stage_curves(report["stage_curves"], out / FILES["stage_curves"])
    if stage is None:
        (out / FILES["stage_curves"]).unlink(missing_ok=True)
    files["stage_curves"] = None if stage is None else str(stage)
    report = {**report, "files": files}
    tmp = out / (FILES["json"] + ".tmp")
    tmp.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    tmp.replace(out / FILES["json"])
    return files
