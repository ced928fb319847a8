"""verify --remote: does the remote hold every object its refs and log pointers reach?"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

from artifacts.errors import StoreError
from artifacts.links import children
from artifacts.remotes.config import get_remote
from artifacts.remotes.connect import open_backend
from artifacts.remotes.pointers import check_remote_config, read_pointers
from artifacts.remotes.present import Presence, prune_marker
from artifacts.remotes.transfer import Meter, default_jobs, download_manifest, parallel
from artifacts.store import Store


@dataclass
class RemoteVerifyReport:
    remote: str
    full: bool
    refs: int = 0
    reachable: int = 0
    bytes_hashed: int = 0
    problems: list[str] = field(default_factory=list)
    damaged: list[str] = field(default_factory=list)  # ids missing, short or corrupt there (repair re-sends them)
    reached: set[str] = field(default_factory=set, repr=False)  # every id the walk met (prune keeps them)
    manifests: set[str] = field(default_factory=set, repr=False)  # those of them that are manifests
    pointers: dict[str, str] = field(default_factory=dict, repr=False)  # "ref NAME" / "log SID" -> id

    lacking_here: list[str] = field(default_factory=list)  # of the damaged: not in this store either

    @property
    def ok(self) -> bool:
        return not self.problems

    @property
    def heal(self) -> str | None:
        """The command that heals what was found, run in a store that has the objects."""
        return None if self.ok else f"accrue remote repair {self.remote}{' --full' if self.full else ''}"

    def as_dict(self) -> dict:
        return {
            "ok": self.ok,
            "heal": self.heal,
            **{k: v for k, v in self.__dict__.items() if k not in ("reached", "manifests", "pointers")},
        }


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
    marker = prune_marker(backend)  # read before the listing (present.py)
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
            report.damaged.append(oid)
            if size is not None or not store.has_object(oid):
                continue  # a manifest this store has is still walked: what it names may be lost too
        elif size is not None:
            if held[oid] != size:
                report.problems.append(
                    f"remote object {oid[:12]} has size {held[oid]}, expected {size} (named by {where})"
                )
                report.damaged.append(oid)
            continue
        try:
            raw = store.read_bytes(oid, verify=True) if store.has_object(oid) else download_manifest(backend, oid)
            obj = json.loads(raw)
            kids = children(oid, obj)
        except (StoreError, ValueError) as exc:
            report.damaged.append(oid)
            report.problems.append(
                f"{exc} (named by {where})"
                if isinstance(exc, StoreError)
                else f"remote object {oid[:12]} is not a manifest (named by {where})"
            )
            continue
        here = f"{obj.get('type')} {oid[:12]}"
        stack += [(k, here, s) for k, s in kids]
    report.reachable, report.reached, report.pointers = len(sizes), set(sizes), {w: o for w, o in pointers}
    report.manifests = {o for o, size in sizes.items() if size is None}
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
        report.damaged += [o for o, p in zip(todo, found) if p and o not in report.damaged]
        report.bytes_hashed = sum(held[o] for o in todo)
    report.lacking_here = [o for o in report.damaged if not store.has_object(o)]
    bad = set(report.damaged)
    Presence(store, spec.name).listed({o: n for o, n in held.items() if o not in bad}, marker)
    return report
