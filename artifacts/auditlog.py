"""The append-only audit log: one JSON line per event, each carrying the hash of the line before.

Events: step-started, step-committed, step-failed, step-abandoned, checkpoint-saved,
artifact-written, ref-moved, gc, quarantined. Appends happen under a kernel lock with O_APPEND
and an fsync; nothing ever rewrites the file, so editing or dropping a line breaks the chain.
"""
from __future__ import annotations

import json
import os
import socket
from typing import Any, Iterator

from artifacts.errors import StoreError
from artifacts.hashing import canonical_json, hash_bytes
from artifacts.locks import store_lock
from artifacts.manifests import now_iso
from artifacts.store import Store

GENESIS = "0" * 64
_TAIL_BYTES = 64 * 1024


def _last_line(store: Store) -> bytes | None:
    try:
        with open(store.log_path, "rb") as f:
            end = f.seek(0, os.SEEK_END)
            step = _TAIL_BYTES
            while True:
                start = max(0, end - step)
                f.seek(start)
                data = f.read(end - start)
                lines = data.rstrip(b"\n").split(b"\n")
                if len(lines) > 1 or start == 0:
                    return lines[-1] if lines[-1] else None
                step *= 2
    except FileNotFoundError:
        return None


def append_event(store: Store, event: str, **fields: Any) -> dict:
    """Append one event and return it (with its seq and prev hash)."""
    store.log_path.parent.mkdir(exist_ok=True)
    with store_lock(store.locks_dir, "log"):
        last = _last_line(store)
        if last is None:
            seq, prev = 0, GENESIS
        else:
            try:
                seq = json.loads(last)["seq"] + 1
            except (ValueError, KeyError, TypeError):
                raise StoreError(f"{store.log_path}: last line is damaged; run `accrue verify`") from None
            prev = hash_bytes(last)
        record = {"seq": seq, "ts": now_iso(), "event": event, "pid": os.getpid(),
                  "host": socket.gethostname(), **fields, "prev": prev}
        line = canonical_json(record) + b"\n"
        fd = os.open(store.log_path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            os.write(fd, line)  # one write(): a kill cannot leave half a line on a local disk
            os.fsync(fd)
        finally:
            os.close(fd)
    return record


def iter_events(store: Store) -> Iterator[dict]:
    try:
        f = open(store.log_path, "rb")
    except FileNotFoundError:
        return
    with f:
        for n, raw in enumerate(f, 1):
            try:
                yield json.loads(raw)
            except ValueError:
                raise StoreError(f"{store.log_path}:{n}: not a JSON line") from None


def check_chain(store: Store) -> tuple[int, list[str]]:
    """(number of events, problems): every line must hash-link to its predecessor."""
    problems: list[str] = []
    prev, n = GENESIS, 0
    try:
        f = open(store.log_path, "rb")
    except FileNotFoundError:
        return 0, []
    with f:
        for n, raw in enumerate(f, 1):
            line = raw.rstrip(b"\n")
            try:
                event = json.loads(line)
            except ValueError:
                problems.append(f"log line {n}: not valid JSON")
                prev = hash_bytes(line)
                continue
            if event.get("prev") != prev:
                problems.append(f"log line {n} (seq {event.get('seq')}): hash chain broken — "
                                "a line before it was changed or removed")
            if event.get("seq") != n - 1:
                problems.append(f"log line {n}: seq {event.get('seq')} out of order")
            prev = hash_bytes(line)
    return n, problems
