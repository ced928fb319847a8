"""`accrue bench SPEC.yaml` (run every cell), `accrue bench status SPEC`, `accrue bench report SPEC`,
`accrue bench budget SPEC` (issue 18's Single-task budget rule).

A spec (workflows/bench/*.yaml) names a base workflow and a grid of methods x task orderings x seeds;
each cell is an ordinary workflow run in the store, so finished cells and shared steps are never
recomputed. See stages/bench/spec.py for the spec's fields.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from typer.core import TyperGroup

from cli.store_cmds import JsonOpt, StoreOpt, console, open_store, print_json


class _RunByDefault(TyperGroup):
    """`accrue bench SPEC.yaml ...` means `accrue bench run SPEC.yaml ...`."""

    def parse_args(self, ctx, args):
        if args and args[0] not in self.commands and args[0] not in ("--help", "-h"):
            args = ["run", *args]
        return super().parse_args(ctx, args)


bench_app = typer.Typer(
    cls=_RunByDefault,
    no_args_is_help=True,
    help="Methods x orderings x seeds as workflow runs: `accrue bench SPEC.yaml` runs the "
    "missing cells; `status` and `report` read the store.",
)

SpecArg = Annotated[
    Path, typer.Argument(metavar="SPEC", help="Bench spec YAML (workflows/bench/*.yaml).", show_default=False)
]


def _comma_list(value: str | None, flag: str = "", kind=str) -> list | None:
    if value is None:
        return None
    items = [v.strip() for v in value.split(",") if v.strip()]
    try:
        return [kind(v) for v in items]
    except ValueError:
        from stages.errors import StageError

        raise StageError(f"{flag}: expected comma-separated integers (got {value!r})") from None


@bench_app.command("run")
def run(
    spec: SpecArg,
    executor: Annotated[
        str, typer.Option("--executor", help="ray (default) or serial (one cell after another in this process).")
    ] = "ray",
    serial: Annotated[bool, typer.Option("--serial", help="Same as --executor serial.")] = False,
    address: Annotated[
        Optional[str],
        typer.Option(
            "--address",
            help="Join this Ray cluster (e.g. HEAD:6379) instead of starting a local one. Every node "
            "needs accrue installed, and either the store mounted at the same path or --remote.",
            show_default=False,
        ),
    ] = None,
    num_cpus: Annotated[
        Optional[int],
        typer.Option(
            "--num-cpus", help="CPUs of the local Ray instance (default: all of this machine's).", show_default=False
        ),
    ] = None,
    retries: Annotated[
        Optional[int],
        typer.Option(
            "--retries",
            help="Extra tries of a failed cell (default: the spec's `retries`, else 1).",
            show_default=False,
        ),
    ] = None,
    logs: Annotated[
        Optional[Path],
        typer.Option(
            "--logs", help="Directory of the cells' step logs (default runs/bench/<spec>/logs).", show_default=False
        ),
    ] = None,
    methods: Annotated[
        Optional[str],
        typer.Option("--methods", help="Only these methods of the spec (comma-separated).", show_default=False),
    ] = None,
    orderings: Annotated[
        Optional[str],
        typer.Option("--orderings", help="Only these orderings of the spec (comma-separated).", show_default=False),
    ] = None,
    seeds: Annotated[
        Optional[str],
        typer.Option(
            "--seeds",
            help="Only these seeds of the spec (comma-separated), e.g. two seeds of every method first and the "
            "third later; the report counts what is missing.",
            show_default=False,
        ),
    ] = None,
    remote: Annotated[
        Optional[str],
        typer.Option(
            "--remote",
            help="Nodes share only this remote of the store (default: the spec's `remote`): each runs its "
            "cells on its own store (--node-store), fetching inputs as steps read them and pushing the "
            "results, which are pulled back here.",
            show_default=False,
        ),
    ] = None,
    node_store: Annotated[
        Optional[str],
        typer.Option(
            "--node-store",
            help="With a remote: each node's store ({host} = its name, {node} = its Ray node id; "
            "default ~/.cache/accrue/bench-node-{host}).",
            show_default=False,
        ),
    ] = None,
    store: StoreOpt = None,
    as_json: JsonOpt = False,
) -> int:
    """Run every cell of SPEC that is not finished yet (finished cells are skipped; a failed cell is retried,
    then reported while the others go on). Exit 1 if any cell failed."""
    from stages.bench.execute import run_bench, summary_rows
    from stages.bench.spec import load_spec, select_cells
    from stages.errors import StageError

    if retries is not None and retries < 0:
        raise StageError(f"--retries: must be >= 0 (got {retries})")
    sp = load_spec(spec)
    cells = select_cells(sp, _comma_list(methods), _comma_list(orderings), _comma_list(seeds, "--seeds", int))
    st = open_store(store)
    results = run_bench(
        sp,
        st,
        cells=cells,
        executor="serial" if serial else executor,
        address=address,
        num_cpus=num_cpus,
        retries=retries,
        logs_dir=logs,
        remote=remote,
        node_store=node_store,
    )
    rows = summary_rows(results)
    failed = [r for r in rows if r["state"] == "failed"]
    if as_json:
        print_json(rows)
    else:
        con = console()
        n = {s: sum(r["state"] == s for r in rows) for s in ("done", "skipped", "failed")}
        con.print(
            f"bench {sp.name}: {n['done']} cells run, {n['skipped']} already done, {n['failed']} failed "
            f"(of {len(rows)})"
        )
        for r in failed:
            con.print(
                f"[red]failed[/] {r['method']} · {r['ordering']} · seed {r['seed']} ({r['tries']} tries): {r['error']}"
            )
    return 1 if failed else 0


@bench_app.command("status")
def status(spec: SpecArg, store: StoreOpt = None, as_json: JsonOpt = False) -> None:
    """Each cell's state (done, running, failed, partial, pending) and an ETA, from the store alone."""
    from rich.table import Table

    from stages.bench.progress import hms
    from stages.bench.spec import load_spec
    from stages.bench.state import cell_states, counts, eta_seconds

    sp = load_spec(spec)
    states = cell_states(open_store(store), sp)
    n = counts(states)
    eta = eta_seconds(states)
    rows = [
        {
            "cell": c.name,
            "method": c.method,
            "ordering": c.ordering,
            "seed": c.seed,
            "state": states[c.name].state,
            "stages_done": states[c.name].stages_done,
            "stages": c.workflow.num_stages,
            "running": states[c.name].running_step,
            "error": states[c.name].error,
            "tries": states[c.name].tries,
            "seconds": states[c.name].seconds,
        }
        for c in sp.cells
    ]
    if as_json:
        print_json({"spec": sp.name, "cells": rows, "counts": n, "eta_s": eta})
        return
    con = console()
    con.print(
        f"[bold]bench {sp.name}[/]: {n['done']}/{len(rows)} done · {n['running']} running · "
        f"{n['failed']} failed · {n['partial']} partial · {n['pending']} pending · ETA ≈ {hms(eta)}"
    )
    table = Table(title_justify="left")
    for col in ("method", "ordering", "seed", "state", "stages", "detail"):
        table.add_column(col, overflow="fold")
    colours = {"done": "green", "running": "cyan", "failed": "red", "partial": "yellow", "pending": "dim"}
    for r in rows:
        detail = r["running"] or r["error"] or (f"{r['seconds']:.0f} s, {r['tries']} tries" if r["seconds"] else "")
        table.add_row(
            r["method"],
            r["ordering"],
            str(r["seed"]),
            f"[{colours[r['state']]}]{r['state']}[/]",
            f"{r['stages_done']}/{r['stages']}",
            detail,
        )
    con.print(table)


@bench_app.command("report")
def report(
    spec: SpecArg,
    out: Annotated[
        Optional[Path],
        typer.Option(
            "--out",
            help="Directory for report.md, the CSVs, report.json and the plots (default runs/bench/<spec>/report).",
            show_default=False,
        ),
    ] = None,
    records: Annotated[
        Optional[Path],
        typer.Option(
            "--records",
            help="Directory of cell records (<cell>.json): writes one for every cell the store has done, and "
            "takes a cell the store has not done from its record, so results survive a change of machine.",
            show_default=False,
        ),
    ] = None,
    store: StoreOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Per method, mean over orderings x seeds of NBT, FWT, AUC, ACC_final, F_final with 95% bootstrap CIs;
    the per-ordering breakdown; missing cells listed; Markdown, CSV, JSON and plots written to --out."""
    from stages.bench.records import write_records
    from stages.bench.report import default_out_dir, markdown, report_with_records, write_report
    from stages.bench.spec import load_spec

    sp = load_spec(spec)
    rep, fresh = report_with_records(open_store(store), sp, records)  # a bad record stops before any write
    command = f"accrue bench report {spec}" + ("" if records is None else f" --records {records}")
    files = write_report(rep, out if out is not None else default_out_dir(sp), command=command)
    written = [] if records is None else write_records(records, fresh)
    if as_json:
        print_json({**rep, "files": files, **({} if records is None else {"records_written": list(map(str, written))})})
        return
    typer.echo(markdown(rep, command=command))
    typer.echo("wrote: " + ", ".join(p for p in files.values() if p))
    if records is not None:
        typer.echo(f"records: {len(written)} written or refreshed in {records} ({len(fresh) - len(written)} unchanged)")


@bench_app.command("budget")
def budget(
    spec: SpecArg,
    tolerance: Annotated[
        float,
        typer.Option("--tolerance", help="Plateau: within this much of every larger budget's success (--against)."),
    ] = 0.03,
    against: Annotated[
        str,
        typer.Option(
            "--against",
            help="every: within --tolerance of every larger budget (the rule); next: of the next larger "
            "one only (the rule as first declared, 2026-12-02).",
        ),
    ] = "every",
    store: StoreOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """The per-stage budget rule on a Single-task-only spec (workflows/bench/contact-budget.yaml): per ordering,
    the smallest per-stage budget whose stage-end success is within --tolerance of every larger one's."""
    from stages.bench.budget import AGAINST, choose_budgets
    from stages.bench.spec import load_spec
    from stages.errors import StageError

    if not 0 <= tolerance < 1:
        raise StageError(f"--tolerance: must be in [0, 1) (got {tolerance})")
    if against not in AGAINST:
        raise StageError(f"--against: must be one of {', '.join(AGAINST)} (got {against!r})")
    rows = choose_budgets(open_store(store), load_spec(spec), tolerance, against)
    if as_json:
        print_json(rows)
        return
    for r in rows:
        points = ", ".join(
            f"{p['env_steps']}: {'—' if p['end_success'] is None else format(p['end_success'], '.3f')}"
            f" ({p['runs']} of {p['cells']} runs)"
            for p in r["points"]
        )
        if not r["complete"]:
            verdict = "not chosen: cells missing"
        else:
            verdict = f"chosen {r['chosen']}" + ("" if r["flattened"] else " (the largest: not flattened)")
        typer.echo(f"{r['ordering']}: stage-end success by budget {points} -> {verdict}")


def register(app: typer.Typer) -> None:
    app.add_typer(bench_app, name="bench")
