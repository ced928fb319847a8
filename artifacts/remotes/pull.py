"""fetch: download what the remote's refs reach, every object verified on arrival, then move the
remote-tracking refs and enter the step records that came in the step cache. pull: fetch, then
fast-forward each local ref that has not moved since this store and the remote last agreed on it
(or that does not exist yet); a ref only this store moved (or deleted) stays; one both moved is a
conflict. --only leaves other kinds' data on the remote. --prune passes deletions on: fetch drops the
remote-tracking refs of refs the remote no longer has, pull also deletes each such local ref that has
not moved since the two sides last agreed on it (compare-and-delete, like every other fast-forward)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from artifacts.auditlog import append_event
from artifacts.errors import StoreError
from artifacts.links import children
from artifacts.manifests import KNOWN_KINDS
from artifacts.refs import delete_ref, read_ref, set_ref
from artifacts.remotes import LOG_TRACKING, TRACKING
from artifacts.remotes.backends import Backend
from artifacts.remotes.closure import bottom_up
from artifacts.remotes.config import get_remote, set_promisor
from artifacts.remotes.connect import open_backend
from artifacts.remotes.lazy import add_promised
from artifacts.remotes.logsegment import KIND as LOG_KIND
from artifacts.remotes.pointers import (
    both_moved,
    check_remote_config,
    displaced_ref,
    forget_bases,
    merge_bases,
    read_pointers,
    record_bases,
    select_refs,
    tracking_refs,
)
from artifacts.remotes.stepindex import index_step_records
from artifacts.remotes.transfer import Meter, default_jobs, download_manifest, download_object, flush_dirs, parallel
from artifacts.store import Store


@dataclass
class FetchReport:
    remote: str
    refs: dict[str, str] = field(default_factory=dict)  # remote ref -> id fetched
    logs: dict[str, str] = field(default_factory=dict)  # other store's id -> log segment id
    objects_received: int = 0
    bytes_received: int = 0
    promised: int = 0
    steps_indexed: int = 0  # step records entered in this store's step cache
    moved: dict[str, list] = field(default_factory=dict)  # pull: local ref -> [old, new]
    up_to_date: list[str] = field(default_factory=list)
    ahead: list[str] = field(default_factory=list)  # pull: only this store moved (push shares it)
    displaced: dict[str, str] = field(default_factory=dict)  # pull --force: ref keeping the local id
    conflicts: list[str] = field(default_factory=list)
    gone: dict[str, str] = field(default_factory=dict)  # deleted on the remote since last seen -> last id
    pruned: list[str] = field(default_factory=list)  # --prune: remote-tracking refs dropped (fetch)
    deleted: dict[str, str] = field(default_factory=dict)  # pull --prune: local refs deleted -> their id
    deleted_here: list[str] = field(default_factory=list)  # pull: deleted in this store only (push --delete)

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class _RemotePlan:
    manifests: dict[str, bytes] = field(default_factory=dict)  # downloaded, not yet stored
    named: dict[str, list[str]] = field(default_factory=dict)
    data: dict[str, int] = field(default_factory=dict)  # to download
    skipped: dict[str, int] = field(default_factory=dict)  # left on the remote (--only)
    kinds: set[str] = field(default_factory=set)  # artifact kinds met


def _remote_closure(store: Store, backend: Backend, roots: list[str], only: set[str] | None, jobs: int) -> _RemotePlan:
    """Breadth first: each level's missing manifests arrive in parallel (verified, in memory);
    manifests already here are read locally. `only`: data of other artifact kinds stays behind."""
    plan = _RemotePlan()
    visited: set[tuple[str, bool]] = set()
    level: list[tuple[str, int | None, bool]] = [(r, None, False) for r in roots]
    while level:
        level = [item for item in dict.fromkeys(level) if (item[0], item[2]) not in visited]
        visited.update((oid, skip) for oid, _, skip in level)
        wanted = sorted(
            {oid for oid, size, _ in level if size is None and oid not in plan.manifests and not store.has_object(oid)}
        )
        for oid, raw in zip(wanted, parallel(lambda o: download_manifest(backend, o), wanted, jobs)):
            plan.manifests[oid] = raw
        following: list[tuple[str, int | None, bool]] = []
        for oid, size, skip in level:
            if size is not None:
                if store.has_object(oid) or oid in plan.data:
                    continue
                if skip:
                    plan.skipped[oid] = size
                else:
                    plan.data[oid] = size
                    plan.skipped.pop(oid, None)
                continue
            obj = json.loads(plan.manifests[oid]) if oid in plan.manifests else store.read_json(oid)
            kids = children(oid, obj)
            plan.named[oid] = [k for k, _ in kids]
            if obj.get("type") == "artifact":
                plan.kinds.add(str(obj.get("kind")))
                leave = only is not None and obj.get("kind") not in only and obj.get("kind") != LOG_KIND
                following.append((kids[0][0], kids[0][1], leave))  # its content
                following += [(k, s, False) for k, s in kids[1:]]  # its inputs decide alone
            else:
                following += [(k, s, skip) for k, s in kids]  # tree entries inherit
        level = following
    return plan


def _gone(store: Store, remote: str, current: dict[str, str], wanted: list[str]) -> dict[str, str]:
    """Refs this store saw on the remote (agreed on, or fetched) that it no longer has: name -> last id."""
    known = {**tracking_refs(store, remote), **merge_bases(store, remote)}
    gone = {n: i for n, i in known.items() if n not in current}
    return {n: i for n, i in gone.items() if not wanted or any(_matches({n: i}, w) for w in wanted)}


def fetch(
    store: Store,
    remote: str,
    refs: list[str] | None = None,
    only: set[str] | None = None,
    jobs: int | None = None,
    meter: Meter | None = None,
    prune: bool = False,
) -> FetchReport:
    spec = get_remote(store, remote)
    backend = open_backend(spec)
    jobs, meter = jobs or default_jobs(), meter or Meter()
    report = FetchReport(remote=spec.name)
    check_remote_config(backend, create=False)
    current = {n: v[0] for n, v in read_pointers(store, spec, backend, "refs").items()}
    report.gone = _gone(store, spec.name, current, refs or [])
    # a ref named that the remote deleted is no error with --prune: its deletion is what is fetched
    wanted = [w for w in refs or [] if not (prune and not _matches(current, w) and _matches(report.gone, w))]
    chosen = select_refs(current, wanted, f"on remote {spec.name}") if wanted or not refs else {}
    own = store.read_config().get("store_id")
    seen_logs = tracking_refs(store, spec.name, LOG_TRACKING)
    logs = {
        sid: v[0]
        for sid, v in read_pointers(store, spec, backend, "logs").items()
        if sid != own and seen_logs.get(sid) != v[0]
    }

    plan = _remote_closure(store, backend, list(chosen.values()) + list(logs.values()), only, jobs)
    unknown = sorted(k for k in only or () if k not in plan.kinds and k not in KNOWN_KINDS)
    if unknown:  # a typo would otherwise leave every artifact's data behind, silently
        there = ", ".join(sorted(plan.kinds - {LOG_KIND})) or "none"
        raise StoreError(f"--only {unknown[0]}: no artifact of that kind on remote {spec.name} (kinds there: {there})")
    meter.start(f"pull ← {spec.name}", len(plan.data) + len(plan.manifests), sum(plan.data.values()))

    new_dirs: set[Path] = set()

    def get(item: tuple[str, int]) -> None:
        download_object(store, backend, item[0], item[1], new_dirs)
        meter.advance(item[1])

    try:
        try:
            parallel(get, sorted(plan.data.items()), jobs)
        finally:
            flush_dirs(new_dirs, jobs)  # what arrived is kept (durably) even if the rest failed
        for group in bottom_up(plan.named):  # manifests after everything they name
            for oid in group:
                if oid in plan.manifests:
                    store.put_bytes(plan.manifests[oid])
                    meter.advance(0)
    finally:
        meter.stop()
    report.objects_received = len(plan.data) + len(plan.manifests)
    report.bytes_received = sum(plan.data.values()) + sum(len(m) for m in plan.manifests.values())
    if plan.skipped:
        add_promised(store, spec.name, sorted(plan.skipped))
        if not spec.promisor:
            set_promisor(store, spec.name)
        report.promised = len(plan.skipped)

    seen = tracking_refs(store, spec.name)
    tracked = {n: oid for n, oid in chosen.items() if seen.get(n) != oid}
    for name, oid in tracked.items():
        set_ref(store, f"{TRACKING}/{spec.name}/{name}", oid, log=False)
    for sid, oid in logs.items():
        set_ref(store, f"{LOG_TRACKING}/{spec.name}/{sid}", oid, log=False)
    if prune:
        for name in sorted(report.gone):
            if delete_ref(store, f"{TRACKING}/{spec.name}/{name}", log=False) is not None:
                report.pruned.append(name)
    if tracked or logs or report.pruned:
        append_event(store, "fetched", remote=spec.name, refs=tracked, logs=logs, **_pruned(report.pruned))
    report.refs, report.logs = chosen, logs
    report.steps_indexed = len(index_step_records(store, list(chosen.values()), f"remote {spec.name}"))
    return report


def _matches(names: dict[str, str], wanted: str) -> bool:
    w = wanted.rstrip("/")
    return any(n == w or n.startswith(w + "/") for n in names)


def _pruned(names: list[str]) -> dict:
    return {"pruned": names} if names else {}


def pull(
    store: Store,
    remote: str,
    refs: list[str] | None = None,
    only: set[str] | None = None,
    force: bool = False,
    jobs: int | None = None,
    meter: Meter | None = None,
    prune: bool = False,
) -> FetchReport:
    spec = get_remote(store, remote)
    before = merge_bases(store, spec.name)
    report = fetch(store, spec.name, refs, only, jobs, meter, prune=prune)
    for name, oid in report.refs.items():
        mine, last = read_ref(store, name), before.get(name)
        if mine == oid:
            report.up_to_date.append(name)
        elif mine is None and last == oid and not force:  # deleted here since the two agreed: stays deleted
            report.deleted_here.append(name)
        elif mine is None or mine == last:  # only the remote moved: fast-forward
            set_ref(store, name, oid)
            report.moved[name] = [mine, oid]
        elif oid == last:  # only this store moved: nothing to take
            report.ahead.append(name)
        elif force:  # both moved: take the remote's, keep this store's under displaced/
            keep = displaced_ref(name, mine)
            set_ref(store, keep, mine)
            set_ref(store, name, oid)
            report.moved[name] = [mine, oid]
            report.displaced[name] = keep
        else:
            report.conflicts.append(both_moved(name, spec.name, mine, oid, last))
    record_bases(store, spec.name, {n: report.refs[n] for n in report.up_to_date + list(report.moved)})
    if prune:
        _pass_deletions_on(store, spec.name, report, before)
    return report


def _pass_deletions_on(store: Store, remote: str, report: FetchReport, before: dict[str, str]) -> None:
    """pull --prune: a ref the remote deleted goes here too if it is still at the id the two sides
    last agreed on (deleted only if still there: compare-and-delete); one moved here since stays,
    as a conflict naming the ways on."""
    for name, last in sorted(report.gone.items()):
        agreed = before.get(name, last)
        mine = read_ref(store, name)
        if mine is not None and mine == agreed:
            mine = delete_ref(store, name, expect=agreed)  # None if it went meanwhile; another id if it moved
            if mine == agreed:
                report.deleted[name] = agreed
                mine = None
        if mine is not None:
            report.conflicts.append(
                f"ref {name}: deleted on remote {remote} since {agreed[:12]}, moved here to {mine[:12]}; "
                f"`accrue push --force {remote} {name}` puts this store's back there, "
                f"`accrue refs delete {name}` drops it here"
            )
            continue
        forget_bases(store, remote, [name])
