"""gc: mark-and-sweep from refs and records, dry-run unless told.

Nothing an in-flight writer has named is swept: gc holds the store's writer lock exclusively for
its whole mark and sweep, so it runs only when no writer is alive (writers.py). The grace period
still keeps young unreferenced objects (a writer that died before rooting them, a store copied in
by hand). Before deleting anything gc logs a `gc-started` event, so a store whose log cannot take
the record of a deletion loses nothing."""

from __future__ import annotations

import os
import re
import time
from dataclasses import dataclass, field

from artifacts import writers
from artifacts.atomic import fsync_dir
from artifacts.auditlog import append_event
from artifacts.errors import StoreError, store_os_error
from artifacts.locks import store_lock, try_lock
from artifacts.reachability import walk
from artifacts.store import Store, remove_tree

DEFAULT_GRACE_S = 24 * 3600


@dataclass
class GcReport:
    dry_run: bool
    kept: int = 0
    young: int = 0
    removed: list[tuple[str, int]] = field(default_factory=list)  # (id, size) removed or to remove
    tmp_removed: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)  # what the mark found wrong (--yes then refuses)

    @property
    def bytes(self) -> int:
        return sum(s for _, s in self.removed)

    def as_dict(self) -> dict:
        return {
            "dry_run": self.dry_run,
            "kept": self.kept,
            "young": self.young,
            "removed": [i for i, _ in self.removed],
            "bytes": self.bytes,
            "tmp_removed": self.tmp_removed,
            "problems": self.problems,
        }


def _age(st: os.stat_result, now: float) -> float:
    return now - max(st.st_mtime, st.st_ctime)


def _owner_alive(name: str) -> bool:
    """Temp names carry their writer's pid (…-<pid>-<hex>); a live writer's staging area — a
    step that has run for days, say — is never swept, whatever its age."""
    import psutil

    m = re.search(r"-(\d+)-[0-9a-f]+$", name)
    return bool(m) and psutil.pid_exists(int(m.group(1)))


def collect_garbage(
    store: Store, dry_run: bool = True, grace_s: float = DEFAULT_GRACE_S, wait_s: float = 0.0
) -> GcReport:
    """wait_s: how long to wait for active writers before giving up (StoreError)."""
    if not os.access(store.objects_dir, os.W_OK):  # a read-only store: nothing can change it meanwhile
        if not dry_run:
            raise StoreError(f"the store at {store.root} cannot be written: gc can only report (drop --yes)")
        return _collect(store, True, grace_s)
    try:
        lock = try_lock(store_lock(store.locks_dir, "gc"), "the store (gc)", timeout=0)
    except OSError as exc:
        raise store_os_error(exc, "gc cannot lock the store") from None
    try:
        with writers.exclusive(store, wait_s=wait_s):
            return _collect(store, dry_run, grace_s)
    except OSError as exc:
        raise store_os_error(exc, "gc could not finish") from None
    finally:
        lock.release()


def _collect(store: Store, dry_run: bool, grace_s: float) -> GcReport:
    report = GcReport(dry_run=dry_run)
    reach = walk(store)
    report.problems = reach.problems
    if reach.problems and not dry_run:
        raise StoreError(f"gc refused: the store has problems ({reach.problems[0]}…); run `accrue verify`")
    now = time.time()
    for oid in list(store.iter_object_ids()):
        if oid in reach.sizes:
            report.kept += 1
            continue
        st = store.object_path(oid).stat()
        if _age(st, now) < grace_s:
            report.young += 1
            continue
        report.removed.append((oid, st.st_size))
    tmp_paths = []
    for entry in sorted(store.tmp_dir.iterdir()) if store.tmp_dir.is_dir() else []:
        if _age(entry.lstat(), now) >= grace_s and not _owner_alive(entry.name):
            report.tmp_removed.append(entry.name)
            tmp_paths.append(entry)
    # temp files of atomic replaces (refs, attempt records, the log head) whose writer died
    for area in (store.refs_dir, store.records_dir, store.log_path.parent):
        for entry in sorted(area.rglob(".tmp-*")) if area.is_dir() else []:
            if _age(entry.lstat(), now) >= grace_s and not _owner_alive(entry.name):
                report.tmp_removed.append(str(entry.relative_to(store.root)))
                tmp_paths.append(entry)
    if dry_run or not (report.removed or report.tmp_removed):
        return report
    # the log must be able to say what is about to go, or nothing goes
    append_event(
        store, "gc-started", removing=len(report.removed), bytes=report.bytes, tmp_removing=len(report.tmp_removed)
    )
    for oid, _ in report.removed:
        store.object_path(oid).unlink(missing_ok=True)
    for entry in tmp_paths:
        remove_tree(entry) if entry.is_dir() and not entry.is_symlink() else entry.unlink(missing_ok=True)
    for fan in {store.object_path(o).parent for o, _ in report.removed}:
        if fan.exists():
            fsync_dir(fan)
    append_event(store, "gc", removed=len(report.removed), bytes=report.bytes, tmp_removed=len(report.tmp_removed))
    return report
