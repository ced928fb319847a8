"""`accrue report WORKFLOW [--json] [--out DIR]`: the continual metrics of a workflow's committed
run, its per-task base-vs-after-RL success, and figures plus a rerun recording written to DIR."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from cli.store_cmds import JsonOpt, StoreOpt, console, open_store, print_json

ARROWS = {"FWT": "↑", "NBT": "↓", "AUC": "↑", "ACC_final": "↑", "F_final": "↓"}


def _num(value: float | None) -> str:
    return "—" if value is None else f"{value:.3f}"


def report(
    workflow: Annotated[Path, typer.Argument(metavar="WORKFLOW", help="Workflow YAML file.", show_default=False)],
    out: Annotated[
        Optional[Path],
        typer.Option(
            "--out",
            help="Directory for the figures, recording and report.json (default: runs/<workflow-name>/report/ for "
            "the default store, <store>-report/<workflow-name>/ beside any other).",
            show_default=False,
        ),
    ] = None,
    single_task: Annotated[
        Optional[Path],
        typer.Option(
            "--single-task",
            help="Hardware workflows: a Single-task workflow of the same tasks to compare robot time against (Fig. 4).",
            show_default=False,
        ),
    ] = None,
    store: StoreOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Metrics (FWT, NBT, AUC, ACC_final, F_final), per-task base vs after-RL success, plots and a .rrd.
    A workflow with a robot gets the paper's Fig. 4 and Table III instead."""
    from stages.report.build import default_out_dir, write_report
    from stages.workflow import load_workflow

    wf = load_workflow(workflow)
    st = open_store(store)
    out = out if out is not None else default_out_dir(wf, st)
    if wf.robot is not None:
        from stages.report.hardware import write_hardware_report

        other = load_workflow(single_task) if single_task is not None else None
        summary = write_hardware_report(st, wf, out, other)
        if as_json:
            print_json(summary)
        else:
            _print_hardware(summary)
        return
    summary = write_report(st, wf, out)
    if as_json:
        print_json(summary)
        return
    _print_summary(summary)


def _missing_text(missing: list[dict]) -> str:
    by_stage: dict[int, list[str]] = {}
    for m in missing:
        by_stage.setdefault(m["stage"], []).append(m["step"])
    return "; ".join(f"stage {k} {', '.join(steps)}" for k, steps in sorted(by_stage.items()))


def _print_summary(s: dict) -> None:
    from rich.table import Table

    con = console()
    m, K = s["stages_reported"], s["stages_total"]
    scope = f"stages 1..{m} of {K}" if m < K else f"all {K} stages"
    con.print(f"[bold]workflow {s['workflow']}[/] ({s['method']}, seed {s['seed']}): {scope}")
    if s["missing"]:
        con.print(f"[yellow]not committed yet: {_missing_text(s['missing'])}[/]")

    metrics = Table(title="metrics (Sec. V-A)", title_justify="left")
    metrics.add_column("metric")
    metrics.add_column("value", justify="right")
    undefined = any(v is None for v in s["metrics"].values())
    if undefined:
        metrics.add_column("note", style="dim")
    for name, value in s["metrics"].items():
        row = [f"{name} {ARROWS[name]}", _num(value)]
        if undefined:
            row.append("needs ≥ 2 stages" if value is None else "")
        metrics.add_row(*row)
    con.print(metrics)

    stages = Table(title="per stage", title_justify="left")
    for col in ("stage", "task", "FWT_k", "NBT_k", "AUC_k", "e* (env steps)"):
        stages.add_column(col, justify="left" if col == "task" else "right")
    per = s["per_stage"]
    for i, st in enumerate(s["stages"]):
        stages.add_row(
            str(st["stage"]),
            st["task"],
            _num(per["FWT"][i]),
            _num(per["NBT"][i]) if i < len(per["NBT"]) else "—",
            _num(per["AUC"][i]),
            str(s["best_checkpoint"][i]["env_steps"]),
        )
    con.print(stages)

    tasks = Table(title="per task: base policy vs after RL (deployment, evaluate-all)", title_justify="left")
    for col in (
        "task",
        "learned in",
        "base π_base",
        "after RL",
        "eval (stage, episodes)",
        "best in own stage c_jj",
        f"after stage {m} c_{m}j",
    ):
        tasks.add_column(col, justify="left" if col == "task" else "right")
    for row in s["per_task"]:
        where = "—" if row["eval_stage"] is None else f"stage {row['eval_stage']}, {row['episodes']}"
        tasks.add_row(
            row["task"],
            f"stage {row['stage']}",
            _num(row["base_success"]),
            _num(row["after_rl_success"]),
            where,
            _num(row["best_in_own_stage"]),
            _num(row["at_last_stage"]),
        )
    con.print(tasks)

    con.print("wrote:")
    for name, path in s["files"].items():
        if path is None:
            con.print(f"  {name}: [dim]not written (no evaluate-all committed yet)[/]")
        else:
            con.print(f"  {path}")


def register(app: typer.Typer) -> None:
    app.command("report")(report)


def _print_hardware(summary: dict) -> None:
    for k, st in summary["stages"].items():
        reached, rule = st["reached_robot_time_s"], st["stop_rule"]
        typer.echo(
            f"stage {k}: warmup {st['warmup_robot_time_s']:.1f} s, RL {st['rl_robot_time_s']:.1f} s over "
            f"{st['episodes']} episodes; "
            + (
                f"{rule['successes']}/{rule['window']} reached at {reached:.1f} s of RL robot time"
                if reached is not None
                else f"not reached ({st['stopped']})"
            )
        )
    for k, row in summary.get("single_task", {}).get("time_saved", {}).items():
        typer.echo(
            f"stage {k}: Single-task needed {row['single_task_s']:.1f} s, {summary['workflow']} "
            f"{row['accrue_s']:.1f} s: {row['saved_s']:.1f} s saved ({row['saved_percent']}%)"
        )
    for k, row in summary.get("interventions", {}).items():
        warm = row.get("warmup")
        typer.echo(
            f"stage {k}: interventions"
            + (f" in warmup {warm['episodes']} {100 * warm['rate']:.1f}%;" if warm else "")
            + f" per {row['window']}-episode train window: "
            + (", ".join(f"{w['episodes']} {100 * w['rate']:.1f}%" for w in row["windows"]) or "none")
        )
    for name, path in summary["files"].items():
        typer.echo(f"{name}: {path}")
