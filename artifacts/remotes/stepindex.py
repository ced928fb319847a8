"""The step cache travels: a committed step record that arrives from a remote (refs name one per
workflow step) is entered in this store's attempt index, records/<cache key>/, as a committed
attempt. The runner's cache lookup reads only that index, so without this a pulled store would
run every step again although it holds their records and outputs."""

from __future__ import annotations

from artifacts.auditlog import append_event
from artifacts.errors import StoreError
from artifacts.hashing import is_full_id
from artifacts.locks import store_lock
from artifacts.records import list_attempts, next_attempt_number, write_attempt
from artifacts.store import Store

MANIFEST_MAX = 1 << 20  # a bigger object is data, never a step record: not read
LOCK_WAIT_S = 10.0  # a step of that key running here: its own commit will count, so skip after this

_COPIED = ("inputs", "config", "code_version", "outputs", "started", "finished", "host", "workflow", "stage")


def index_step_records(store: Store, oids: list[str], source: str) -> list[str]:
    """Enter every committed step record among oids (those this store holds) that its index
    lacks; returns their ids. Each under its key's step lock, as the runner numbers attempts."""
    from filelock import Timeout

    added: list[str] = []
    for oid in dict.fromkeys(oids):
        record = _step_record(store, oid)
        if record is None:
            continue
        key = record["cache_key"]
        lock = store_lock(store.locks_dir, f"step-{key}")
        try:
            lock.acquire(timeout=LOCK_WAIT_S)
        except Timeout:
            continue
        try:
            if any(a.get("record_id") == oid for a in list_attempts(store, key, problems=[])):
                continue
            attempt = {f: record.get(f) for f in _COPIED}
            attempt.update(
                cache_key=key,
                attempt=next_attempt_number(store, key),
                step=record["step"],
                state="committed",
                mode="normal",
                pid=None,
                checkpoints=[],
                resumed_from=None,
                record_id=oid,
                imported_from=source,
            )
            write_attempt(store, attempt)
            added.append(oid)
        finally:
            lock.release()
    if added:
        append_event(store, "step-records-indexed", source=source, records=added)
    return added


def _step_record(store: Store, oid: str) -> dict | None:
    if not store.has_object(oid) or (store.object_size(oid) or 0) > MANIFEST_MAX:
        return None
    try:
        obj = store.read_json(oid)
    except (StoreError, ValueError):
        return None  # data, not a manifest
    if not isinstance(obj, dict) or obj.get("type") != "step-record" or obj.get("state") != "committed":
        return None
    if not is_full_id(str(obj.get("cache_key", ""))) or not isinstance(obj.get("outputs"), dict):
        return None
    return obj
