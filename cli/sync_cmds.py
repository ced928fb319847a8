"""`accrue clone URL DIR` and `accrue status`: a new store from a remote, and where each ref stands
against each remote. Only typer at module level; the store code is imported inside each command."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, List, Optional

import typer

from cli.store_cmds import JsonOpt, StoreOpt, human_size, open_store, print_json, transfer_meter


def parse_kinds(only: Optional[List[str]]) -> Optional[set]:
    """--only a,b --only c -> {a, b, c} (each a well-formed kind), or None for everything."""
    if not only:
        return None
    from artifacts.manifests import check_kind

    return {check_kind(k.strip()) for item in only for k in item.split(",") if k.strip()}


def _empty(directory: Path, remove: bool) -> None:
    import shutil

    if remove:
        shutil.rmtree(directory, ignore_errors=True)
        return
    for child in directory.iterdir():
        if child.is_dir():
            shutil.rmtree(child, ignore_errors=True)
        else:
            child.unlink(missing_ok=True)


SettingOpt = Optional[str]
CLONING = "cloning"  # remotes/<name>/cloning: a clone that has not finished (running it again goes on)


def clone(
    url: Annotated[str, typer.Argument(help="s3://BUCKET/PREFIX, or a directory remote.")],
    directory: Annotated[Path, typer.Argument(metavar="DIR", help="The new store's directory (must not be a store).")],
    name: Annotated[str, typer.Option("--name", help="What to call the remote here.")] = "origin",
    only: Annotated[
        Optional[List[str]],
        typer.Option("--only", metavar="KIND", help="Partial clone: the data of these kinds only (see pull --only)."),
    ] = None,
    endpoint: Annotated[
        SettingOpt,
        typer.Option("--endpoint", help="S3 endpoint URL (e.g. http://minio.lab:9000), kept as the remote's setting."),
    ] = None,
    profile: Annotated[
        SettingOpt, typer.Option("--profile", help="AWS profile, kept as the remote's setting.", show_default=False)
    ] = None,
    region: Annotated[
        SettingOpt, typer.Option("--region", help="S3 region, kept as the remote's setting.", show_default=False)
    ] = None,
    jobs: Annotated[Optional[int], typer.Option("--jobs", "-j", min=1, show_default=False)] = None,
    as_json: JsonOpt = False,
) -> None:
    """Make a store in DIR with the remote as `origin`, and pull everything (or --only some kinds). S3
    settings given here are kept in the remote's config (as `accrue remote set` keeps them). A clone cut off
    midway keeps what arrived: the same command again goes on from there."""
    from artifacts.errors import StoreError
    from artifacts.remotes.config import add_remote, check_remote_name, check_setting, parse_url
    from artifacts.store import Store

    spec = parse_url(check_remote_name(name), url)  # a bad URL or setting is refused before anything is made
    settings = {k: v for k, v in (("endpoint", endpoint), ("profile", profile), ("region", region)) if v is not None}
    for key, value in settings.items():
        check_setting(spec, key, value)
    if (directory / "config").exists():
        store = Store.open(directory)
        _resumable(store, spec, url, directory)
        made = False
    else:
        made = not directory.exists()
        if directory.exists() and any(directory.iterdir()):
            raise StoreError(f"{directory} exists and is not empty; clone into a new directory")
        store, _ = Store.init(directory)
        try:
            add_remote(store, name, url)
        except BaseException:
            _empty(directory, remove=made)
            raise
    report = _clone_pull(store, spec, url, directory, made, settings, only, jobs, as_json)
    if as_json:
        print_json({"store": str(store.root), **report.as_dict()})
    else:
        typer.echo(
            f"cloned {url} into {store.root}: {len(report.moved)} refs, {report.objects_received} objects "
            f"({human_size(report.bytes_received)}), {report.steps_indexed} step records in the step cache"
            + (f"; {report.promised} objects left on the remote until needed" if report.promised else "")
        )


def _resumable(store, spec, url: str, directory: Path) -> None:
    """DIR is a store: a clone of this URL that did not finish goes on; anything else is refused,
    naming the commands that work there."""
    from artifacts.errors import StoreError
    from artifacts.remotes.config import list_remotes
    from artifacts.remotes.pointers import state_dir

    known = list_remotes(store).get(spec.name)
    same = known is not None and known.url == (str(spec.path) if spec.kind == "dir" else url)
    if same and (state_dir(store, spec.name) / CLONING).is_file():
        return
    flag = f" --store {directory}"
    if same:
        raise StoreError(
            f"{directory} is a store already, with remote {spec.name} at {url}; "
            f"`accrue pull {spec.name}{flag}` brings what it lacks"
        )
    if known is not None:
        raise StoreError(
            f"{directory} is a store already, whose remote {spec.name} is {known.url}; "
            f"`accrue remote add NAME {url}{flag}` and `accrue pull NAME{flag}` there"
        )
    raise StoreError(
        f"{directory} is a store already; `accrue remote add {spec.name} {url}{flag}` and "
        f"`accrue pull {spec.name}{flag}` there"
    )


def _clone_pull(store, spec, url: str, directory: Path, made: bool, settings: dict, only, jobs, as_json: bool):
    from artifacts.errors import StoreError
    from artifacts.remotes.config import set_setting
    from artifacts.remotes.pointers import state_dir
    from artifacts.remotes.pull import pull

    marker = state_dir(store, spec.name) / CLONING
    try:
        for key, value in settings.items():
            set_setting(store, spec.name, key, value)
        marker.parent.mkdir(parents=True, exist_ok=True)
        marker.touch()
        report = pull(store, spec.name, only=parse_kinds(only), jobs=jobs, meter=transfer_meter(as_json))
    except BaseException as exc:
        # a clone that received nothing leaves nothing behind; one cut off midway is kept, so that
        # running it again goes on from what arrived
        if next(iter(store.iter_object_ids()), None) is None and not list(_user_refs(store)):
            _empty(directory, remove=made)
            raise
        if isinstance(exc, StoreError):
            raise StoreError(
                f"{exc}; the clone in {directory} keeps what arrived: once that is fixed, "
                f"`accrue clone {url} {directory}` again goes on from there"
            ) from None
        raise
    marker.unlink(missing_ok=True)
    return report


def _user_refs(store):
    from artifacts.remotes.pointers import local_refs

    return local_refs(store)


def status(
    remotes: Annotated[
        Optional[List[str]], typer.Argument(metavar="[REMOTE]...", help="Default: every remote.", show_default=False)
    ] = None,
    offline: Annotated[bool, typer.Option("--offline", help="Against what the last fetch saw (no network).")] = False,
    show_all: Annotated[bool, typer.Option("--all", help="Also list refs that are up to date.")] = False,
    store: StoreOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Per ref and remote: up to date, ahead (only here moved), behind (only there), diverged, or on one side only."""
    from artifacts.errors import StoreError
    from artifacts.remotes.config import list_remotes
    from artifacts.remotes.status import STATES, ref_status

    st = open_store(store)
    known = list_remotes(st)
    names = list(remotes or known)
    if not names:
        raise StoreError("this store has no remotes; add one with `accrue remote add NAME URL`")
    result = {n: ref_status(st, n, offline=offline) for n in names}
    if as_json:
        print_json({n: [r.__dict__ for r in rows] for n, rows in result.items()})
        return
    for name, rows in result.items():
        counts = {s: sum(r.state == s for r in rows) for s in STATES}
        summary = ", ".join(f"{c} {s}" for s, c in counts.items() if c) or "no refs"
        typer.echo(f"{name} ({known[name].url}{', as last fetched' if offline else ''}): {summary}")
        for r in rows:
            if r.state != "up-to-date" or show_all:
                ids = f"{r.local[:12] if r.local else '-':12}  {r.remote[:12] if r.remote else '-':12}"
                typer.echo(f"  {r.state:11}  {ids}  {r.ref}")


def register(app: typer.Typer) -> None:
    for fn in (clone, status):
        app.command(name=fn.__name__)(fn)
