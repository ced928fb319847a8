"""Tables of aggregated runs (accrue.metrics.aggregate_runs): one row per method, and one per method
and ordering, as plain rows that rich, Markdown and CSV writers share.

    rows = method_rows(agg, expected={"accrue": 6})        # [[method, runs, "0.823 [0.780, 0.861]", ...]]
    text = markdown_table(METHOD_HEADER, rows)

A metric with no defined value in a group prints as "—"; a group with fewer runs than expected says
how many ("4 of 6"), so a missing cell is visible in every table.
"""

from __future__ import annotations

import csv
import io

from accrue.metrics import METRICS

# the paper's column order (Tables I, II, IV, V) and which way is better
TABLE_METRICS = ("NBT", "FWT", "AUC", "ACC_final", "F_final")
ARROWS = {
    "FWT": "↑",
    "NBT": "↓",
    "AUC": "↑",
    "ACC_final": "↑",
    "F_final": "↓",
    "FWT_no0": "↑",
    "jumpstart": "↑",
    "T_thr": "↓",
}
# issue 18's transfer figures beside FWT (accrue.metrics): a table of their own
TRANSFER_METRICS = ("FWT", "FWT_no0", "jumpstart", "T_thr")

METHOD_HEADER = ["method", "runs", *(f"{m} {ARROWS[m]}" for m in TABLE_METRICS)]
ORDERING_HEADER = ["method", "ordering", "seeds", *(f"{m} {ARROWS[m]}" for m in TABLE_METRICS)]


def fmt(value: float | None, digits: int = 3, signed: bool = False) -> str:
    return "—" if value is None else f"{value:+.{digits}f}" if signed else f"{value:.{digits}f}"


def fmt_ci(summary: dict, digits: int = 3, signed: bool = False) -> str:
    """'mean [low, high]'; a lone run has no interval to show; '—' when undefined."""
    if summary["mean"] is None:
        return "—"
    mean = fmt(summary["mean"], digits, signed)
    if summary["n"] < 2:
        return mean
    return f"{mean} [{fmt(summary['ci_low'], digits, signed)}, {fmt(summary['ci_high'], digits, signed)}]"


def _runs_text(found: int, expected: int | None) -> str:
    return str(found) if expected is None or expected == found else f"{found} of {expected}"


def method_rows(agg: dict, expected: dict[str, int] | None = None) -> list[list[str]]:
    return [
        [
            m["method"],
            _runs_text(m["runs"], (expected or {}).get(m["method"])),
            *(fmt_ci(m["metrics"][name]) for name in TABLE_METRICS),
        ]
        for m in agg["methods"]
    ]


def ordering_rows(agg: dict, expected: dict[tuple[str, str], int] | None = None) -> list[list[str]]:
    rows = []
    for m in agg["methods"]:
        for o in m["orderings"]:
            want = (expected or {}).get((m["method"], o["ordering"]))
            seeds = ", ".join(str(s) for s in o["seeds"])
            if want is not None and want != o["runs"]:
                seeds += f" ({o['runs']} of {want})"
            rows.append([m["method"], o["ordering"], seeds, *(fmt_ci(o["metrics"][name]) for name in TABLE_METRICS)])
    return rows


def markdown_table(header: list[str], rows: list[list[str]]) -> str:
    def line(cells):
        return "| " + " | ".join(str(c).replace("|", "\\|") for c in cells) + " |"

    align = ["---:" if h.split()[0].lstrip("Δ") in METRICS or h in ("runs", "pairs") else "---" for h in header]
    return "\n".join([line(header), "| " + " | ".join(align) + " |", *(line(r) for r in rows)]) + "\n"


def summary_csv(agg: dict) -> str:
    """Long format: one line per (method, ordering or "all", metric) with mean, CI, n, undefined."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["method", "ordering", "runs", "metric", "mean", "ci_low", "ci_high", "n", "undefined"])
    for m in agg["methods"]:
        groups = [("all", m["runs"], m["metrics"])] + [(o["ordering"], o["runs"], o["metrics"]) for o in m["orderings"]]
        for ordering, runs, metrics in groups:
            for name in (*TABLE_METRICS, *(x for x in METRICS if x not in TABLE_METRICS and x in metrics)):
                s = metrics[name]
                w.writerow(
                    [
                        m["method"],
                        ordering,
                        runs,
                        name,
                        _csv_num(s["mean"]),
                        _csv_num(s["ci_low"]),
                        _csv_num(s["ci_high"]),
                        s["n"],
                        s["undefined"],
                    ]
                )
    return buf.getvalue()


def _csv_num(v: float | None) -> str:
    return "" if v is None else repr(float(v))
