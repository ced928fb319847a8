"""`accrue stage status` for a workflow with a robot: one table of sessions per hardware step."""

from __future__ import annotations

from rich.table import Table

from cli.store_cmds import console


def print_hardware_status(store, wf) -> None:
    from stages.steps.robot_status import robot_status

    rows = robot_status(store, wf)
    if not rows:
        console().print("robot: no hardware step has run yet")
        return
    for r in rows:
        if "error" in r:
            console().print(f"[red]stage {r['stage']} {r['step']}: cannot read its sealed episodes ({r['error']})[/]")
            continue
        title = (
            f"robot — stage {r['stage']} {r['step']} ({r['state']}): {r['episodes']} episodes, "
            f"{r['successes']} labelled success, robot time {r['robot_time_s']:.1f} s, "
            f"{r['faults']} with faults"
        )
        if "window" in r:
            title += f"; running success {r['window']} — stop rule {r['stop_rule']}"
        table = Table(title=title, title_justify="left")
        for col in ("session", "started", "last seal", "host", "operator", "episodes", "robot time", "ended"):
            table.add_column(col, overflow="fold")
        for s in r["sessions"]:
            table.add_row(
                str(s["id"]),
                s["started"][:19].replace("T", " "),
                s["last"][:19].replace("T", " "),
                s["host"],
                s["operator"],
                str(s["episodes"]),
                f"{s['robot_time_s']:.1f} s",
                s["ended"],
            )
        console().print(table)
