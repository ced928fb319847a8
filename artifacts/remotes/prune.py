"""remote prune: delete what nothing on a remote reaches — objects left by `push --force`, deleted
refs and killed pushes — and uploads a killed push left unfinished. A dry run unless told.

Safe beside a concurrent push (git's and restic's rules): an object younger than the grace period
is kept, because a push uploads objects before it moves the refs that reach them; nothing is
deleted while a push holds a live lease (artifacts/remotes/lease.py: leases of pushes that are gone
are taken over), because a push may have found an old unreachable object present and be about to
point a ref at it; and the refs are read again just before deleting, so one that moved meanwhile
stops the prune. A prune that deletes objects leaves a marker that makes every store's next push
list the remote in full (artifacts/remotes/present.py)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from artifacts.errors import StoreError
from artifacts.remotes.backends import OBJECTS, object_key
from artifacts.remotes.check import verify_remote
from artifacts.remotes.config import get_remote
from artifacts.remotes.connect import open_backend
from artifacts.remotes.lease import read_leases, take_over
from artifacts.remotes.pointers import read_pointers
from artifacts.remotes.present import mark_pruned
from artifacts.remotes.transfer import default_jobs, parallel
from artifacts.store import Store


@dataclass
class PruneReport:
    remote: str
    dry_run: bool
    reachable: int = 0
    removed: list[str] = field(default_factory=list)  # object ids (would be) deleted
    bytes: int = 0
    young: int = 0  # unreachable, but younger than the grace period: kept
    uploads: list[str] = field(default_factory=list)  # unfinished uploads (would be) dropped
    leases_taken_over: list[str] = field(default_factory=list)  # of pushes that are gone

    def as_dict(self) -> dict:
        return dict(self.__dict__)


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
    leases = read_leases(backend)
    busy = [lease for lease in leases if lease.state == "live"]
    if busy:
        raise StoreError(
            f"remote {spec.name}: a push is running ({busy[0].describe()}); nothing was deleted — prune again "
            f"when it is done, or `accrue remote unlock {spec.name} --all` if no push is running there"
        )
    report.leases_taken_over = [lease.describe() for lease in take_over(backend, leases)]
    again = {f"ref {n}": v[0] for n, v in read_pointers(store, spec, backend, "refs").items()}
    again |= {f"log of store {s[:12]}": v[0] for s, v in read_pointers(store, spec, backend, "logs").items()}
    if again != walk.pointers:
        raise StoreError(f"remote {spec.name}: its refs moved while prune looked; nothing was deleted — run it again")
    if doomed:
        mark_pruned(backend, f"prune by store {store.read_config().get('store_id', '?')}")
    parallel(lambda oid: backend.remove(object_key(oid)), sorted(doomed), jobs)
    for _what, handle in uploads:
        backend.drop_upload(handle)
    return report
