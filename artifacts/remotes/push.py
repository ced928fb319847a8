"""push: upload what the chosen refs reach and the remote lacks (data first, then manifests bottom
up, then the audit-log segment), then move each remote ref by compare-and-swap — only where the
remote has not moved it since the two sides last agreed on it (pointers.merge_bases)."""

from __future__ import annotations

import os
from dataclasses import dataclass, field

from artifacts.auditlog import append_event
from artifacts.errors import StoreError
from artifacts.links import children
from artifacts.refs import set_ref
from artifacts.remotes import TRACKING
from artifacts.remotes.backends import RefMoved
from artifacts.remotes.closure import bottom_up
from artifacts.remotes.config import check_not_copied, get_remote, store_id
from artifacts.remotes.connect import open_backend
from artifacts.remotes.lease import held_lease
from artifacts.remotes.logsegment import next_segment
from artifacts.remotes.pointers import (
    both_moved,
    check_remote_config,
    displaced_ref,
    load_json,
    local_refs,
    merge_bases,
    read_pointers,
    record_bases,
    remember_version,
    save_json,
    select_refs,
    state_dir,
    tracking_refs,
    used_before,
)
from artifacts.remotes.present import Presence
from artifacts.remotes.transfer import Meter, default_jobs, parallel
from artifacts.store import Store

BOOKKEEPING = {"pushed", "fetched", "step-records-indexed"}  # events a push or pull logs about itself


@dataclass
class PushReport:
    remote: str
    moved: dict[str, list] = field(default_factory=dict)  # ref -> [old remote id, new id]
    up_to_date: list[str] = field(default_factory=list)
    behind: list[str] = field(default_factory=list)  # remote moved on; this store did not
    gone_there: list[str] = field(default_factory=list)  # deleted on the remote since last seen: not re-made
    conflicts: list[str] = field(default_factory=list)
    displaced: dict[str, str] = field(default_factory=dict)  # --force: remote ref keeping what it replaced
    objects_sent: int = 0
    bytes_sent: int = 0
    objects_checked: int = 0  # every object the refs it names reach, checked to be on the remote
    healed: list[str] = field(default_factory=list)  # of those sent: missing or damaged there although reached
    objects_rehashed: int = 0  # --verify: downloaded and hashed
    leases_taken_over: list[str] = field(default_factory=list)  # of pushes whose holder is gone
    uploads_resumed: list[str] = field(default_factory=list)  # a killed push's multipart uploads, finished
    log_segment: str | None = None

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class _Plan:
    data: dict[str, int] = field(default_factory=dict)  # id -> size
    manifests: dict[str, list[str]] = field(default_factory=dict)  # id -> ids it names
    absent: set[str] = field(default_factory=set)  # reached, not in this store


def _local_closure(store: Store, roots: list[str], stop: set[str]) -> _Plan:
    plan = _Plan()
    stack: list[tuple[str, int | None]] = [(r, None) for r in roots]
    seen: set[str] = set()
    while stack:
        oid, size = stack.pop()
        if oid in seen or oid in stop:
            continue
        seen.add(oid)
        if not store.has_object(oid):
            plan.absent.add(oid)  # a partial clone's: the remote must have it already
            if size is not None:
                plan.data[oid] = size
            continue
        if size is not None:
            plan.data[oid] = size
            continue
        kids = children(oid, store.read_json(oid))
        plan.manifests[oid] = [k for k, _ in kids]
        stack += kids
    return plan


def _same_id(remote: str, sid: str) -> str:
    return (
        f"remote {remote}: another store pushed an audit log with this store's id {sid[:12]} (a copied "
        "store?); no ref was moved; run `accrue remote rekey` in the copy, then push again"
    )


def push(
    store: Store,
    remote: str,
    refs: list[str] | None = None,
    force: bool = False,
    jobs: int | None = None,
    meter: Meter | None = None,
    verify: bool = False,
) -> PushReport:
    """With verify, every object the refs reach that the remote holds is downloaded and re-hashed,
    and a corrupt one is sent again over it (before any ref moves)."""
    spec = get_remote(store, remote)
    check_not_copied(store)  # a copied store is refused before anything is sent
    backend = open_backend(spec)
    local = select_refs(local_refs(store), refs or [], "in this store")
    check_remote_config(backend, create=True, known=used_before(store, spec.name))
    sid = store_id(store)
    running = state_dir(store, spec.name) / "push-running"  # there after a push of this store was killed
    killed = running.is_file()
    with held_lease(backend, sid) as held:
        # uploads a killed push left unfinished are taken up where they stopped: looked for only after a
        # push was killed (this store's, or one whose lease this push took over), only those begun before
        # this push's lease was written, and only when no other push was running then (none is its)
        if (killed or held.taken) and not held.others_live:
            backend.resume_before = held.written_at()
        running.parent.mkdir(parents=True, exist_ok=True)
        running.touch()
        try:
            report = _push(store, spec, backend, sid, local, force, jobs or default_jobs(), meter or Meter(), verify)
        finally:
            running.unlink(missing_ok=True)
    report.leases_taken_over = [lease.describe() for lease in held.taken]
    report.uploads_resumed = list(backend.resumed)
    return report


def _decide(report: PushReport, spec, local: dict, current: dict, base: dict, force: bool):
    """Per ref: which to move (and, with force, whose remote id to keep as displaced/)."""
    to_move: dict[str, str] = {}
    displace: dict[str, str] = {}  # push --force over a remote that moved: its id, kept there
    for name, oid in local.items():
        cur, last = current.get(name, (None, ""))[0], base.get(name)
        if cur == oid:
            report.up_to_date.append(name)
        elif cur is None and last is not None and not force:  # deleted there since the two agreed
            if oid == last:
                report.gone_there.append(name)  # never made again by a plain push
            else:
                report.conflicts.append(both_moved(name, spec.name, oid, None, last))
        elif cur == last or cur is None:  # only this store moved (or the ref is new there)
            to_move[name] = oid
        elif force:
            to_move[name] = oid
            displace[name] = cur
        elif oid == last:  # only the remote moved: nothing to send
            report.behind.append(name)
        else:
            report.conflicts.append(both_moved(name, spec.name, oid, cur, last))
    return to_move, displace


def _only_bookkeeping(segment) -> bool:
    import json

    try:
        return all(json.loads(line).get("event") in BOOKKEEPING for line in segment.data.splitlines())
    except ValueError:
        return False


def _push(
    store: Store, spec, backend, sid: str, local: dict, force: bool, jobs: int, meter: Meter, verify: bool
) -> PushReport:
    report = PushReport(remote=spec.name)
    current = read_pointers(store, spec, backend, "refs")
    seen = tracking_refs(store, spec.name)
    base = merge_bases(store, spec.name)
    to_move, displace = _decide(report, spec, local, current, base, force)

    # the audit-log segment written since the last push to this remote (a push that moves no ref
    # sends none when those lines are only the last push's and pull's own: they go with the next)
    log_state_path = state_dir(store, spec.name) / "log.json"
    log_state = load_json(log_state_path)
    remote_log = read_pointers(store, spec, backend, "logs").get(sid)
    remote_log_id = remote_log[0] if remote_log else None
    if remote_log_id and log_state.get("manifest") not in (None, remote_log_id):
        raise StoreError(_same_id(spec.name, sid))  # another store pushed a log under this store's id
    chained = log_state.get("manifest") == remote_log_id and remote_log_id is not None
    segment = next_segment(store, sid, remote_log_id if chained else None, log_state.get("end", 0) if chained else 0)
    if segment and not to_move and _only_bookkeeping(segment):
        segment = None

    # every object the refs the remote will hold reach: on the remote, at the right size (--verify:
    # the right bytes), else sent, before any ref moves
    named = [local[n] for n in list(to_move) + report.up_to_date]
    plan = _local_closure(store, named, set())
    candidates = sorted(set(plan.data) | set(plan.manifests) | plan.absent)
    seg_ids = [segment.data_id, segment.manifest_id] if segment else []
    presence = Presence(store, spec.name)
    there = presence.check(backend, candidates + seg_ids, jobs, fresh=not current)
    report.objects_checked = len(candidates) + len(seg_ids)
    damaged = sorted(
        o for o in candidates if there.get(o) is not None and _expected_size(store, plan, o) not in (None, there[o])
    )
    if verify:
        damaged += _rehash(backend, [o for o in candidates if o in there and o not in damaged], jobs, meter, report)
    lacking = [o for o in candidates if o not in there] + damaged
    for oid in lacking:
        if oid in plan.absent:
            raise StoreError(
                f"object {oid[:12]} is not in this store (a partial clone) and remote {spec.name} "
                f"{'holds it damaged' if oid in damaged else 'lacks it too'}; pull it from the remote that has it first"
            )
    presence.forget(damaged)
    # reached by a ref the remote holds already (or through objects it holds): it should have been there
    if lacking:
        report.healed = sorted(set(damaged) | (set(lacking) & _reached_from_held(store, local_refs(store), current)))

    replace = set(damaged)
    data = [o for o in lacking if o in plan.data]
    groups = [[o for o in g if o in lacking] for g in bottom_up(plan.manifests)]
    sizes = {o: store.object_size(o) or 0 for o in lacking}
    meter.start(f"push → {spec.name}", len(lacking), sum(sizes.values()))

    def send(oid: str) -> None:
        if oid in replace:  # a damaged copy is there under this name
            backend.upload_object(oid, store.object_path(oid), sizes[oid], replace=True)
        else:
            backend.upload_object(oid, store.object_path(oid), sizes[oid])
        meter.advance(sizes[oid])

    try:
        parallel(send, data, jobs)
        for group in groups:
            parallel(send, group, jobs)
    finally:
        meter.stop()
    presence.confirm(lacking)
    report.objects_sent, report.bytes_sent = len(lacking), sum(sizes.values())

    if segment:
        from artifacts.remotes.backends import object_key

        for oid, raw in ((segment.data_id, segment.data), (segment.manifest_id, segment.manifest)):
            if oid not in there:
                backend.put_bytes(object_key(oid), raw)
                report.objects_sent += 1
                report.bytes_sent += len(raw)
        try:
            version = backend.swap(
                f"logs/{sid}", (segment.manifest_id + "\n").encode(), remote_log[1] if remote_log else None
            )
        except RefMoved:
            raise StoreError(_same_id(spec.name, sid)) from None
        remember_version(store, spec.name, "logs", sid, segment.manifest_id, version)
        state_dir(store, spec.name).mkdir(parents=True, exist_ok=True)
        save_json(log_state_path, {"manifest": segment.manifest_id, "end": segment.end})
        report.log_segment = segment.manifest_id

    for name, theirs in displace.items():  # before the ref moves, so the remote's work stays reachable
        backend.put_bytes(f"refs/{displaced_ref(name, theirs)}", (theirs + "\n").encode())
    for name, oid in to_move.items():
        old, version = current.get(name, (None, None))
        try:
            version = backend.swap(f"refs/{name}", (oid + "\n").encode(), version or None)
        except RefMoved:
            now = read_pointers(store, spec, backend, "refs").get(name, (None,))[0]
            report.conflicts.append(both_moved(name, spec.name, oid, now, base.get(name)))
            continue
        remember_version(store, spec.name, "refs", name, oid, version)
        report.moved[name] = [old, oid]
        if name in displace:
            report.displaced[name] = displaced_ref(name, displace[name])
    record_bases(store, spec.name, {n: local[n] for n in report.up_to_date + list(report.moved)})
    tracked = {n: local[n] for n in report.up_to_date + list(report.moved) if seen.get(n) != local[n]}
    for name, oid in tracked.items():
        set_ref(store, f"{TRACKING}/{spec.name}/{name}", oid, log=False)
    if tracked:  # one event for what was shared (the next push carries it; a no-op push logs nothing)
        append_event(store, "pushed", remote=spec.name, refs=tracked)
    return report


def _expected_size(store: Store, plan: _Plan, oid: str) -> int | None:
    if oid in plan.data:
        return plan.data[oid]
    return store.object_size(oid) if oid in plan.manifests else None


def _reached_from_held(store: Store, local: dict, current: dict) -> set[str]:
    """What the refs the remote holds at this store's ids reach (all of it should be there already)."""
    held = [oid for name, oid in local.items() if current.get(name, (None,))[0] == oid]
    plan = _local_closure(store, held, set())
    return set(plan.data) | set(plan.manifests) | plan.absent


def _rehash(backend, oids: list[str], jobs: int, meter: Meter, report: PushReport) -> list[str]:
    """push --verify: download and hash each; the ids whose remote bytes are not theirs."""
    from artifacts.remotes.backends import MissingOnRemote, object_key

    meter.start(f"re-hashing {backend.spec.name}", len(oids), 0)

    def check(oid: str) -> bool:
        with open(os.devnull, "wb") as sink:
            try:
                got, _n = backend.download_to(object_key(oid), sink.fileno())
            except MissingOnRemote:
                return True  # gone since it was listed: sent again like a corrupt one
        meter.advance(0)
        return got != oid

    try:
        bad = parallel(check, oids, jobs)
    finally:
        meter.stop()
    report.objects_rehashed = len(oids)
    return [o for o, b in zip(oids, bad) if b]
