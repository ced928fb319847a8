"""Audit logs the tests write by hand: a log from before log/head existed."""

from __future__ import annotations

from artifacts.auditlog import head_path
from artifacts.hashing import canonical_json, hash_bytes
from artifacts.store import Store


def write_old_log(store: Store, extras: list[dict]) -> bytes:
    """A log from before log/head existed (no log_format, no head file): one event per extra, chained.
    Returns the last line (without its newline)."""
    prev, raw, line = "0" * 64, [], b""
    for seq, extra in enumerate(extras):
        line = canonical_json(
            {"seq": seq, "ts": "2026-01-01T00:00:00.000+00:00", "event": "custom", **extra, "prev": prev}
        )
        raw.append(line + b"\n")
        prev = hash_bytes(line)
    store.log_path.write_bytes(b"".join(raw))
    head_path(store).unlink(missing_ok=True)
    return line
