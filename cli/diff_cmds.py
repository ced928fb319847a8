"""`accrue diff A B`: two step records, artifacts (handoffs) or runs side by side. Only typer at
module level; the store code is imported inside the command."""

from __future__ import annotations

from typing import Annotated, Any

import typer

from cli.store_cmds import JsonOpt, StoreOpt, console, open_store, print_json


def _cell(value: Any) -> str:
    if value is None:
        return "-"
    text = str(value)
    return text[:12] if len(text) == 64 and all(c in "0123456789abcdef" for c in text) else text


def diff(
    a: Annotated[
        str, typer.Argument(metavar="A", help="Step record, artifact (id, ref, REF:role) or run (ref prefix).")
    ],
    b: Annotated[str, typer.Argument(metavar="B")],
    show_all: Annotated[bool, typer.Option("--all", help="Also list fields that are the same.")] = False,
    store: StoreOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Which inputs, config fields and code versions differ between A and B, with their metrics side by side."""
    from rich.table import Table

    from artifacts.diff import diff as do_diff

    result = do_diff(open_store(store), a, b, show_all=show_all)
    if as_json:
        print_json(result.as_dict())
        return
    out = console()
    for side, steps in (("A", result.only_a), ("B", result.only_b)):
        for step in steps:
            out.print(f"only in {side}: {step}")
    table = Table(title=f"diff {a} {b}", title_justify="left")
    for col in ("field", "A", "B"):
        table.add_column(col, overflow="fold")
    for name, (va, vb) in result.fields.items():
        table.add_row(name, _cell(va), _cell(vb))
    if not result.fields:
        table.add_row("(no differences)", "", "")
    out.print(table)
    if result.metrics:
        metrics = Table(title="metrics", title_justify="left")
        for col in ("metric", "A", "B", "change"):
            metrics.add_column(col, overflow="fold")
        for name, (va, vb) in result.metrics.items():
            change = f"{vb - va:+.4g}" if isinstance(va, (int, float)) and isinstance(vb, (int, float)) else "-"
            metrics.add_row(name, _cell(va), _cell(vb), change)
        out.print(metrics)


def register(app: typer.Typer) -> None:
    app.command(name="diff")(diff)
