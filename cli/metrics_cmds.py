"""`accrue metrics FILE.json... [--json]`: the paper's continual metrics of success curves, per method
and per task ordering when the runs are labelled."""

from __future__ import annotations

from pathlib import Path

import typer


def metrics(
    files: list[Path] = typer.Argument(
        ...,
        help="JSON files, each one run {tasks, grid, curves} or a list of runs; "
        "a run may carry method, ordering and seed labels.",
    ),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of tables."),
) -> None:
    """FWT, NBT, continual AUC, ACC_final and F_final (paper Sec. V-A) of each run; per method, the mean
    over its runs (orderings x seeds) with a 95% percentile-bootstrap CI (4000 resamples, seed 0), and
    the same per ordering. Runs may follow different task orderings (permutations or other sequences)."""
    import json

    from accrue.metrics import aggregate_runs, load_metrics_file, run_record

    loaded = []
    for f in files:
        try:
            loaded += load_metrics_file(f)
        except RecursionError:  # json.loads of absurdly nested input
            from accrue.errors import AccrueError

            raise AccrueError(f"{f}: JSON nested too deeply to be a metrics file") from None
    records = [
        run_record(r["curves"], method=r["method"], tasks=r["tasks"], ordering=r["ordering"], seed=r["seed"])
        for r in loaded
    ]
    agg = aggregate_runs(records)
    if as_json:
        print(json.dumps({**agg, "runs": records}, indent=2))
        return
    from rich.console import Console

    console = Console(highlight=False)
    if len(records) == 1:
        _print_single(console, loaded[0], records[0])
    else:
        _print_groups(console, agg, files)


def _print_single(console, run: dict, record: dict) -> None:
    from rich.table import Table

    from stages.report.tables import ARROWS, TABLE_METRICS, fmt

    table = Table(title=f"{run['method']}: {len(run['tasks'])} tasks, one run")
    table.add_column("metric")
    table.add_column("value", justify="right")
    for name in TABLE_METRICS:
        table.add_row(f"{name} {ARROWS[name]}", fmt(record["metrics"][name]))
    console.print(table)
    stages = Table(title="per stage")
    for col in ("stage", "task", "FWT_k", "NBT_k", "AUC_k", "best point"):
        stages.add_column(col, justify="right" if col != "task" else "left")
    per, best, grid = record["per_stage"], record["best_checkpoint"], run["grid"]
    for k, task in enumerate(run["tasks"]):
        nbt = fmt(per["NBT"][k]) if k < len(per["NBT"]) else "—"
        stages.add_row(str(k + 1), task, fmt(per["FWT"][k]), nbt, fmt(per["AUC"][k]), f"{grid[best[k]]:g}")
    console.print(stages)


def _print_groups(console, agg: dict, files: list[Path]) -> None:
    from rich.table import Table

    from stages.report.tables import METHOD_HEADER, ORDERING_HEADER, method_rows, ordering_rows

    pct = round(agg["confidence"] * 100)
    names = ", ".join(f.name for f in files)
    for title, header, rows in (
        (f"{names}: per method, mean [{pct}% bootstrap CI] over runs", METHOD_HEADER, method_rows(agg)),
        ("per ordering (mean [CI] over its seeds)", ORDERING_HEADER, ordering_rows(agg)),
    ):
        table = Table(title=title, title_justify="left")
        for col in header:
            table.add_column(col, justify="left" if col in ("method", "ordering", "seeds") else "right")
        for row in rows:
            table.add_row(*row)
        console.print(table)
    console.print(
        f"[dim]percentile bootstrap of the mean, {agg['resamples']} resamples, numpy seed "
        f"{agg['bootstrap_seed']}; '—' = undefined (NBT and F_final need ≥ 2 stages)[/]"
    )


def register(app: typer.Typer) -> None:
    app.command("metrics")(metrics)
