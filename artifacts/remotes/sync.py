"""push, fetch, pull and verify against a remote.

push: upload what the chosen refs reach and the remote lacks (data first, then manifests bottom
up, then the audit-log segment), then move each remote ref by compare-and-swap from where this
store last saw it (its remote-tracking ref). fetch: the reverse, every object verified on arrival,
then the remote-tracking refs move. pull: fetch, then move local refs that have not changed
since this store last saw the remote (or that do not exist yet).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from artifacts.atomic import write_replace
from artifacts.auditlog import append_event
from artifacts.errors import StoreError
from artifacts.hashing import HASH_NAME, canonical_json, is_full_id
from artifacts.locks import store_lock
from artifacts.refs import check_ref_name, list_refs, read_ref, set_ref
from artifacts.remotes import LOG_TRACKING, RESERVED, TRACKING
from artifacts.remotes.backends import Backend, RefMoved, open_backend
from artifacts.remotes.closure import bottom_up, children
from artifacts.remotes.config import RemoteSpec, get_remote, set_promisor, store_id
from artifacts.remotes.lazy import add_promised
from artifacts.remotes.logsegment import KIND as LOG_KIND
from artifacts.remotes.logsegment import next_segment
from artifacts.remotes.transfer import (
    Meter,
    default_jobs,
    download_manifest,
    download_object,
    flush_dirs,
    parallel,
)
from artifacts.store import Store

REMOTE_CONFIG = {"format": 1, "hash": HASH_NAME, "type": "accrue-remote"}
HEAD_MAX = 256  # up to this many candidates are checked one HEAD each; more: one listing


# ============================================================================ small helpers
def _state_dir(store: Store, remote: str) -> Path:
    return store.root / "remotes" / remote


def _load_json(path: Path) -> dict:
    try:
        return json.loads(path.read_bytes())
    except (FileNotFoundError, ValueError):
        return {}


def _save_json(path: Path, value: dict) -> None:
    write_replace(path, canonical_json(value) + b"\n")


def _local_refs(store: Store) -> dict[str, str]:
    return {n: i for n, i in list_refs(store).items() if not n.startswith(RESERVED)}


def _tracking(store: Store, remote: str, space: str = TRACKING) -> dict[str, str]:
    prefix = f"{space}/{remote}/"
    return {n[len(prefix) :]: i for n, i in list_refs(store, prefix).items()}


def _select(names: dict[str, str], wanted: list[str], where: str) -> dict[str, str]:
    """Every ref when nothing is named; else each name picks that ref or the refs under it."""
    if not wanted:
        return dict(names)
    out: dict[str, str] = {}
    for w in wanted:
        w = w.rstrip("/")
        if w.startswith(RESERVED):
            raise StoreError(f"{w}: remote-tracking refs are never pushed or pulled")
        hit = {n: i for n, i in names.items() if n == w or n.startswith(w + "/")}
        if not hit:
            raise StoreError(f"no ref {w!r} {where}")
        out.update(hit)
    return out


def _short(oid: str | None) -> str:
    return oid[:12] if oid else "nothing"


def check_remote_config(backend: Backend, create: bool) -> None:
    raw = backend.get_bytes("config")
    if raw is None:
        backend.probe(create)  # e.g. an S3 listing tells a missing bucket from an empty prefix
        if not create:
            raise StoreError(f"{backend.describe()} holds no accrue store yet (push to it first)")
        try:
            backend.swap("config", canonical_json(REMOTE_CONFIG) + b"\n", None)
        except RefMoved:
            pass  # another store created it at the same moment
        return
    try:
        cfg = json.loads(raw)
    except ValueError:
        cfg = {}
    if not isinstance(cfg, dict) or cfg.get("type") != "accrue-remote":
        raise StoreError(f"{backend.describe()}: its config is not an accrue remote's")
    if cfg.get("format") != REMOTE_CONFIG["format"] or cfg.get("hash") != HASH_NAME:
        raise StoreError(
            f"{backend.describe()}: unsupported remote format {cfg.get('format')!r} / hash {cfg.get('hash')!r}"
        )


def read_pointers(store: Store, spec: RemoteSpec, backend: Backend, space: str) -> dict[str, tuple[str, str]]:
    """Remote refs (space "refs") or log pointers ("logs"): name -> (id, version). One listing;
    a value is fetched only when its version differs from the one cached in remotes/<name>/."""
    cache_path = _state_dir(store, spec.name) / f"{space}.json"
    cache = _load_json(cache_path)
    out: dict[str, tuple[str, str]] = {}
    for key, version in sorted(backend.list_versions(space).items()):
        name = key[len(space) + 1 :]
        try:
            check_ref_name(name)
        except StoreError:
            continue  # not a ref (e.g. an editor's backup file)
        if name.startswith(RESERVED):
            continue  # another store's tracking refs are its own business
        cached = cache.get(name)
        if cached and version and cached[0] == version:
            out[name] = (cached[1], version)
            continue
        got = backend.read_versioned(key)
        if got is None:
            continue  # removed meanwhile
        text = got[0].decode(errors="replace").strip()
        if not is_full_id(text):
            raise StoreError(f"{backend.describe()}: {key} is damaged (holds {text[:20]!r}, not an id)")
        out[name] = (text, got[1])
    fresh = {n: [v, i] for n, (i, v) in out.items()}
    if fresh != cache:
        _state_dir(store, spec.name).mkdir(parents=True, exist_ok=True)
        _save_json(cache_path, fresh)
    return out


def _remember_version(store: Store, remote: str, space: str, name: str, oid: str, version: str) -> None:
    path = _state_dir(store, remote) / f"{space}.json"
    with store_lock(store.locks_dir, f"remote-{remote}"):
        cache = _load_json(path)
        cache[name] = [version, oid]
        path.parent.mkdir(parents=True, exist_ok=True)
        _save_json(path, cache)


def _present_on_remote(backend: Backend, oids: list[str], jobs: int) -> set[str]:
    from artifacts.remotes.backends import object_key

    if len(oids) <= HEAD_MAX:
        sizes = parallel(lambda o: backend.head(object_key(o)), oids, jobs)
        return {o for o, s in zip(oids, sizes) if s is not None}
    return set(backend.remote_object_ids()) & set(oids)


# ============================================================================ push
@dataclass
class PushReport:
    remote: str
    moved: dict[str, list] = field(default_factory=dict)  # ref -> [old remote id, new id]
    up_to_date: list[str] = field(default_factory=list)
    behind: list[str] = field(default_factory=list)  # remote moved on; this store did not
    conflicts: list[str] = field(default_factory=list)
    objects_sent: int = 0
    bytes_sent: int = 0
    objects_checked: int = 0
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


def push(
    store: Store,
    remote: str,
    refs: list[str] | None = None,
    force: bool = False,
    jobs: int | None = None,
    meter: Meter | None = None,
) -> PushReport:
    spec = get_remote(store, remote)
    backend = open_backend(spec)
    jobs, meter = jobs or default_jobs(), meter or Meter()
    report = PushReport(remote=spec.name)
    check_remote_config(backend, create=True)
    local = _select(_local_refs(store), refs or [], "in this store")
    current = read_pointers(store, spec, backend, "refs")
    seen = _tracking(store, spec.name)

    to_move: dict[str, str] = {}
    for name, oid in local.items():
        cur = current.get(name, (None, ""))[0]
        if cur == oid:
            report.up_to_date.append(name)
        elif force or cur == seen.get(name) or cur is None:  # (a wiped remote gets it again)
            to_move[name] = oid
        elif oid == seen.get(name):
            report.behind.append(name)
        else:
            report.conflicts.append(
                f"ref {name}: remote {spec.name} has {_short(cur)}, but this store "
                f"last saw {_short(seen.get(name))} there; pull first, or push --force"
            )

    # the audit-log segment written since the last push to this remote
    sid = store_id(store)
    log_state_path = _state_dir(store, spec.name) / "log.json"
    log_state = _load_json(log_state_path)
    remote_log = read_pointers(store, spec, backend, "logs").get(sid)
    remote_log_id = remote_log[0] if remote_log else None
    chained = log_state.get("manifest") == remote_log_id and remote_log_id is not None
    segment = next_segment(store, sid, remote_log_id if chained else None, log_state.get("end", 0) if chained else 0)

    # what the refs to move reach, less what the remote provably has (its refs' closures)
    stop = {oid for name, oid in seen.items() if current.get(name, (None,))[0] == oid}
    plan = _local_closure(store, list(to_move.values()), stop)
    candidates = sorted(set(plan.data) | set(plan.manifests) | plan.absent)
    seg_ids = [segment.data_id, segment.manifest_id] if segment else []
    present = _present_on_remote(backend, candidates + seg_ids, jobs)
    report.objects_checked = len(candidates) + len(seg_ids)
    lacking = [o for o in candidates if o not in present]
    for oid in lacking:
        if oid in plan.absent:
            raise StoreError(
                f"object {oid[:12]} is not in this store (a partial clone) and remote "
                f"{spec.name} lacks it too; pull it from the remote that has it first"
            )

    data = [o for o in lacking if o in plan.data]
    groups = [[o for o in g if o not in present] for g in bottom_up(plan.manifests)]
    sizes = {o: store.object_size(o) or 0 for o in lacking}
    meter.start(f"push → {spec.name}", len(lacking), sum(sizes.values()))

    def send(oid: str) -> None:
        backend.upload_object(oid, store.object_path(oid), sizes[oid])
        meter.advance(sizes[oid])

    try:
        parallel(send, data, jobs)
        for group in groups:
            parallel(send, group, jobs)
    finally:
        meter.stop()
    report.objects_sent, report.bytes_sent = len(lacking), sum(sizes.values())

    if segment:
        from artifacts.remotes.backends import object_key

        for oid, raw in ((segment.data_id, segment.data), (segment.manifest_id, segment.manifest)):
            if oid not in present:
                backend.put_bytes(object_key(oid), raw)
                report.objects_sent += 1
                report.bytes_sent += len(raw)
        try:
            version = backend.swap(
                f"logs/{sid}", (segment.manifest_id + "\n").encode(), remote_log[1] if remote_log else None
            )
        except RefMoved:
            raise StoreError(
                f"remote {spec.name}: another store pushed with this store's id {sid[:12]} "
                "(a copied store?); its audit log was left as it is"
            ) from None
        _remember_version(store, spec.name, "logs", sid, segment.manifest_id, version)
        _state_dir(store, spec.name).mkdir(parents=True, exist_ok=True)
        _save_json(log_state_path, {"manifest": segment.manifest_id, "end": segment.end})
        report.log_segment = segment.manifest_id

    for name, oid in to_move.items():
        old, version = current.get(name, (None, None))
        try:
            version = backend.swap(f"refs/{name}", (oid + "\n").encode(), version or None)
        except RefMoved:
            now = read_pointers(store, spec, backend, "refs").get(name, (None,))[0]
            report.conflicts.append(
                f"ref {name}: remote {spec.name} has {_short(now)}, but this store "
                f"last saw {_short(seen.get(name))} there; pull first, or push --force"
            )
            continue
        _remember_version(store, spec.name, "refs", name, oid, version)
        report.moved[name] = [old, oid]
    tracked = {n: local[n] for n in report.up_to_date + list(report.moved) if seen.get(n) != local[n]}
    for name, oid in tracked.items():
        set_ref(store, f"{TRACKING}/{spec.name}/{name}", oid, log=False)
    if tracked:  # one event for what was shared (the next push carries it; a no-op push logs nothing)
        append_event(store, "pushed", remote=spec.name, refs=tracked)
    return report


# ============================================================================ fetch / pull
@dataclass
class FetchReport:
    remote: str
    refs: dict[str, str] = field(default_factory=dict)  # remote ref -> id fetched
    logs: dict[str, str] = field(default_factory=dict)  # other store's id -> log segment id
    objects_received: int = 0
    bytes_received: int = 0
    promised: int = 0
    moved: dict[str, list] = field(default_factory=dict)  # pull: local ref -> [old, new]
    up_to_date: list[str] = field(default_factory=list)
    conflicts: list[str] = field(default_factory=list)

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class _RemotePlan:
    manifests: dict[str, bytes] = field(default_factory=dict)  # downloaded, not yet stored
    named: dict[str, list[str]] = field(default_factory=dict)
    data: dict[str, int] = field(default_factory=dict)  # to download
    skipped: dict[str, int] = field(default_factory=dict)  # left on the remote (--only)


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
                leave = only is not None and obj.get("kind") not in only and obj.get("kind") != LOG_KIND
                following.append((kids[0][0], kids[0][1], leave))  # its content
                following += [(k, s, False) for k, s in kids[1:]]  # its inputs decide alone
            else:
                following += [(k, s, skip) for k, s in kids]  # tree entries inherit
        level = following
    return plan


def fetch(
    store: Store,
    remote: str,
    refs: list[str] | None = None,
    only: set[str] | None = None,
    jobs: int | None = None,
    meter: Meter | None = None,
) -> FetchReport:
    spec = get_remote(store, remote)
    backend = open_backend(spec)
    jobs, meter = jobs or default_jobs(), meter or Meter()
    report = FetchReport(remote=spec.name)
    check_remote_config(backend, create=False)
    current = {n: v[0] for n, v in read_pointers(store, spec, backend, "refs").items()}
    chosen = _select(current, refs or [], f"on remote {spec.name}")
    own = store.read_config().get("store_id")
    seen_logs = _tracking(store, spec.name, LOG_TRACKING)
    logs = {
        sid: v[0]
        for sid, v in read_pointers(store, spec, backend, "logs").items()
        if sid != own and seen_logs.get(sid) != v[0]
    }

    plan = _remote_closure(store, backend, list(chosen.values()) + list(logs.values()), only, jobs)
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

    seen = _tracking(store, spec.name)
    tracked = {n: oid for n, oid in chosen.items() if seen.get(n) != oid}
    for name, oid in tracked.items():
        set_ref(store, f"{TRACKING}/{spec.name}/{name}", oid, log=False)
    for sid, oid in logs.items():
        set_ref(store, f"{LOG_TRACKING}/{spec.name}/{sid}", oid, log=False)
    if tracked or logs:
        append_event(store, "fetched", remote=spec.name, refs=tracked, logs=logs)
    report.refs, report.logs = chosen, logs
    return report


def pull(
    store: Store,
    remote: str,
    refs: list[str] | None = None,
    only: set[str] | None = None,
    force: bool = False,
    jobs: int | None = None,
    meter: Meter | None = None,
) -> FetchReport:
    spec = get_remote(store, remote)
    before = _tracking(store, spec.name)
    report = fetch(store, spec.name, refs, only, jobs, meter)
    for name, oid in report.refs.items():
        mine = read_ref(store, name)
        if mine == oid:
            report.up_to_date.append(name)
        elif mine is None or mine == before.get(name) or force:
            set_ref(store, name, oid)
            report.moved[name] = [mine, oid]
        else:
            report.conflicts.append(
                f"ref {name}: this store has {_short(mine)}, remote {spec.name} has "
                f"{_short(oid)} (last seen there: {_short(before.get(name))}); "
                "pull --force to take the remote's"
            )
    return report


# ============================================================================ verify --remote
@dataclass
class RemoteVerifyReport:
    remote: str
    full: bool
    refs: int = 0
    reachable: int = 0
    bytes_hashed: int = 0
    problems: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems

    def as_dict(self) -> dict:
        return {"ok": self.ok, **self.__dict__}


def verify_remote(
    store: Store, remote: str, full: bool = False, jobs: int | None = None, meter: Meter | None = None
) -> RemoteVerifyReport:
    """Does the remote hold every object its refs and log pointers reach, with the right size?
    Manifests are read from this store when it has them, else from the remote (verified). With
    full, every reachable remote object is downloaded and re-hashed (nothing is stored)."""
    from artifacts.remotes.backends import MissingOnRemote

    spec = get_remote(store, remote)
    backend = open_backend(spec)
    jobs, meter = jobs or default_jobs(), meter or Meter()
    report = RemoteVerifyReport(remote=spec.name, full=full)
    check_remote_config(backend, create=False)
    held = backend.remote_object_ids()
    pointers = [(f"ref {n}", v[0]) for n, v in read_pointers(store, spec, backend, "refs").items()]
    pointers += [(f"log of store {s[:12]}", v[0]) for s, v in read_pointers(store, spec, backend, "logs").items()]
    report.refs = len(pointers)
    sizes: dict[str, int | None] = {}
    stack: list[tuple[str, str, int | None]] = [(oid, where, None) for where, oid in pointers]
    while stack:
        oid, where, size = stack.pop()
        if oid in sizes:
            continue
        sizes[oid] = size
        if oid not in held:
            report.problems.append(f"remote {spec.name} lacks object {oid[:12]} (named by {where})")
            continue
        if size is not None:
            if held[oid] != size:
                report.problems.append(
                    f"remote object {oid[:12]} has size {held[oid]}, expected {size} (named by {where})"
                )
            continue
        try:
            raw = store.read_bytes(oid, verify=True) if store.has_object(oid) else download_manifest(backend, oid)
            obj = json.loads(raw)
            kids = children(oid, obj)
        except (StoreError, ValueError) as exc:
            report.problems.append(
                f"{exc} (named by {where})"
                if isinstance(exc, StoreError)
                else f"remote object {oid[:12]} is not a manifest (named by {where})"
            )
            continue
        here = f"{obj.get('type')} {oid[:12]}"
        stack += [(k, here, s) for k, s in kids]
    report.reachable = len(sizes)
    if full:
        import os

        todo = sorted(o for o in sizes if o in held)
        meter.start(f"re-hashing {spec.name}", len(todo), sum(held[o] for o in todo))

        def check(oid: str) -> str | None:
            from artifacts.remotes.backends import object_key

            with open(os.devnull, "wb") as sink:
                try:
                    got, n = backend.download_to(object_key(oid), sink.fileno())
                except MissingOnRemote:
                    return f"remote {spec.name} lacks object {oid[:12]}"
            meter.advance(n)
            return None if got == oid else f"remote object {oid[:12]} is corrupt (its bytes do not hash to its id)"

        try:
            found = parallel(check, todo, jobs)
        finally:
            meter.stop()
        report.problems += [p for p in found if p]
        report.bytes_hashed = sum(held[o] for o in todo)
    return report


# ============================================================================ remote remove
def forget_remote(store: Store, remote: str, force: bool = False) -> int:
    """Drop a remote: its config entry, its remote-tracking refs and what this store cached about
    it. A partial clone still relying on it is refused unless forced. Returns refs dropped."""
    import shutil

    from artifacts.remotes.config import remove_remote_entry
    from artifacts.remotes.lazy import promised_path

    spec = get_remote(store, remote)
    promised = promised_path(store, spec.name)
    if promised.is_file() and not force:
        lacking = [o for o in promised.read_text().split() if not store.has_object(o)]
        if lacking:
            raise StoreError(
                f"remote {spec.name} still holds {len(lacking)} object(s) this partial clone "
                f"left there (e.g. {lacking[0][:12]}); pull them first, or remove --force"
            )
    dropped = 0
    with store_lock(store.locks_dir, "refs"):
        for space in (TRACKING, LOG_TRACKING):
            base = store.refs_dir / space / spec.name
            if base.is_dir():
                dropped += sum(1 for p in base.rglob("*") if p.is_file())
                shutil.rmtree(base)
    shutil.rmtree(_state_dir(store, spec.name), ignore_errors=True)
    remove_remote_entry(store, spec.name)
    store._promised = None
    return dropped
