"""gc: mark-and-sweep from refs and records, dry-run unless told, with a grace period for young
unreferenced objects (a concurrent writer may have published objects whose manifest or record is
not written yet), under an exclusive lock."""
from __future__ import annotations

import os
import re
import time
from dataclasses import dataclass, field

from artifacts.atomic import fsync_dir
from artifacts.auditlog import append_event
from artifacts.errors import StoreError
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

    @property
    def bytes(self) -> int:
        return sum(s for _, s in self.removed)

    def as_dict(self) -> dict:
        return {"dry_run": self.dry_run, "kept": self.kept, "young": self.young,
                "removed": [i for i, _ in self.removed], "bytes": self.bytes,
                "tmp_removed": self.tmp_removed}


def _age(st: os.stat_result, now: float) -> float:
    return now - max(st.st_mtime, st.st_ctime)


def _owner_alive(name: str) -> bool:
    """Temp names carry their writer's pid (…-<pid>-<hex>); a live writer's staging area — a
    step that has run for days, say — is never swept, whatever its age."""
    import psutil

    m = re.search(r"-(\d+)-[0-9a-f]+$", name)
    return bool(m) and psutil.pid_exists(int(m.group(1)))


def collect_garbage(store: Store, dry_run: bool = True, grace_s: float = DEFAULT_GRACE_S) -> GcReport:
    report = GcReport(dry_run=dry_run)
    lock = try_lock(store_lock(store.locks_dir, "gc"), "the store (gc)", timeout=0)
    try:
        reach = walk(store)
        if reach.problems and not dry_run:
            raise StoreError(f"gc refused: the store has problems ({reach.problems[0]}…); run `accrue verify`")
        now = time.time()
        for oid in list(store.iter_object_ids()):
            if oid in reach.sizes:
                report.kept += 1
                continue
            path = store.object_path(oid)
            st = path.stat()
            if _age(st, now) < grace_s:
                report.young += 1
                continue
            report.removed.append((oid, st.st_size))
            if not dry_run:
                path.unlink()
        for entry in sorted(store.tmp_dir.iterdir()) if store.tmp_dir.is_dir() else []:
            if _age(entry.lstat(), now) >= grace_s and not _owner_alive(entry.name):
                report.tmp_removed.append(entry.name)
                if not dry_run:
                    remove_tree(entry) if entry.is_dir() else entry.unlink(missing_ok=True)
        # temp files of atomic replaces (refs, attempt records) whose writer died before the rename
        for area in (store.refs_dir, store.records_dir):
            for entry in sorted(area.rglob(".tmp-*")) if area.is_dir() else []:
                if _age(entry.lstat(), now) >= grace_s and not _owner_alive(entry.name):
                    report.tmp_removed.append(str(entry.relative_to(store.root)))
                    if not dry_run:
                        entry.unlink(missing_ok=True)
        if not dry_run and (report.removed or report.tmp_removed):
            for fan in {store.object_path(o).parent for o, _ in report.removed}:
                if fan.exists():
                    fsync_dir(fan)
            append_event(store, "gc", removed=len(report.removed), bytes=report.bytes,
                         tmp_removed=len(report.tmp_removed))
    finally:
        lock.release()
    return report
