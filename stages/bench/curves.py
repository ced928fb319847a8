"""Mean success curves per stage position over a bench method's runs, for the plot, the CSV and the
start → end table of the report.

    means = mean_stage_curves(curves)      # {method: [per stage k: {"grid", "runs", "current", "earlier"}]}
    text = stage_curves_csv(means)         # long format: method, stage, env_step, runs, mean and CI per curve
    header, rows = stage_success_rows(means)

`curves` is {method: [per run: [per stage k: {"grid": [...], "current": [...], "earlier": [...] | None}]]}:
"current" is the success of the task learned in stage k at each grid point, "earlier" the mean over the
tasks of stages < k. A run whose stage-k grid differs from the method's first run (other budgets) is left
out of that stage, and "runs" says how many were averaged. Every point is summarize_values' mean and 95%
bootstrap CI (accrue.metrics), the same statistics as the metric tables.
"""

from __future__ import annotations

import csv
import io

from accrue.metrics import summarize_values
from stages.report.tables import fmt


def _column_summaries(rows: list[list[float]]) -> list[dict]:
    return [summarize_values(list(column)) for column in zip(*rows)]


def mean_stage_curves(curves: dict[str, list]) -> dict[str, list[dict]]:
    out: dict[str, list[dict]] = {}
    for method, runs in curves.items():
        if not runs:
            continue
        stages = []
        for k in range(max(len(r) for r in runs)):
            stage = [r[k] for r in runs if len(r) > k]
            grid = stage[0]["grid"]
            same = [s for s in stage if s["grid"] == grid]
            earlier = [s["earlier"] for s in same if s["earlier"] is not None]
            stages.append(
                {
                    "grid": list(grid),
                    "runs": len(same),
                    "current": _column_summaries([s["current"] for s in same]),
                    "earlier": _column_summaries(earlier) if earlier else None,
                }
            )
        out[method] = stages
    return out


def stage_curves_csv(means: dict[str, list[dict]]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    curve_cols = [f"{c}_{s}" for c in ("current", "earlier") for s in ("mean", "ci_low", "ci_high")]
    w.writerow(["method", "stage", "env_step", "runs", *curve_cols])
    for method, stages in means.items():
        for k, st in enumerate(stages, start=1):
            for i, step in enumerate(st["grid"]):
                values = []
                for key in ("current", "earlier"):
                    point = st[key][i] if st[key] is not None else None
                    for field in ("mean", "ci_low", "ci_high"):
                        v = None if point is None else point[field]
                        values.append("" if v is None else repr(float(v)))
                w.writerow([method, k, step, st["runs"], *values])
    return buf.getvalue()


def stage_success_rows(means: dict[str, list[dict]]) -> tuple[list[str], list[list[str]]]:
    """One row per method: per stage, the mean success on that stage's task at its first and last
    evaluation ("start → end"), and the runs averaged."""
    n_stages = max((len(s) for s in means.values()), default=0)
    header = ["method", "runs", *(f"stage {k}" for k in range(1, n_stages + 1))]
    rows = []
    for method, stages in means.items():
        cells = []
        for k in range(n_stages):
            if k >= len(stages):
                cells.append("—")
                continue
            start, end = stages[k]["current"][0]["mean"], stages[k]["current"][-1]["mean"]
            cells.append(f"{fmt(start, 2)} → {fmt(end, 2)}")
        runs = sorted({s["runs"] for s in stages})
        rows.append([method, "/".join(map(str, runs)), *cells])
    return header, rows


def stage_curve_rows(means: dict[str, list[dict]]) -> tuple[list[str], list[list[str]]]:
    """One row per method and stage: the whole learning curve on that stage's task (mean over runs at every
    grid point), so a table shows where a curve dips and whether it still rises at the budget's end."""
    header = ["method · ordering", "stage", "runs", "env steps", "success at each evaluation"]
    rows = []
    for method, stages in means.items():
        for k, st in enumerate(stages, start=1):
            grid = st["grid"]
            spacing = grid[1] - grid[0] if len(grid) > 1 else 0
            steps = f"0–{grid[-1]:,} every {spacing:,}" if spacing else f"{grid[-1]:,}"
            values = " · ".join(fmt(point["mean"], 2) for point in st["current"])
            rows.append([method, str(k), str(st["runs"]), steps, values])
    return header, rows
