"""push --delete: remove refs from a remote. A ref goes only if it is still where this store last
saw it there (compare-and-delete), so a ref someone moved meanwhile is never lost by it. Objects
stay on the remote until `accrue remote prune` finds nothing reaches them."""

from __future__ import annotations

from dataclasses import dataclass, field

from artifacts.auditlog import append_event
from artifacts.errors import StoreError
from artifacts.refs import delete_ref
from artifacts.remotes import TRACKING
from artifacts.remotes.backends import RefMoved
from artifacts.remotes.config import get_remote
from artifacts.remotes.connect import open_backend
from artifacts.remotes.pointers import (
    check_remote_config,
    forget_bases,
    read_pointers,
    select_refs,
    short,
    tracking_refs,
)
from artifacts.store import Store


@dataclass
class DeleteReport:
    remote: str
    deleted: dict[str, str] = field(default_factory=dict)  # ref -> the id it named
    conflicts: list[str] = field(default_factory=list)

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def delete_remote_refs(store: Store, remote: str, names: list[str]) -> DeleteReport:
    if not names:
        raise StoreError("push --delete: name the ref(s) to remove from the remote")
    spec = get_remote(store, remote)
    backend = open_backend(spec)
    check_remote_config(backend, create=False)
    current = read_pointers(store, spec, backend, "refs")
    chosen = select_refs({n: v[0] for n, v in current.items()}, names, f"on remote {spec.name}")
    seen = tracking_refs(store, spec.name)
    report = DeleteReport(remote=spec.name)
    for name, oid in sorted(chosen.items()):
        if seen.get(name) != oid:
            report.conflicts.append(
                f"ref {name}: remote {spec.name} has {short(oid)}, this store last saw {short(seen.get(name))} "
                f"there; `accrue fetch {spec.name}` first, so nothing you have not seen is deleted"
            )
            continue
        try:
            backend.delete(f"refs/{name}", current[name][1])
        except RefMoved:
            report.conflicts.append(f"ref {name}: remote {spec.name} moved it meanwhile; fetch and try again")
            continue
        delete_ref(store, f"{TRACKING}/{spec.name}/{name}", log=False)
        report.deleted[name] = oid
    forget_bases(store, spec.name, list(report.deleted))
    if report.deleted:
        append_event(store, "remote-refs-deleted", remote=spec.name, refs=report.deleted)
    return report
