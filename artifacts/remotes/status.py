"""status: per ref, which side moved since this store and a remote last agreed (refs carry no
history, so "ahead" and "behind" name which side moved, not how many steps)."""

from __future__ import annotations

from dataclasses import dataclass

from artifacts.remotes.config import get_remote
from artifacts.remotes.connect import open_backend
from artifacts.remotes.pointers import check_remote_config, local_refs, merge_bases, read_pointers, tracking_refs
from artifacts.store import Store

STATES = {
    "up-to-date": "same id on both sides",
    "ahead": "only this store moved it: `accrue push` shares it",
    "behind": "only the remote moved it: `accrue pull` takes it",
    "diverged": "both moved: see `accrue pull` for the ways on",
    "local-only": "not on the remote: `accrue push` sends it",
    "remote-only": "not in this store: `accrue pull` brings it",
    "gone-there": "deleted on the remote since this store last saw it: `accrue pull --prune` deletes it here",
    "deleted-here": "deleted in this store since it last agreed with the remote: `accrue push --delete` passes it on",
}


@dataclass(frozen=True)
class RefStatus:
    ref: str
    local: str | None
    remote: str | None
    state: str


def ref_status(store: Store, remote: str, offline: bool = False) -> list[RefStatus]:
    """Against the remote's refs now (one listing), or with offline against what the last fetch
    or pull saw there (its remote-tracking refs)."""
    spec = get_remote(store, remote)
    if offline:
        there = tracking_refs(store, spec.name)
    else:
        backend = open_backend(spec)
        check_remote_config(backend, create=False)
        there = {n: v[0] for n, v in read_pointers(store, spec, backend, "refs").items()}
    here, base = local_refs(store), merge_bases(store, spec.name)
    rows = []
    for name in sorted(set(here) | set(there)):
        mine, theirs, last = here.get(name), there.get(name), base.get(name)
        if mine == theirs:
            state = "up-to-date"
        elif theirs is None:
            state = "gone-there" if last == mine else "local-only" if last is None else "diverged"
        elif mine is None:
            state = "deleted-here" if last == theirs else "remote-only" if last is None else "behind"
        elif theirs == last:
            state = "ahead"
        elif mine == last:
            state = "behind"
        else:
            state = "diverged"
        rows.append(RefStatus(name, mine, theirs, state))
    return rows
