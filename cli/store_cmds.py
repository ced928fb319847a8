"""Store commands: init, add, show, lineage, log, refs (and refs delete), verify, gc.

Only typer/rich at module level; the store code is imported inside each command.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Annotated, Any, List, Optional

import typer

StoreOpt = Annotated[
    Optional[Path],
    typer.Option(
        "--store",
        envvar="ACCRUE_STORE",
        help="Store directory (default: ./.accrue, or $ACCRUE_STORE).",
        show_default=False,
    ),
]
JsonOpt = Annotated[bool, typer.Option("--json", help="Machine-readable output.")]


def open_store(path: Path | None):
    from artifacts.store import Store

    return Store.open(path)


def console():
    from rich.console import Console

    return Console(highlight=False)


def print_json(value: Any) -> None:
    typer.echo(json.dumps(value, indent=2, sort_keys=True, default=str))


def human_size(n: int | None) -> str:
    if n is None:
        return "-"
    size = float(n)
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if size < 1024 or unit == "TiB":
            return f"{size:.0f} {unit}" if unit == "B" else f"{size:.1f} {unit}"
        size /= 1024
    return f"{n} B"


def transfer_meter(quiet: bool):
    """Progress of remote transfers: drawn with rich, or silent (with --json)."""
    from artifacts.remotes.progress import RichMeter
    from artifacts.remotes.transfer import Meter

    return Meter() if quiet else RichMeter()


def parse_duration(text: str, option: str = "--grace") -> float:
    m = re.fullmatch(r"\s*(\d{1,12}(?:\.\d{1,9})?)\s*([smhd]?)\s*", text)
    if not m:
        from artifacts.errors import StoreError, quote

        raise StoreError(f"{option}: not a duration {quote(text)} (use e.g. 0, 90s, 30m, 24h, 14d)")
    return float(m.group(1)) * {"": 1, "s": 1, "m": 60, "h": 3600, "d": 86400}[m.group(2)]


# ---------------------------------------------------------------------------- commands
def init(store: StoreOpt = None, as_json: JsonOpt = False) -> None:
    """Create an empty store (default ./.accrue, or $ACCRUE_STORE)."""
    from artifacts.store import Store

    st, created = Store.init(store)
    if as_json:
        print_json({"store": str(st.root), "created": created})
    else:
        typer.echo(f"{'initialised empty' if created else 'already an'} accrue store at {st.root}")


def add(
    path: Annotated[Path, typer.Argument(help="File or directory to ingest.", show_default=False)],
    kind: Annotated[str, typer.Option("--kind", help="Artifact kind, e.g. demos, episodes, base-policy.")],
    ref: Annotated[Optional[str], typer.Option("--ref", help="Also point this ref at it.")] = None,
    workflow: Annotated[
        Optional[Path],
        typer.Option(
            "--workflow",
            help="With --kind demos: a lerobot-record dataset, checked against this workflow's "
            "robot mapping and stored converted into accrue's demo layout.",
            show_default=False,
        ),
    ] = None,
    task: Annotated[
        Optional[str],
        typer.Option(
            "--task",
            help="With --workflow: the workflow task the demonstrations are for (default: the one the "
            "dataset names, or the workflow's only task).",
            show_default=False,
        ),
    ] = None,
    store: StoreOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Ingest a file or directory (e.g. a LeRobotDataset) and print its id."""
    from artifacts.errors import StoreError
    from artifacts.ingest import add_path

    if not path.exists():
        raise StoreError(f"{path}: no such file or directory")
    if task is not None and workflow is None:
        raise StoreError("--task goes with --workflow (the robot whose demonstrations are converted)")
    st = open_store(store)
    if workflow is not None:  # a robot's demonstrations: mapped into accrue's demo layout, then stored
        import shutil
        import tempfile

        from cli.hw_demos import convert_demos_for_workflow

        work = Path(tempfile.mkdtemp(prefix="accrue-demos-"))
        try:
            convert_demos_for_workflow(path, kind, workflow, task, work / "demos")
            artifact_id, created = add_path(st, work / "demos", kind, ref=ref)
        finally:
            shutil.rmtree(work, ignore_errors=True)
    else:
        artifact_id, created = add_path(st, path, kind, ref=ref)
    if as_json:
        print_json({"id": artifact_id, "created": created, "kind": kind})
    else:
        typer.echo(artifact_id)


def show(
    target: Annotated[str, typer.Argument(metavar="ID_OR_REF", help="Id, id prefix, ref, or REF:role.")],
    store: StoreOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Show an artifact, step record or tree."""
    from rich.table import Table

    from artifacts.resolve import resolve

    st = open_store(store)
    oid = resolve(st, target)
    raw = st.read_bytes(oid)
    try:
        obj = json.loads(raw)
    except ValueError:
        obj = None
    if not isinstance(obj, dict) or "type" not in obj:
        if as_json:
            print_json({"id": oid, "type": "data", "size": len(raw)})
        else:
            typer.echo(f"{oid}  data object, {human_size(len(raw))}")
        return
    if as_json:
        print_json({"id": oid, **obj})
        return
    out = console()
    table = Table(title=f"{obj['type']} {oid}", show_header=False, title_justify="left")
    table.add_column(style="bold")
    table.add_column(overflow="fold")
    if obj["type"] == "tree":
        for e in obj["entries"]:
            table.add_row(e["path"], f"{e['id'][:16]}  {human_size(e['size'])}")
    else:
        for field, value in obj.items():
            if field in ("type", "format"):
                continue
            if field == "size":
                value = human_size(value)
            elif isinstance(value, (dict, list)):
                value = json.dumps(value, sort_keys=True) if value else "-"
            table.add_row(field, str(value))
    out.print(table)


def lineage(
    target: Annotated[str, typer.Argument(metavar="ID_OR_REF")], store: StoreOpt = None, as_json: JsonOpt = False
) -> None:
    """The tree of inputs that produced an artifact or step record, down to demos and seeds."""
    from rich.tree import Tree

    from artifacts.lineage import lineage as build
    from artifacts.resolve import resolve

    st = open_store(store)
    node = build(st, resolve(st, target))
    if node.get("error"):  # the target itself cannot be read: nothing to show
        from artifacts.errors import StoreError

        raise StoreError(f"lineage of {target[:200]}: {node['error']}")
    broken = _unreadable(node)
    if as_json:
        print_json(node)
    if broken:  # an incomplete lineage is a finding, like verify's: exit 1, after showing what is known
        typer.echo(
            f"lineage incomplete: {broken} input{'s' if broken != 1 else ''} cannot be read (run `accrue verify`)",
            err=True,
        )
    if as_json:
        if broken:
            raise SystemExit(1)
        return

    def label(n: dict, role: str | None) -> str:
        head = f"[cyan]{role}[/] " if role else ""
        if n.get("repeat"):
            return f"{head}{n['id'][:12]} (shown above)"
        if n.get("error"):
            return f"{head}[red]{n['id'][:12]} {n['error']}[/]"
        what = n.get("kind") or n.get("type")
        step = n.get("step")
        seeds = " ".join(f"{k}={v}" for k, v in (n.get("seeds") or {}).items())
        parts = [f"{head}[bold]{what}[/] {n['id'][:12]}"]
        if step:
            parts.append(f"from {step}")
        if n.get("source"):
            parts.append(f"({n['source']})")
        if seeds:
            parts.append(f"[magenta]{seeds}[/]")
        if n.get("size") is not None:
            parts.append(human_size(n["size"]))
        return "  ".join(parts)

    def grow(tree, n: dict) -> None:
        for role, child in n.get("inputs", {}).items():
            grow(tree.add(label(child, role)), child)

    root = Tree(label(node, None))
    grow(root, node)
    console().print(root)
    if broken:
        raise SystemExit(1)


def _unreadable(node: dict) -> int:
    return sum(bool(child.get("error")) + _unreadable(child) for child in node.get("inputs", {}).values())


def log(
    n: Annotated[int, typer.Option("-n", "--lines", help="Show the last N events.", min=1)] = 20,
    show_all: Annotated[bool, typer.Option("--all", help="Show every event.")] = False,
    event: Annotated[Optional[str], typer.Option("--event", help="Only events of this type.")] = None,
    remote: Annotated[
        Optional[str],
        typer.Option(
            "--remote",
            metavar="NAME",
            help="Other stores' logs, as the last fetch/pull from remote NAME brought them, each "
            "checked as one hash chain across its segments (exit 1 if one is broken).",
        ),
    ] = None,
    store: StoreOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """The audit log: step started/committed/failed, artifacts written, refs moved."""
    from collections import deque

    from rich.table import Table

    from artifacts.auditlog import iter_events

    st = open_store(store)
    chains = None
    if remote is not None:
        from artifacts.remotes.logchain import remote_log_chains

        chains = remote_log_chains(st, remote)
        source = [{**e, "store": c.store_id[:12]} for c in chains for e in c.events]
        source.sort(key=lambda e: str(e.get("ts", "")))
    else:
        source = iter_events(st)
    events = (e for e in source if event is None or e.get("event") == event)
    rows = list(events) if show_all else list(deque(events, maxlen=min(n, 1 << 40)))  # deque caps maxlen
    broken = [c for c in chains or () if not c.ok]
    if as_json:
        if chains is not None:
            print_json({"stores": [c.summary() for c in chains], "events": rows})
        else:
            for e in rows:
                typer.echo(json.dumps(e, sort_keys=True))
        if broken:
            raise SystemExit(1)
        return
    out = console()
    for c in chains or ():
        status = "[green]chain ok[/]" if c.ok else f"[red]{len(c.problems)} problem(s)[/]"
        out.print(f"store {c.store_id[:12]} ({c.host}): {c.segments} segments, {len(c.events)} events, {status}")
        for problem in c.problems:
            out.print(f"  [red]problem:[/] {problem}")
    if chains == []:
        out.print(f"no other store's log came from remote {remote} yet (`accrue fetch {remote}` brings them)")
    table = Table(title=f"audit log ({len(rows)} event{'s' if len(rows) != 1 else ''} shown)", title_justify="left")
    columns = (
        ("store", "seq", "time", "event", "step", "detail")
        if chains is not None
        else ("seq", "time", "event", "step", "detail")
    )
    for col in columns:
        table.add_column(col, overflow="fold")
    skip = {
        "seq",
        "ts",
        "event",
        "step",
        "prev",
        "pid",
        "host",
        "cache_key",
        "inputs",
        "outputs",
        "log_format",
        "store",
    }
    for e in rows:
        detail = " ".join(f"{k}={_short(v)}" for k, v in e.items() if k not in skip and v is not None)
        cells = [
            str(e.get("seq")),
            str(e.get("ts", ""))[:19].replace("T", " "),
            e.get("event", ""),
            e.get("step") or "",
            detail,
        ]
        table.add_row(*([e["store"]] if chains is not None else []), *cells)
    out.print(table)
    if broken:
        raise SystemExit(1)


def _short(value: Any) -> str:
    if isinstance(value, str):
        return re.sub(r"([0-9a-f]{12})[0-9a-f]{52}", r"\1", value)  # ids, also inside ref names
    if isinstance(value, dict):
        return "{" + ",".join(f"{k}:{_short(v)}" for k, v in value.items()) + "}"
    return str(value)


def refs(
    words: Annotated[
        Optional[List[str]],
        typer.Argument(
            metavar="[PREFIX] | delete NAME...",
            help="Only refs starting with PREFIX; or `delete NAME...` to delete refs of this store.",
            show_default=False,
        ),
    ] = None,
    store: StoreOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """List refs (mutable names pointing at artifacts and step records), or delete some: `accrue refs delete NAME`."""
    from rich.table import Table

    from artifacts.errors import StoreError
    from artifacts.refs import list_refs

    words = list(words or [])
    if words[:1] == ["delete"]:
        return _delete_refs(words[1:], store, as_json)
    if len(words) > 1:
        raise StoreError("refs: give one PREFIX to list, or `accrue refs delete NAME...` to delete")
    problems: list[str] = []
    found = list_refs(open_store(store), words[0] if words else "", problems=problems)
    for problem in problems:  # a foreign or damaged file under refs/: say so, list the rest
        typer.echo(f"warning: {problem}", err=True)
    if as_json:
        print_json(found)
        return
    table = Table(title="refs", title_justify="left")
    table.add_column("ref")
    table.add_column("id")
    for name, oid in found.items():
        table.add_row(name, oid[:16])
    console().print(table)


def _delete_refs(names: list[str], store, as_json: bool) -> None:
    """`accrue refs delete NAME...`: every name is checked before any ref goes."""
    from artifacts.errors import StoreError
    from artifacts.refs import check_ref_name, delete_ref, read_ref
    from artifacts.remotes import RESERVED, TRACKING
    from artifacts.remotes.config import list_remotes

    if not names:
        raise StoreError(
            "refs delete: name the ref(s) to delete (e.g. `accrue refs delete workflow/old/stage/1/train`)"
        )
    st = open_store(store)
    for name in names:
        check_ref_name(name)
        if name.startswith(RESERVED):
            raise StoreError(
                f"refs delete {name}: a remote-tracking ref; `accrue fetch --prune` drops those of refs the remote "
                "deleted, `accrue remote remove` all of a remote's"
            )
        if read_ref(st, name) is None:
            raise StoreError(f"refs delete: no ref {name!r} in this store (nothing was deleted)")
    deleted = {}
    for name in dict.fromkeys(names):
        old = delete_ref(st, name)
        if old is not None:
            deleted[name] = old
    remotes = list(list_remotes(st))
    there = {name: [r for r in remotes if read_ref(st, f"{TRACKING}/{r}/{name}") is not None] for name in deleted}
    if as_json:
        print_json({"deleted": deleted, "on_remotes": there})
        return
    for name, oid in deleted.items():
        typer.echo(
            f"deleted ref {name} (was {oid[:12]}; what it named stays until `accrue gc` finds nothing else reaches it)"
        )
        for r in there[name]:
            typer.echo(f"  remote {r} still has it: `accrue push --delete {r} {name}` deletes it there")


def verify(
    full: Annotated[bool, typer.Option("--full", help="Re-hash every object (slow), quarantine corrupt ones.")] = False,
    repair: Annotated[
        bool,
        typer.Option(
            "--repair",
            help="Seal damage found in the audit log (a cut, edited "
            "or half-written tail) with a log-repaired event naming it, so writes can go on.",
        ),
    ] = False,
    remote: Annotated[
        Optional[str],
        typer.Option(
            "--remote",
            metavar="NAME",
            help="Check that remote NAME holds every object its refs reach (with --full: re-hash them).",
        ),
    ] = None,
    store: StoreOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Check the store; exit 1 if anything is wrong."""
    from rich.progress import BarColumn, DownloadColumn, Progress, TransferSpeedColumn

    from artifacts.verify import verify_store

    if remote is not None:
        return _verify_remote(remote, full, store, as_json)
    st = open_store(store)
    if full and not as_json:
        total = sum(st.object_size(o) or 0 for o in st.iter_object_ids())
        with Progress(
            "re-hashing", BarColumn(), DownloadColumn(), TransferSpeedColumn(), console=console(), transient=True
        ) as bar:
            task = bar.add_task("", total=total)
            report = verify_store(st, full=True, progress=lambda n: bar.advance(task, n), repair=repair)
    else:
        report = verify_store(st, full=full, repair=repair)
    if as_json:
        print_json(report.as_dict())
    else:
        out = console()
        for note in report.notes:
            out.print(f"[dim]note: {note}[/]")
        for problem in report.problems:
            out.print(f"[red]problem:[/] {problem}")
        what = (
            f"{report.objects_checked} objects re-hashed ({human_size(report.bytes_hashed)})"
            if full
            else f"{report.objects_checked} reachable objects present with their sizes"
        )
        status = "[green]ok[/]" if report.ok else f"[red]{len(report.problems)} problem(s)[/]"
        out.print(
            f"verify {'--full' if full else '(quick)'}: {status} — {what}, {report.log_events} log events chained"
        )
    if not report.ok:
        # SystemExit, not typer.Exit: cli.main runs the app with standalone_mode=False, where click
        # turns typer.Exit into a return value that main() does not pass on.
        raise SystemExit(1)


def _verify_remote(name: str, full: bool, store, as_json: bool) -> None:
    """`accrue verify --remote NAME`."""
    from artifacts.remotes.check import verify_remote

    report = verify_remote(open_store(store), name, full=full, meter=transfer_meter(as_json))
    if as_json:
        print_json(report.as_dict())
    else:
        out = console()
        for problem in report.problems:
            out.print(f"[red]problem:[/] {problem}")
        status = "[green]ok[/]" if report.ok else f"[red]{len(report.problems)} problem(s)[/]"
        what = f", {human_size(report.bytes_hashed)} re-hashed" if full else ""
        out.print(
            f"verify --remote {name}{' --full' if full else ''}: {status} — {report.reachable} objects "
            f"reachable from {report.refs} refs and logs are on the remote{what}"
        )
        if report.heal:
            lacking = len(report.lacking_here)
            out.print(
                f"to heal it: `{report.heal}`"
                + (f" from a store that has them ({lacking} of them are not in this store)" if lacking else ""),
                soft_wrap=True,
            )
    if not report.ok:
        raise SystemExit(1)


def gc(
    yes: Annotated[bool, typer.Option("--yes", help="Really delete (default is a dry run).")] = False,
    grace: Annotated[str, typer.Option("--grace", help="Keep unreferenced objects younger than this.")] = "24h",
    wait: Annotated[
        str,
        typer.Option(
            "--wait", help="Wait this long for running accrue processes to finish (gc needs the store to itself)."
        ),
    ] = "0",
    store: StoreOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Remove objects no ref or record reaches (dry run unless --yes). Runs only while no other
    accrue process writes to the store."""
    from artifacts.gc import collect_garbage

    report = collect_garbage(
        open_store(store),
        dry_run=not yes,
        grace_s=parse_duration(grace, "--grace"),
        wait_s=parse_duration(wait, "--wait"),
    )
    for problem in report.problems:  # e.g. a damaged ref: what it named is unknown, so --yes refuses
        typer.echo(f"warning: {problem}", err=True)
    if as_json:
        print_json(report.as_dict())
        return
    verb = "would remove" if report.dry_run else "removed"
    typer.echo(
        f"gc: {verb} {len(report.removed)} objects ({human_size(report.bytes)}) and "
        f"{len(report.tmp_removed)} stale temp entries; kept {report.kept} reachable and "
        f"{report.young} younger than {grace}"
        + ("; pass --yes to delete" if report.dry_run and (report.removed or report.tmp_removed) else "")
    )


def register(app: typer.Typer) -> None:
    for fn in (init, add, show, lineage, log, refs, verify, gc):
        app.command(name=fn.__name__)(fn)
