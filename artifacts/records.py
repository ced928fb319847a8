"""Attempt records: one small JSON file per attempt of a step, records/<cache key>/NNNN.json.

state: running -> committed | failed | abandoned. The file is replaced atomically at each change;
a committed attempt names its immutable step-record object (record_id), which is what refs and
caches point at. Checkpoints saved during the attempt are listed in order (oldest first).

Each write also records `log_anchor`, the audit log's head (seq and hash of its last line) at
that moment: an anchor the log does not control, so verify sees a log cut or rewritten behind it.
"""

from __future__ import annotations

import json
from pathlib import Path

from artifacts import writers
from artifacts.atomic import write_replace
from artifacts.errors import StoreError, store_os_error
from artifacts.hashing import canonical_json, is_full_id
from artifacts.store import Store

STATES = ("running", "committed", "failed", "abandoned")


def attempt_path(store: Store, key: str, number: int) -> Path:
    return store.records_dir / key / f"{number:04d}.json"


def write_attempt(store: Store, attempt: dict) -> None:
    if attempt["state"] not in STATES:
        raise ValueError(f"bad attempt state {attempt['state']}")
    from artifacts.auditlog import current_anchor

    writers.hold(store)  # the attempt names inputs and checkpoints: gc must not sweep them meanwhile
    path = attempt_path(store, attempt["cache_key"], attempt["attempt"])
    anchored = {**attempt, "log_anchor": current_anchor(store)}
    try:
        write_replace(path, canonical_json(anchored) + b"\n")
    except OSError as exc:
        raise store_os_error(exc, f"cannot write attempt record {path}") from None


def read_attempt(path: Path) -> dict:
    try:
        return json.loads(path.read_bytes())
    except (OSError, ValueError) as exc:
        raise StoreError(f"{path}: damaged attempt record ({exc.__class__.__name__})") from None


def list_attempts(store: Store, key: str | None = None, problems: list[str] | None = None) -> list[dict]:
    """Attempts of one cache key (or of all keys), oldest first within a key. A damaged file
    raises StoreError, or is reported into `problems` and skipped when a list is given."""
    keys = (
        [key]
        if key
        else sorted(p.name for p in store.records_dir.iterdir() if p.is_dir() and is_full_id(p.name))
        if store.records_dir.is_dir()
        else []
    )
    out = []
    for k in keys:
        d = store.records_dir / k
        if d.is_dir():
            for p in sorted(d.glob("[0-9][0-9][0-9][0-9].json")):
                try:
                    out.append(read_attempt(p))
                except StoreError as exc:
                    if problems is None:
                        raise
                    problems.append(str(exc))
    return out


def next_attempt_number(store: Store, key: str) -> int:
    """Call only while holding the step's lock, so two attempts never get the same number."""
    d = store.records_dir / key
    numbers = [int(p.stem) for p in d.glob("[0-9][0-9][0-9][0-9].json")] if d.is_dir() else []
    return max(numbers, default=0) + 1
