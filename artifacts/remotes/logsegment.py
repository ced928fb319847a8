"""The audit log travels as segments: each push sends the lines written since the last push to
that remote, as an `audit-log` artifact whose input `previous` is the segment before it. The first
line of a segment carries the hash of the last line of the previous one, so the chain can be
checked across segments exactly as within the local file (artifacts/remotes/logchain.py does)."""

from __future__ import annotations

import json
import socket
from dataclasses import dataclass

from artifacts.hashing import canonical_json, hash_bytes
from artifacts.manifests import MANIFEST_FORMAT
from artifacts.store import Store

KIND = "audit-log"


@dataclass
class Segment:
    manifest_id: str
    manifest: bytes
    data_id: str
    data: bytes
    end: int  # byte offset in the local log just after this segment


def next_segment(store: Store, sid: str, previous: str | None, start: int) -> Segment | None:
    """The log lines from byte `start` (whole lines only), or None when there are none. If the
    log is shorter than `start` (it was replaced), the chain starts again from its beginning."""
    try:
        log = store.log_path.read_bytes()
    except FileNotFoundError:
        return None
    if len(log) < start:
        previous, start = None, 0
    end = log.rfind(b"\n") + 1  # a line being appended right now waits for the next push
    if end <= start:
        return None
    data = log[start:end]
    lines = data.splitlines()
    first, last = json.loads(lines[0]), json.loads(lines[-1])
    manifest = {
        "type": "artifact",
        "format": MANIFEST_FORMAT,
        "kind": KIND,
        "producer": {"store": sid, "host": socket.gethostname()},
        "inputs": {"previous": previous} if previous else {},
        "config": {},
        "code_version": "",
        "created": last.get("ts", ""),
        "meta": {"first_seq": first.get("seq"), "last_seq": last.get("seq"), "events": len(lines)},
        "layout": "file",
        "content": hash_bytes(data),
        "size": len(data),
        "files": 1,
        "name": "events.jsonl",
    }
    raw = canonical_json(manifest)
    return Segment(hash_bytes(raw), raw, manifest["content"], data, end)
