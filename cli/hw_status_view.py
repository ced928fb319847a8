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
            f"{fault_text(r)}"
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


def fault_text(row: dict, shown: int = 3) -> str:
    """`no faults`, or `1 with faults (episode 4, ended fault: robot did not answer ...)`: which episodes,
    and the first fault of each (the first `shown` of them; `accrue log --event robot-fault` has all)."""
    eps = row.get("fault_episodes")
    if not row["faults"]:
        return "no faults"
    if not eps:
        return f"{row['faults']} with faults"
    parts = []
    for e in eps[:shown]:
        more = f" and {len(e['faults']) - 1} more" if len(e["faults"]) > 1 else ""
        parts.append(f"episode {e['index']}, ended {e['end']}: {e['faults'][0]}{more}")
    rest = f"; {len(eps) - shown} more: accrue log --event robot-fault" if len(eps) > shown else ""
    return f"{row['faults']} with faults ({'; '.join(parts)}{rest})"
