"""Remote commands: `accrue remote add/init/list/remove/set/rekey/prune/repair/unlock`, `accrue push`
(and `push --delete`, `push --verify`), `accrue fetch`, `accrue pull` (both with `--prune`).

Only typer/rich at module level; the store and obstore are imported inside each command.
"""

from __future__ import annotations

from typing import Annotated, List, Optional

import typer

from cli.store_cmds import JsonOpt, StoreOpt, human_size, open_store, parse_duration, print_json, transfer_meter
from cli.sync_cmds import parse_kinds

remote_app = typer.Typer(help="Remotes this store pushes to and pulls from (S3 or a directory).", no_args_is_help=True)

WordsArg = Annotated[
    Optional[List[str]],
    typer.Argument(
        metavar="[NAME] [REF]...",
        help="Remote (optional when there is one, or one named origin), then refs "
        "(a ref, or a prefix like workflow/quick; default: every ref).",
        show_default=False,
    ),
]
JobsOpt = Annotated[
    Optional[int],
    typer.Option(
        "--jobs", "-j", min=1, help="Parallel transfers (default 16, or $ACCRUE_REMOTE_JOBS).", show_default=False
    ),
]
OnlyOpt = Annotated[
    Optional[List[str]],
    typer.Option(
        "--only",
        metavar="KIND",
        help="Partial clone: bring every manifest and record, but the data of these "
        "artifact kinds only (e.g. --only handoff); the rest is fetched when a step needs it.",
        show_default=False,
    ),
]


def _meter(quiet: bool):
    return transfer_meter(quiet)


def _pick(store_path, words: Optional[List[str]]):
    from artifacts.remotes.config import pick_remote

    st = open_store(store_path)
    spec, refs = pick_remote(st, list(words or []))
    return st, spec, refs


def _named(store_path, name: Optional[str]):
    """A command on one remote: the one named (which must exist), else the only one (or origin)."""
    from artifacts.remotes.config import get_remote, pick_remote

    st = open_store(store_path)
    return st, (get_remote(st, name) if name else pick_remote(st, [])[0])


def _fail_on(conflicts: list[str]) -> None:
    if conflicts:
        from artifacts.errors import StoreError

        more = f" (and {len(conflicts) - 1} more conflicting ref(s))" if len(conflicts) > 1 else ""
        raise StoreError(conflicts[0] + more)


# ---------------------------------------------------------------------------- remote add/list/remove
@remote_app.command("add")
def remote_add(
    name: Annotated[str, typer.Argument(help="Short name, e.g. origin or nas.")],
    url: Annotated[str, typer.Argument(help="s3://BUCKET/PREFIX, or a directory (NAS, USB disk).")],
    create: Annotated[
        bool,
        typer.Option("--create", help="Also make it an empty remote (a directory: made; its parent must exist)."),
    ] = False,
    store: StoreOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Add a remote. S3 endpoint, region and credentials come from the usual AWS_* variables or profile,
    or per remote from `accrue remote set NAME endpoint|profile|region VALUE`. A directory remote's
    directory must exist (`--create` makes it, as `accrue remote init NAME` does later)."""
    from artifacts.remotes.config import add_remote, remove_remote_entry

    st = open_store(store)
    spec = add_remote(st, name, url)
    made = None
    if create:
        from artifacts.remotes.create import init_remote

        try:
            made = init_remote(st, spec.name)
        except BaseException:
            remove_remote_entry(st, spec.name)  # a remote that could not be made is not added either
            raise
    missing = spec.kind == "dir" and not spec.path.is_dir()
    if as_json:
        print_json({"name": spec.name, "url": spec.url, "kind": spec.kind, "created": made, "exists": not missing})
        return
    typer.echo(
        f"remote {spec.name}: {spec.url} ({'S3' if spec.kind == 's3' else 'directory'})"
        + ("; made an empty remote there" if made else "")
        + (f"; {spec.path} does not exist yet: `accrue remote init {spec.name}` makes it" if missing else "")
    )


@remote_app.command("init")
def remote_init(
    name: Annotated[Optional[str], typer.Argument(help="The remote (optional when there is one).")] = None,
    store: StoreOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Make the remote an empty accrue remote (a directory: made, its parent must exist). Also how a
    wiped remote starts afresh: this store forgets what it knew of it, so the next push sends everything."""
    from artifacts.remotes.create import init_remote

    st, spec = _named(store, name)
    made = init_remote(st, spec.name)
    if as_json:
        print_json({"name": spec.name, "url": spec.url, "created": made})
    else:
        typer.echo(
            f"remote {spec.name}: {'made an empty remote at' if made else 'already an accrue remote:'} {spec.url}"
        )


@remote_app.command("list")
def remote_list(store: StoreOpt = None, as_json: JsonOpt = False) -> None:
    """List this store's remotes."""
    from artifacts.remotes.config import list_remotes

    remotes = list_remotes(open_store(store))
    if as_json:
        print_json(
            {n: {"url": s.url, "kind": s.kind, "promisor": s.promisor, **s.settings} for n, s in remotes.items()}
        )
        return
    for name, spec in remotes.items():
        extra = "".join(f"\t{k}={v}" for k, v in sorted(spec.settings.items()))
        typer.echo(
            f"{name}\t{spec.url}{extra}" + ("\t(partial clone: fetches lazily from here)" if spec.promisor else "")
        )


@remote_app.command("remove")
def remote_remove(
    name: Annotated[str, typer.Argument()],
    force: Annotated[bool, typer.Option("--force", help="Even if a partial clone still needs it.")] = False,
    store: StoreOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Forget a remote and its remote-tracking refs (nothing on the remote changes)."""
    from artifacts.remotes.forget import forget_remote

    dropped = forget_remote(open_store(store), name, force=force)
    if as_json:
        print_json({"removed": name, "tracking_refs_dropped": dropped})
    else:
        typer.echo(f"removed remote {name} ({dropped} remote-tracking refs dropped)")


@remote_app.command("set")
def remote_set(
    name: Annotated[str, typer.Argument(help="The remote.")],
    key: Annotated[str, typer.Argument(help="endpoint, profile or region (S3 remotes).")],
    value: Annotated[Optional[str], typer.Argument(help="The value; leave out with --unset.")] = None,
    unset: Annotated[bool, typer.Option("--unset", help="Remove the setting (the AWS_* environment applies).")] = False,
    store: StoreOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Per-remote S3 settings, used over the AWS_* environment: endpoint, profile, region."""
    from artifacts.errors import StoreError
    from artifacts.remotes.config import set_setting

    if (value is None) != unset:
        raise StoreError("give a value, or --unset (not both)")
    spec = set_setting(open_store(store), name, key, None if unset else value)
    if as_json:
        print_json({"name": spec.name, **spec.settings})
    else:
        typer.echo(f"remote {spec.name}: {key} {'unset' if unset else '= ' + str(value)}")


@remote_app.command("rekey")
def remote_rekey(store: StoreOpt = None, as_json: JsonOpt = False) -> None:
    """Give this store a new id (after copying a store with cp -a): its audit log starts a new chain."""
    from artifacts.remotes.config import rekey_store

    old, new = rekey_store(open_store(store))
    if as_json:
        print_json({"old": old, "new": new})
    else:
        typer.echo(f"store id {old[:12] if old else '(none)'} -> {new[:12]}")


@remote_app.command("prune")
def remote_prune(
    name: Annotated[Optional[str], typer.Argument(help="The remote (optional when there is one).")] = None,
    yes: Annotated[bool, typer.Option("--yes", help="Really delete (default is a dry run).")] = False,
    grace: Annotated[
        str, typer.Option("--grace", help="Keep unreachable objects and unfinished uploads younger than this.")
    ] = "24h",
    jobs: JobsOpt = None,
    store: StoreOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Delete objects nothing on the remote reaches, and uploads killed pushes left (dry run unless --yes)."""
    from artifacts.remotes.prune import prune_remote

    st, spec, _ = _pick(store, [name] if name else [])
    report = prune_remote(st, spec.name, dry_run=not yes, grace_s=parse_duration(grace, "--grace"), jobs=jobs)
    if as_json:
        print_json(report.as_dict())
        return
    verb = "would remove" if report.dry_run else "removed"
    typer.echo(
        f"prune {spec.name}: {verb} {len(report.removed)} unreachable objects ({human_size(report.bytes)}) and "
        f"{len(report.uploads)} unfinished uploads; kept {report.reachable} reachable and {report.young} "
        f"younger than {grace}"
        + ("; pass --yes to delete" if report.dry_run and (report.removed or report.uploads) else "")
    )
    for lease in report.leases_taken_over:
        typer.echo(f"  took over the lease of a push that is gone: {lease}")


@remote_app.command("unlock")
def remote_unlock(
    name: Annotated[Optional[str], typer.Argument(help="The remote (optional when there is one).")] = None,
    every: Annotated[
        bool,
        typer.Option(
            "--all",
            help="Remove every lease, live ones too (and a directory remote's ref lock files): only when "
            "no push to this remote is running anywhere.",
        ),
    ] = False,
    store: StoreOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Remove the leases of pushes that are gone (stale: not renewed for 15 min, or their process on this
    host has ended), which `remote prune` waits for; --all removes every lease."""
    from artifacts.remotes.lease import unlock_remote

    st, spec = _named(store, name)
    dropped, kept, locks = unlock_remote(st, spec.name, every)
    if as_json:
        print_json(
            {
                "removed": [lease.describe() for lease in dropped],
                "live": [lease.describe() for lease in kept],
                "ref_locks_removed": locks,
            }
        )
        return
    for lease in dropped:
        typer.echo(f"  removed {lease.state if not every else 'lease'}: {lease.describe()}")
    for key in locks:
        typer.echo(f"  removed ref lock {key}")
    for lease in kept:
        typer.echo(f"  kept live: {lease.describe()}")
    typer.echo(
        f"unlock {spec.name}: removed {len(dropped)} lease(s)"
        + (f"; kept {len(kept)} live (`--all` removes them if no push is running)" if kept else "")
    )


@remote_app.command("repair")
def remote_repair(
    name: Annotated[Optional[str], typer.Argument(help="The remote (optional when there is one).")] = None,
    full: Annotated[
        bool, typer.Option("--full", help="Also download and re-hash every object, to find corrupt ones.")
    ] = False,
    jobs: JobsOpt = None,
    store: StoreOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Re-send every object the remote's refs reach that it lacks or holds damaged, from this store."""
    from artifacts.remotes.repair import repair_remote

    st, spec, _ = _pick(store, [name] if name else [])
    report = repair_remote(st, spec.name, full=full, jobs=jobs, meter=_meter(as_json))
    if as_json:
        print_json(report.as_dict())
    else:
        typer.echo(
            f"repair {spec.name}: {report.damaged} damaged or missing, re-sent {len(report.resent)} "
            f"({human_size(report.bytes_sent)})"
            + (f"; {len(report.unhealed)} not in this store either" if report.unhealed else "")
        )
    if report.unhealed:
        from artifacts.errors import StoreError

        raise StoreError(
            f"remote {spec.name}: {len(report.unhealed)} damaged object(s) this store lacks too "
            f"(first {report.unhealed[0][:12]}); run `accrue remote repair {spec.name}` from a store that has them"
        )


# ---------------------------------------------------------------------------- push / fetch / pull
def push(
    words: WordsArg = None,
    force: Annotated[
        bool,
        typer.Option(
            "--force", help="Move remote refs even if someone else moved them (theirs kept as displaced/REF/ID)."
        ),
    ] = False,
    delete: Annotated[
        bool,
        typer.Option("--delete", help="Remove the named refs from the remote instead (if still where last seen)."),
    ] = False,
    verify: Annotated[
        bool,
        typer.Option(
            "--verify",
            help="Also download and re-hash every object the refs reach on the remote, and send corrupt ones again.",
        ),
    ] = False,
    jobs: JobsOpt = None,
    store: StoreOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Make sure the remote holds every object the refs reach (sending what it lacks), then move the remote's
    refs (compare-and-swap). A ref deleted there since this store last saw it is not made again."""
    from artifacts.remotes.push import push as do_push

    st, spec, refs = _pick(store, words)
    if delete:
        return _delete(st, spec.name, refs, as_json)
    report = do_push(st, spec.name, refs, force=force, jobs=jobs, meter=_meter(as_json), verify=verify)
    if as_json:
        print_json(report.as_dict())
    else:  # plain echo, not rich: a no-op push should cost little more than start-up
        for name, (old, new) in report.moved.items():
            typer.echo(f"  {name}: {old[:12] if old else '(new)'} -> {new[:12]}")
        for name in report.behind:
            typer.echo(f"  {name}: the remote has moved on; `accrue pull {spec.name} {name}` to get it")
        for name in report.gone_there:
            typer.echo(
                f"  {name}: deleted on {spec.name} since this store last saw it, not sent; "
                f"`accrue pull --prune {spec.name} {name}` deletes it here, "
                f"`accrue push --force {spec.name} {name}` puts it back there"
            )
        for name, keep in report.displaced.items():
            typer.echo(f"  {name}: the remote's previous id is kept there as ref {keep}")
        for lease in report.leases_taken_over:
            typer.echo(f"  took over the lease of a push that is gone: {lease}")
        for upload in report.uploads_resumed:
            typer.echo(f"  finished a killed push's upload of {upload}")
        healed = f" ({len(report.healed)} missing or damaged there although its refs reach them)"
        typer.echo(
            f"push -> {spec.name}: sent {report.objects_sent} objects ({human_size(report.bytes_sent)})"
            + (healed if report.healed else "")
            + f", moved {len(report.moved)} refs, {len(report.up_to_date)} up to date"
            + (f", {len(report.gone_there)} deleted there" if report.gone_there else "")
            + (f", {len(report.conflicts)} refused" if report.conflicts else "")
            + (f"; {report.objects_rehashed} objects re-hashed there" if verify else "")
        )
    _fail_on(report.conflicts)


def _delete(st, remote: str, refs: list[str], as_json: bool) -> None:
    from artifacts.remotes.unshare import delete_remote_refs

    report = delete_remote_refs(st, remote, refs)
    if as_json:
        print_json(report.as_dict())
    else:
        from artifacts.refs import read_ref

        for name, oid in report.deleted.items():
            here = read_ref(st, name) is not None
            typer.echo(
                f"  {name}: deleted on {remote} (was {oid[:12]})"
                + (
                    "; still in this store: `accrue refs delete` deletes it here, else a push sends it again"
                    if here
                    else ""
                )
            )
        typer.echo(f"push --delete -> {remote}: {len(report.deleted)} refs deleted")
    _fail_on(report.conflicts)


def _print_fetch(report, verb: str, as_json: bool) -> None:
    if as_json:
        print_json(report.as_dict())
        return
    for name, (old, new) in report.moved.items():
        typer.echo(f"  {name}: {old[:12] if old else '(new)'} -> {new[:12]}")
    for name in report.ahead:
        typer.echo(f"  {name}: only this store moved it; `accrue push {report.remote} {name}` shares it")
    for name, keep in report.displaced.items():
        typer.echo(f"  {name}: this store's previous id is kept as ref {keep}")
    for name in report.deleted_here:
        typer.echo(
            f"  {name}: deleted in this store, not taken again; `accrue push --delete {report.remote} {name}` "
            f"deletes it there, `accrue pull --force {report.remote} {name}` brings it back"
        )
    for name, oid in report.deleted.items():
        typer.echo(f"  {name}: deleted here, as on {report.remote} (was {oid[:12]})")
    if not report.pruned and not report.deleted:
        for name in sorted(n for n in report.gone if n not in report.deleted):
            typer.echo(
                f"  {name}: deleted on {report.remote}; `accrue {verb} --prune {report.remote} {name}` "
                + ("deletes it here" if verb == "pull" else "drops its remote-tracking ref")
            )
    tail = f"; {report.promised} objects left on the remote until needed" if report.promised else ""
    if report.steps_indexed:
        tail += f"; {report.steps_indexed} step records now in the step cache"
    moved = f", moved {len(report.moved)} local refs" if verb == "pull" else ""
    if report.deleted or report.pruned:
        moved += f", deleted {len(report.deleted) if verb == 'pull' else len(report.pruned)} gone there"
    typer.echo(
        f"{verb} <- {report.remote}: received {report.objects_received} objects "
        f"({human_size(report.bytes_received)}) for {len(report.refs)} refs{moved}{tail}"
    )


PruneOpt = Annotated[
    bool,
    typer.Option(
        "--prune",
        help="Pass on refs the remote deleted: fetch drops their remote-tracking refs; pull also deletes each "
        "local one not moved here since the two sides last agreed.",
    ),
]


def fetch(
    words: WordsArg = None,
    only: OnlyOpt = None,
    prune: PruneOpt = False,
    jobs: JobsOpt = None,
    store: StoreOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Download what the remote's refs reach (verified) and update the remote-tracking refs only."""
    from artifacts.remotes.pull import fetch as do_fetch

    st, spec, refs = _pick(store, words)
    report = do_fetch(st, spec.name, refs, only=parse_kinds(only), jobs=jobs, meter=_meter(as_json), prune=prune)
    _print_fetch(report, "fetch", as_json)


def pull(
    words: WordsArg = None,
    only: OnlyOpt = None,
    force: Annotated[
        bool,
        typer.Option(
            "--force", help="Take the remote's refs even over local changes (yours kept as displaced/REF/ID)."
        ),
    ] = False,
    prune: PruneOpt = False,
    jobs: JobsOpt = None,
    store: StoreOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """fetch, then fast-forward: take each ref only the remote moved since the two sides last agreed
    (with --prune, delete each one only the remote deleted)."""
    from artifacts.remotes.pull import pull as do_pull

    st, spec, refs = _pick(store, words)
    report = do_pull(
        st, spec.name, refs, only=parse_kinds(only), force=force, jobs=jobs, meter=_meter(as_json), prune=prune
    )
    _print_fetch(report, "pull", as_json)
    _fail_on(report.conflicts)


def register(app: typer.Typer) -> None:
    app.add_typer(remote_app, name="remote")
    for fn in (push, fetch, pull):
        app.command(name=fn.__name__)(fn)
