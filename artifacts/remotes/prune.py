"""remote prune: delete what nothing on a remote reaches — objects left by `push --force`, deleted
refs and killed pushes — and uploads a killed push left unfinished. A dry run unless told.

Safe beside a concurrent push (git's and restic's rules): an object younger than the grace period
is kept, because a push uploads objects before it moves the refs that reach them; nothing is
deleted while a push holds a lease (pushes/… on the remote, younger than LEASE_S), because a push
may have found an old unreachable object present and be about to point a ref at it; and the refs
are read again just before deleting, so one that moved meanwhile stops the prune."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from artifacts.errors import StoreError
from artifacts.remotes.backends import OBJECTS, object_key
from artifacts.remotes.check import verify_remote
from artifacts.remotes.config import get_remote
from artifacts.remotes.connect import open_backend
from artifacts.remotes.pointers import read_pointers
from artifacts.remotes.push import PUSH_LEASES
from artifacts.remotes.transfer import default_jobs, parallel
from artifacts.store import Store

LEASE_S = 3600.0  # a push lease older than this belongs to a push that died


@dataclass
class PruneReport:
    remote: str
    dry_run: bool
    reachable: int = 0
    removed: list[str] = field(default_factory=list)  # object ids (would be) deleted
    bytes: int = 0
    young: int = 0  # unreachable, but younger than the grace period: kept
    uploads: list[str] = field(default_factory=list)  # unfinished uploads (would be) dropped

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def _leases(backend) -> list[str]:
    now = time.time()
    return [k for k, (_s, mtime) in backend.list_aged(PUSH_LEASES).items() if now - mtime < LEASE_S]


def prune_remote(
    store: Store, remote: str, dry_run: bool = True, grace_s: float = 86400.0, jobs: int | None = None
) -> PruneReport:
    spec = get_remote(store, remote)
    backend = open_backend(spec)
    jobs = jobs or default_jobs()
    report = PruneReport(remote=spec.name, dry_run=dry_run)
    walk = verify_remote(store, spec.name)  # every id the remote's refs and log pointers reach
    unreadable = [p for p in walk.problems if "lacks object" not in p and "has size" not in p]
    if unreadable:  # what an unreadable manifest names is unknown: deleting could lose it
        raise StoreError(
            f"remote {spec.name}: cannot tell what is reachable ({unreadable[0]}); "
            f"run `accrue remote repair {spec.name}` first"
        )
    report.reachable = len(walk.reached)
    now = time.time()
    doomed: dict[str, int] = {}
    for key, (size, mtime) in backend.list_aged(OBJECTS).items():
        parts = key.split("/")
        oid = parts[-2] + parts[-1] if len(parts) >= 2 else ""
        if oid in walk.reached or object_key(oid) != key:
            continue  # reachable, or not an object's name at all (left alone)
        if now - mtime < grace_s:
            report.young += 1
        else:
            doomed[oid] = size
    uploads = [(what, handle) for what, started, handle in backend.unfinished_uploads() if now - started >= grace_s]
    report.removed, report.bytes = sorted(doomed), sum(doomed.values())
    report.uploads = sorted(what for what, _ in uploads)
    if dry_run or not (doomed or uploads):
        return report
    busy = _leases(backend)
    if busy:
        raise StoreError(
            f"remote {spec.name}: a push is running ({busy[0]}); nothing was deleted — prune again when it is done"
        )
    again = {f"ref {n}": v[0] for n, v in read_pointers(store, spec, backend, "refs").items()}
    again |= {f"log of store {s[:12]}": v[0] for s, v in read_pointers(store, spec, backend, "logs").items()}
    if again != walk.pointers:
        raise StoreError(f"remote {spec.name}: its refs moved while prune looked; nothing was deleted — run it again")
    parallel(lambda oid: backend.remove(object_key(oid)), sorted(doomed), jobs)
    for _what, handle in uploads:
        backend.drop_upload(handle)
    return report
