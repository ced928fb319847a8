"""verify: quick (every reachable object exists with its recorded size) or full (re-hash every
object, quarantine the corrupt ones, then the quick check sees them as missing); both check the
audit log's chain against its head and the anchors in attempt records. On a store it cannot
write, verify reports and quarantines nothing. `repair` seals the log's damage (auditlog.py)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

from artifacts.auditlog import append_event, check_log, repair_log
from artifacts.errors import StoreError, os_error_text
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
    repaired: dict | None = None  # the log-repaired event, when --repair sealed something

    @property
    def ok(self) -> bool:
        return not self.problems

    def as_dict(self) -> dict:
        return {
            "ok": self.ok,
            "full": self.full,
            "objects_checked": self.objects_checked,
            "bytes_hashed": self.bytes_hashed,
            "reachable": self.reachable,
            "log_events": self.log_events,
            "quarantined": self.quarantined,
            "problems": self.problems,
            "notes": self.notes,
            "repaired": self.repaired,
        }


def verify_store(
    store: Store, full: bool = False, progress: Callable[[int], None] | None = None, repair: bool = False
) -> VerifyReport:
    report = VerifyReport(full=full)
    if full:
        _rehash(store, report, progress)
    reach = walk(store)
    report.reachable = len(reach.sizes)
    if not full:
        report.objects_checked = len(reach.sizes)
    report.problems += reach.problems
    attempts = list_attempts(store, problems=[])
    anchors = [
        (f"attempt {a['cache_key'][:12]}/{a['attempt']:04d} ({a.get('step')})", a["log_anchor"])
        for a in attempts
        if isinstance(a.get("log_anchor"), dict)
    ]
    has_history = bool(attempts) or (store.refs_dir.is_dir() and any(p.is_file() for p in store.refs_dir.rglob("*")))
    log = check_log(store, anchors, has_history=has_history)
    if repair and log.problems:
        report.repaired = repair_log(store, log)
        report.notes.append(
            f"repaired the audit log: sealed {len(log.problems)} problem(s) with a "
            f"log-repaired event (seq {report.repaired['seq']})"
        )
        log = check_log(store, anchors, has_history=has_history)
    report.log_events = log.events
    report.problems += [p.text for p in log.problems]
    report.notes += log.sealed
    for a in attempts:
        if a["state"] == "running":
            report.notes.append(
                f"attempt {a['cache_key'][:12]}/{a['attempt']:04d} ({a['step']}) "
                f"is marked running by pid {a.get('pid')}"
            )
    return report


def _rehash(store: Store, report: VerifyReport, progress: Callable[[int], None] | None) -> None:
    """Re-hash every object; move the corrupt ones aside unless the store cannot be written."""
    writable = True
    for oid in list(store.iter_object_ids()):
        try:
            actual, size = hash_file(store.object_path(oid))
        except FileNotFoundError:
            continue  # removed since it was listed (a gc beside this verify): nothing left to check
        except OSError as exc:
            report.problems.append(f"object {oid[:12]} cannot be read: {os_error_text(exc)}")
            continue
        report.objects_checked += 1
        report.bytes_hashed += size
        if progress:
            progress(size)
        if actual == oid:
            continue
        if writable:
            try:
                dest = store.quarantine(oid)
            except FileNotFoundError:
                continue  # removed meanwhile: no corrupt copy is left to move aside or report
            except OSError as exc:
                writable = False
                report.notes.append(
                    f"the store cannot be written ({os_error_text(exc)}): corrupt objects are reported, not quarantined"
                )
            else:
                report.quarantined.append(oid)
                report.problems.append(f"object {oid[:12]} is corrupt: moved to {dest.relative_to(store.root)}")
                try:
                    append_event(store, "quarantined", object=oid, reason="hash mismatch")
                except StoreError as exc:
                    report.notes.append(f"quarantine of {oid[:12]} not logged: {exc}")
                continue
        report.problems.append(f"object {oid[:12]} is corrupt (its bytes no longer match its id)")
