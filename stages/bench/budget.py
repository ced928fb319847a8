"""Issue 18's budget rule, Single-task alone (workflows/bench/contact-budget.yaml): per ordering (one per
task family), the smallest per-stage budget whose stage-end success is within `tolerance` of every larger
budget's; if none is, the largest, flagged as not flattened.

The rule first declared (2026-12-02) compared a budget with the next larger one only (`against="next"`);
on the contact family it chose 12k, where Single-task had barely started to learn (12k 0.320, 24k 0.342,
48k 0.397): two budgets that both precede learning look like a plateau. The amended rule (2026-12-03,
on those Single-task numbers alone; the spec's header has the record) asks that no larger budget measured
gains more than `tolerance`.

    choice = choose_budgets(store, spec)   # [{"ordering", "points": [...], "chosen", "flattened", "complete"}]

A cell's stage-end success is the mean over its stages k of the success of task k at the last grid point
of stage k, read from the disjoint report set when the run has one. A budget is the cells' env_steps; its
point is the mean over its finished cells. The rule is applied only when every cell of the ordering is
done ("complete"): a budget chosen on part of the seeds would be chosen on whichever finished first.
"""

from __future__ import annotations

from artifacts.errors import StoreError
from artifacts.store import Store
from stages.bench.spec import BenchSpec
from stages.bench.state import cell_states
from stages.errors import StageError
from stages.report.data import load_run

TOLERANCE = 0.03


def stage_end_success(run) -> float:
    """Mean over stages of the stage's own task at its last grid point (report set when there is one)."""
    ends = []
    for sc in run.curves:
        curves = sc.report if sc.report is not None else sc.success
        ends.append(curves[sc.task_ids[-1]][-1])
    return sum(ends) / len(ends)


AGAINST = ("every", "next")  # compare a budget with every larger one (the rule), or the next only (as first declared)


def plateau(points: list[tuple[int, float]], tolerance: float = TOLERANCE, against: str = "every") -> tuple[int, bool]:
    """(chosen budget, flattened) from (budget, stage-end success) points: the smallest budget whose success
    is at least every larger budget's (`against="next"`: the next larger one's) minus `tolerance`; none:
    the largest, not flattened."""
    if not points:
        raise ValueError("plateau: no points")
    if against not in AGAINST:
        raise ValueError(f"plateau: against must be one of {AGAINST} (got {against!r})")
    ordered = sorted(points)
    for i, (budget, end) in enumerate(ordered[:-1]):
        larger = ordered[i + 1 :] if against == "every" else ordered[i + 1 : i + 2]
        if all(end >= later - tolerance for _, later in larger):
            return budget, True
    return ordered[-1][0], False


def choose_budgets(store: Store, spec: BenchSpec, tolerance: float = TOLERANCE, against: str = "every") -> list[dict]:
    methods = {c.method for c in spec.cells}
    if any(c.workflow.method != "single-task" for c in spec.cells):
        raise StageError(
            f"{spec.path}: the budget rule is applied to Single-task alone; this spec runs {sorted(methods)}"
        )
    states = cell_states(store, spec)
    out = []
    for ordering in spec.orderings:
        by_budget: dict[int, dict] = {}
        for cell in (c for c in spec.cells if c.ordering == ordering):
            b = by_budget.setdefault(cell.workflow.budgets.env_steps, {"method": cell.method, "ends": [], "cells": 0})
            b["cells"] += 1
            if states[cell.name].state != "done":
                continue
            try:
                b["ends"].append(stage_end_success(load_run(store, cell.workflow)))
            except (StageError, StoreError):
                continue
        points = [
            {
                "env_steps": steps,
                "method": b["method"],
                "runs": len(b["ends"]),
                "cells": b["cells"],
                "end_success": sum(b["ends"]) / len(b["ends"]) if b["ends"] else None,
            }
            for steps, b in sorted(by_budget.items())
        ]
        complete = all(p["runs"] == p["cells"] for p in points)
        chosen, flattened = (
            plateau([(p["env_steps"], p["end_success"]) for p in points], tolerance, against)
            if complete
            else (None, None)
        )
        out.append(
            {
                "ordering": ordering,
                "points": points,
                "tolerance": tolerance,
                "complete": complete,
                "chosen": chosen,
                "flattened": flattened,
            }
        )
    return out
