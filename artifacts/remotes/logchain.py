"""Other stores' audit logs, as pulled: each store's segments (artifacts/remotes/logsegment.py),
walked back through their `previous` inputs and checked as one chain — every line's `prev` is the
hash of the line before it, across segment boundaries, and seq counts up from 0 — exactly as
`verify` checks this store's own log."""

from __future__ import annotations

import json
from dataclasses import dataclass, field

from artifacts.auditlog import GENESIS
from artifacts.errors import StoreError
from artifacts.hashing import hash_bytes
from artifacts.remotes import LOG_TRACKING
from artifacts.remotes.config import get_remote
from artifacts.remotes.logsegment import KIND
from artifacts.remotes.pointers import tracking_refs
from artifacts.store import Store

MAX_SEGMENTS = 1_000_000  # a cycle of `previous` inputs cannot happen with content ids; a bound anyway


@dataclass
class LogChain:
    store_id: str
    host: str = ""
    segments: int = 0
    events: list[dict] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems

    def summary(self) -> dict:
        return {
            "store_id": self.store_id,
            "host": self.host,
            "segments": self.segments,
            "events": len(self.events),
            "first": self.events[0].get("ts") if self.events else None,
            "last": self.events[-1].get("ts") if self.events else None,
            "ok": self.ok,
            "problems": self.problems,
        }


def remote_log_chains(store: Store, remote: str) -> list[LogChain]:
    """One chain per other store whose log a fetch or pull from this remote brought."""
    spec = get_remote(store, remote)
    return [
        check_chain(store, sid, head) for sid, head in sorted(tracking_refs(store, spec.name, LOG_TRACKING).items())
    ]


def check_chain(store: Store, sid: str, head: str) -> LogChain:
    chain = LogChain(store_id=sid)
    segments: list[tuple[str, dict]] = []
    oid: str | None = head
    while oid and len(segments) < MAX_SEGMENTS:
        try:
            manifest = store.read_json(oid)
        except StoreError as exc:
            chain.problems.append(f"segment {oid[:12]}: {exc}")
            break
        if manifest.get("type") != "artifact" or manifest.get("kind") != KIND:
            chain.problems.append(f"segment {oid[:12]} is not an audit-log segment")
            break
        segments.append((oid, manifest))
        oid = (manifest.get("inputs") or {}).get("previous")
    segments.reverse()
    chain.segments = len(segments)
    chain.host = str((segments[-1][1].get("producer") or {}).get("host", "")) if segments else ""
    prev, seq = GENESIS, 0
    for oid, manifest in segments:
        try:
            data = store.read_bytes(manifest["content"])
        except StoreError as exc:
            chain.problems.append(f"segment {oid[:12]}: {exc}")
            return chain
        lines = data.splitlines()
        meta = manifest.get("meta") or {}
        for n, line in enumerate(lines):
            try:
                event = json.loads(line)
            except ValueError:
                chain.problems.append(f"segment {oid[:12]} line {n + 1}: not valid JSON")
                return chain
            if event.get("prev") != prev:
                chain.problems.append(
                    f"segment {oid[:12]} line {n + 1} (seq {event.get('seq')}): hash chain broken — "
                    "a line before it was changed, removed or never sent"
                )
            if event.get("seq") != seq:
                chain.problems.append(f"segment {oid[:12]} line {n + 1}: seq {event.get('seq')}, expected {seq}")
            chain.events.append(event)
            prev, seq = hash_bytes(line), (event.get("seq") if isinstance(event.get("seq"), int) else seq) + 1
        if lines and (meta.get("events") != len(lines) or meta.get("last_seq") != chain.events[-1].get("seq")):
            chain.problems.append(f"segment {oid[:12]}: its manifest's counts do not match its lines")
    return chain
