"""verify: quick (every reachable object exists with its recorded size) or full (re-hash every
object, quarantine the corrupt ones, then the quick check sees them as missing)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

from artifacts.auditlog import append_event, check_chain
from artifacts.hashing import hash_file
from artifacts.reachability import walk
from artifacts.records import list_attempts
from artifacts.store import Store


@dataclass
class VerifyReport:
    full: bool
    objects_checked: int = 0
    bytes_hashed: int = 0
    reachable: int = 0
    log_events: int = 0
    quarantined: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems

    def as_dict(self) -> dict:
        return {"ok": self.ok, "full": self.full, "objects_checked": self.objects_checked,
                "bytes_hashed": self.bytes_hashed, "reachable": self.reachable,
                "log_events": self.log_events, "quarantined": self.quarantined,
                "problems": self.problems, "notes": self.notes}


def verify_store(store: Store, full: bool = False,
                 progress: Callable[[int], None] | None = None) -> VerifyReport:
    report = VerifyReport(full=full)
    if full:
        for oid in list(store.iter_object_ids()):
            path = store.object_path(oid)
            actual, size = hash_file(path)
            report.objects_checked += 1
            report.bytes_hashed += size
            if progress:
                progress(size)
            if actual != oid:
                dest = store.quarantine(oid)
                report.quarantined.append(oid)
                report.problems.append(f"object {oid[:12]} is corrupt: moved to {dest.relative_to(store.root)}")
                append_event(store, "quarantined", object=oid, reason="hash mismatch")
    reach = walk(store)
    report.reachable = len(reach.sizes)
    if not full:
        report.objects_checked = len(reach.sizes)
    report.problems += reach.problems
    report.log_events, chain_problems = check_chain(store)
    report.problems += chain_problems
    for a in list_attempts(store, problems=[]):
        if a["state"] == "running":
            report.notes.append(f"attempt {a['cache_key'][:12]}/{a['attempt']:04d} ({a['step']}) "
                                f"is marked running by pid {a.get('pid')}")
    return report
