"""`accrue metrics FILE.json [--json]`: the paper's continual metrics of success curves."""
from __future__ import annotations

from pathlib import Path

import typer


def metrics(
    file: Path = typer.Argument(..., help="JSON with tasks, grid, curves (or a list of such runs, one per seed)."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of a table."),
) -> None:
    """Compute FWT, NBT, continual AUC, ACC_final and F_final (paper Sec. V-A) with bootstrap CIs over seeds."""
    import json

    from accrue.metrics import aggregate, load_metrics_file

    tasks, grid, runs = load_metrics_file(file)
    result = aggregate(runs)
    if as_json:
        print(json.dumps({"tasks": tasks, "grid": grid, **result}, indent=2))
        return
    from rich.console import Console
    from rich.table import Table

    n = len(runs)
    pct = int(result["confidence"] * 100)
    table = Table(title=f"{file.name}: {len(tasks)} tasks, {n} seed{'s' if n != 1 else ''}")
    table.add_column("metric")
    table.add_column("mean", justify="right")
    if n > 1:
        table.add_column(f"{pct}% CI (bootstrap)", justify="right")
    arrows = {"FWT": "↑", "NBT": "↓", "AUC": "↑", "ACC_final": "↑", "F_final": "↓"}
    for name, m in result["metrics"].items():
        mean = "—" if m["mean"] is None else f"{m['mean']:.3f}"
        row = [f"{name} {arrows[name]}", mean]
        if n > 1:
            row.append("—" if m["mean"] is None else f"[{m['ci_low']:.3f}, {m['ci_high']:.3f}]")
        table.add_row(*row)
    console = Console()
    console.print(table)
    if n == 1:
        stages = Table(title="per stage")
        for col in ("stage", "task", "FWT_k", "NBT_k", "AUC_k", "best point"):
            stages.add_column(col, justify="right" if col != "task" else "left")
        per = result["runs"][0]["per_stage"]
        best = result["runs"][0]["best_checkpoint"]
        for k, task in enumerate(tasks):
            nbt = f"{per['NBT'][k]:.3f}" if k < len(per["NBT"]) else "—"
            stages.add_row(str(k + 1), task, f"{per['FWT'][k]:.3f}", nbt, f"{per['AUC'][k]:.3f}",
                           f"{grid[best[k]]:g}")
        console.print(stages)


def register(app: typer.Typer) -> None:
    app.command("metrics")(metrics)
