"""The append-only audit log: one JSON line per event, each carrying the hash of the line before.

Events: step-started, step-committed, step-failed, step-abandoned, checkpoint-saved,
artifact-written, ref-moved, gc-started, gc, quarantined, log-repaired. Appends happen under a
kernel lock with O_APPEND and an fsync; nothing ever rewrites the file, so editing or dropping a
line breaks the chain.

A hash chain cannot see its own tail, so the head is anchored outside it: after every append
`log/head` records the seq, hash and byte span of the last line, and every attempt record carries
the head it saw (records.py). Cutting, editing or deleting the log's tail then disagrees with
those anchors; `verify` reports it and appends refuse until `accrue verify --repair` seals the
damage with a `log-repaired` event that names it (the damaged bytes stay, for the audit).
"""

from __future__ import annotations

import json
import os
import socket
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

from artifacts.atomic import write_replace
from artifacts.clock import now_iso
from artifacts.errors import StoreError, os_error_text
from artifacts.hashing import canonical_json, hash_bytes, is_full_id
from artifacts.locks import store_lock
from artifacts.store import Store

GENESIS = "0" * 64
LOG_FORMAT = 2  # events written with a log/head beside them say so, so a lost head is noticed
_TAIL_BYTES = 64 * 1024
_REPAIR_HINT = "`accrue verify` shows the damage, `accrue verify --repair` seals it"


def head_path(store: Store) -> Path:
    return store.log_path.parent / "head"


@dataclass
class Head:
    seq: int
    hash: str
    start: int  # byte offset of the last line
    end: int  # byte offset just after it (its newline included)


def read_head(store: Store) -> Head | None:
    path = head_path(store)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise StoreError(f"cannot read the audit log's head: {os_error_text(exc)}") from None
    try:
        h = json.loads(raw)
        head = Head(int(h["seq"]), str(h["hash"]), int(h["start"]), int(h["end"]))
    except (ValueError, KeyError, TypeError):
        raise StoreError(f"{path} is damaged (not a log head); {_REPAIR_HINT}") from None
    if not is_full_id(head.hash) or not 0 <= head.start < head.end or head.seq < 0:
        raise StoreError(f"{path} is damaged (not a log head); {_REPAIR_HINT}")
    return head


def current_anchor(store: Store) -> dict | None:
    """{"seq", "hash"} of the log's last anchored line, for records written beside the log."""
    try:
        head = read_head(store)
    except StoreError:
        return None
    return {"seq": head.seq, "hash": head.hash} if head else None


def _damaged(store: Store, reason: str) -> StoreError:
    return StoreError(f"audit log {store.log_path}: {reason}; nothing was written ({_REPAIR_HINT})")


def _parse(line: bytes) -> dict | None:
    try:
        event = json.loads(line)
    except ValueError:
        return None
    return event if isinstance(event, dict) else None


def _last_line(store: Store, size: int) -> bytes:
    with open(store.log_path, "rb") as f:
        step = _TAIL_BYTES
        while True:
            start = max(0, size - step)
            f.seek(start)
            data = f.read(size - start)
            lines = data[:-1].split(b"\n") if data.endswith(b"\n") else [b""]
            if len(lines) > 1 or start == 0:
                return lines[-1]
            step *= 2


def _tail(store: Store) -> tuple[int, str, int]:
    """(next seq, hash of the last line, log size) for the next append; StoreError when the tail
    disagrees with the head (cut, edited, half-written) — appending would bury the damage."""
    head = read_head(store)
    try:
        size = store.log_path.stat().st_size
    except FileNotFoundError:
        size = 0
    if size == 0:
        if head is not None:
            raise _damaged(store, f"the log is missing or empty, but log/head says it ended at seq {head.seq}")
        return 0, GENESIS, 0
    if head is None:
        last = _last_line(store, size)
        event = _parse(last)
        if not last or event is None or not isinstance(event.get("seq"), int):
            raise _damaged(store, "its last line is damaged")
        if event.get("log_format", 1) >= LOG_FORMAT:
            raise _damaged(store, "log/head is missing")
        return event["seq"] + 1, hash_bytes(last), size  # a log from before heads existed
    if size < head.end:
        raise _damaged(
            store,
            f"it is {size} bytes long, but log/head says its seq {head.seq} ends at byte {head.end}: its tail was cut",
        )
    with open(store.log_path, "rb") as f:
        f.seek(head.start)
        data = f.read(size - head.start)
    anchored, rest = data[: head.end - head.start], data[head.end - head.start :]
    event = _parse(anchored[:-1])
    if (
        not anchored.endswith(b"\n")
        or hash_bytes(anchored[:-1]) != head.hash
        or event is None
        or event.get("seq") != head.seq
    ):
        raise _damaged(store, f"its line of seq {head.seq} is not the one log/head recorded: it was edited")
    seq, prev = head.seq, head.hash
    if rest and not rest.endswith(b"\n"):
        raise _damaged(store, "its last line is incomplete")
    for line in rest[:-1].split(b"\n") if rest else []:  # lines a crash left unanchored (normally one)
        event = _parse(line)
        if event is None or event.get("prev") != prev or event.get("seq") != seq + 1:
            raise _damaged(store, f"the line after seq {seq} is damaged")
        seq, prev = seq + 1, hash_bytes(line)
    return seq + 1, prev, size


def _write_head(store: Store, seq: int, digest: str, start: int, end: int) -> None:
    write_replace(head_path(store), canonical_json({"seq": seq, "hash": digest, "start": start, "end": end}) + b"\n")


def _append_line(store: Store, line: bytes, size: int) -> None:
    fd = os.open(store.log_path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        try:
            if os.write(fd, line) != len(line):  # one write(): a kill cannot leave half a line
                raise OSError(28, "No space left on device (short write)", str(store.log_path))
            os.fsync(fd)
        except OSError:
            try:
                os.ftruncate(fd, size)  # take back our own partial line (we hold the log lock)
            except OSError:
                pass
            raise
    finally:
        os.close(fd)


def _log_lock(store: Store):
    try:
        store.log_path.parent.mkdir(exist_ok=True)
        return store_lock(store.locks_dir, "log")
    except OSError as exc:
        raise StoreError(f"cannot write the audit log: {os_error_text(exc)}") from None


def ensure_appendable(store: Store) -> None:
    """StoreError now (before anything else is written) if an append would be refused."""
    try:
        with _log_lock(store):
            _tail(store)
    except OSError as exc:
        raise StoreError(f"cannot write the audit log: {os_error_text(exc)}") from None


def append_event(store: Store, event: str, **fields: Any) -> dict:
    """Append one event and return it (with its seq and prev hash)."""
    try:
        with _log_lock(store):
            seq, prev, size = _tail(store)
            record = {
                "seq": seq,
                "ts": now_iso(),
                "event": event,
                "pid": os.getpid(),
                "host": socket.gethostname(),
                **fields,
                "prev": prev,
                "log_format": LOG_FORMAT,
            }
            line = canonical_json(record) + b"\n"
            _append_line(store, line, size)
            _write_head(store, seq, hash_bytes(line[:-1]), size, size + len(line))
    except OSError as exc:
        raise StoreError(f"cannot write the audit log: {os_error_text(exc)}") from None
    return record


def iter_events(store: Store) -> Iterator[dict]:
    """Every event in order; a damaged line is yielded as {"event": "damaged-line", "line": n}."""
    try:
        f = open(store.log_path, "rb")
    except FileNotFoundError:
        return
    except OSError as exc:
        raise StoreError(f"cannot read the audit log: {os_error_text(exc)}") from None
    with f:
        for n, raw in enumerate(f, 1):
            event = _parse(raw)
            yield event if event is not None else {"seq": None, "event": "damaged-line", "line": n}


# ----------------------------------------------------------------------------- checking
@dataclass
class LogProblem:
    text: str
    line: int | None = None  # 1-based line the problem is about
    anchor: tuple[int, str] | None = None  # (seq, hash) an outside record expected


@dataclass
class LogCheck:
    events: int = 0
    problems: list[LogProblem] = field(default_factory=list)  # not sealed by a repair
    sealed: list[str] = field(default_factory=list)  # what each log-repaired event sealed


@dataclass
class _Lines:
    lines: list[bytes]  # without their newlines
    ends: list[int]  # byte offset just after each line
    present: bool  # the file exists
    partial: bool  # the last line has no newline (a write was cut off)


def _read_lines(store: Store) -> _Lines:
    try:
        data = store.log_path.read_bytes()
    except FileNotFoundError:
        return _Lines([], [], False, False)
    except OSError as exc:
        raise StoreError(f"cannot read the audit log: {os_error_text(exc)}") from None
    partial = bool(data) and not data.endswith(b"\n")
    pieces = data.split(b"\n") if partial else data.split(b"\n")[:-1]
    lines, ends, pos = [], [], 0
    for piece in pieces:
        pos += len(piece) + 1
        lines.append(piece)
        ends.append(min(pos, len(data)))
    return _Lines(lines, ends, True, partial)


def check_log(store: Store, anchors: list[tuple[str, dict]] = (), has_history: bool = False) -> LogCheck:
    """Chain, head and outside anchors. anchors: (what, {"seq", "hash"}) that records saw;
    has_history: refs or records exist, so an absent log means a deleted one."""
    found: list[LogProblem] = []
    read = _read_lines(store)
    lines, ends = read.lines, read.ends
    sealed_lines: set[int] = set()
    sealed_anchors: set[tuple[int, str]] = set()
    repairs: list[str] = []
    prev, newest_format = GENESIS, 1
    for n, line in enumerate(lines, 1):
        event = _parse(line)
        if event is None:
            why = "incomplete (a write was cut off)" if read.partial and n == len(lines) else "not valid JSON"
            found.append(LogProblem(f"log line {n}: {why}", line=n))
        else:
            if event.get("prev") != prev:
                found.append(
                    LogProblem(
                        f"log line {n} (seq {event.get('seq')}): hash chain broken — "
                        "a line before it was changed or removed",
                        line=n,
                    )
                )
            if event.get("seq") != n - 1:
                found.append(LogProblem(f"log line {n}: seq {event.get('seq')} out of order", line=n))
            newest_format = max(
                newest_format, event.get("log_format", 1) if isinstance(event.get("log_format"), int) else 1
            )
            if event.get("event") == "log-repaired":
                sealed_lines.update(event.get("sealed_lines") or [])
                sealed_anchors |= {(s, h) for s, h in event.get("sealed_anchors") or []}
                named = event.get("problems") or ["?"]
                repairs.append(
                    f"log-repaired at seq {event.get('seq')} ({str(event.get('ts'))[:19]}) sealed "
                    f"{len(named)} problem(s): {'; '.join(named[:3])}{'…' if len(named) > 3 else ''}"
                )
        prev = hash_bytes(line)
    try:
        head = read_head(store)
        head_error = None
    except StoreError as exc:
        head, head_error = None, str(exc)
    if head_error:
        found.append(LogProblem(head_error))
    elif head is not None:
        found += _head_problems(head, lines, ends, read.present)
    elif lines and newest_format >= LOG_FORMAT:
        found.append(LogProblem("log/head is missing (it was deleted; the log's tail cannot be trusted)"))
    elif not lines and has_history:
        found.append(
            LogProblem(
                f"the audit log {store.log_path} is missing or empty, but the store has refs "
                "and records: it was deleted"
            )
        )
    for what, anchor in anchors:
        seq, digest = anchor.get("seq"), anchor.get("hash")
        if not isinstance(seq, int) or seq < 0 or not isinstance(digest, str):
            continue  # not an anchor (a damaged record): nothing to hold the log to
        if seq >= len(lines) or hash_bytes(lines[seq]) != digest:
            had = "does not hold it" if seq >= len(lines) else "holds a different line there"
            found.append(
                LogProblem(
                    f"{what} was written after log event seq {seq}, but the log {had}: it was cut or rewritten",
                    anchor=(seq, digest),
                )
            )
    check = LogCheck(events=len(lines), sealed=repairs)
    check.problems = [
        p
        for p in found
        if not (
            (p.line is not None and p.line in sealed_lines) or (p.anchor is not None and p.anchor in sealed_anchors)
        )
    ]
    return check


def _head_problems(head: Head, lines: list[bytes], ends: list[int], present: bool) -> list[LogProblem]:
    if not lines:
        return [
            LogProblem(
                f"the audit log is {'empty' if present else 'missing'}, but log/head says it ended "
                f"at seq {head.seq}: it was {'cut' if present else 'deleted'}"
            )
        ]
    if ends[-1] < head.end:
        last = _parse(lines[-1]) or {}
        return [
            LogProblem(
                f"the log ends at seq {last.get('seq', '?')} (byte {ends[-1]}), but log/head says "
                f"it ended at seq {head.seq} (byte {head.end}): its tail was cut"
            )
        ]
    starts = [0, *ends[:-1]]
    if head.end in ends:
        n = ends.index(head.end) + 1
    elif head.start in starts:  # the line is where the head says, but longer or shorter
        n = starts.index(head.start) + 1
    else:
        return [
            LogProblem(
                f"no log line ends at byte {head.end}, where log/head says seq {head.seq} ends: the log was rewritten"
            )
        ]
    event = _parse(lines[n - 1]) or {}
    if hash_bytes(lines[n - 1]) != head.hash or event.get("seq") != head.seq:
        return [
            LogProblem(
                f"log line {n} (seq {event.get('seq')}) is not the line log/head recorded: it was edited", line=n
            )
        ]
    return []


def check_chain(store: Store) -> tuple[int, list[str]]:
    """(number of events, problems) of the log on its own (chain and head, no outside anchors)."""
    check = check_log(store)
    return check.events, [p.text for p in check.problems]


def repair_log(store: Store, check: LogCheck) -> dict | None:
    """Seal the problems of `check` with a log-repaired event (None if there are none). Nothing
    is rewritten: a half-written last line is completed with a newline, the event chains onto
    whatever the log ends with, and log/head is re-anchored on it."""
    if not check.problems:
        return None
    problems = check.problems
    try:
        with _log_lock(store):
            read = _read_lines(store)
            lines = read.lines
            size = read.ends[-1] if lines else 0
            if read.partial:  # complete the cut-off line, so the seal starts a line of its own
                _append_line(store, b"\n", size)
                size += 1
            prev = hash_bytes(lines[-1]) if lines else GENESIS
            seq = len(lines)
            record = {
                "seq": seq,
                "ts": now_iso(),
                "event": "log-repaired",
                "pid": os.getpid(),
                "host": socket.gethostname(),
                "problems": [p.text[:300] for p in problems[:50]],
                "sealed_lines": sorted({p.line for p in problems if p.line is not None}),
                "sealed_anchors": sorted({p.anchor for p in problems if p.anchor is not None}),
                "prev": prev,
                "log_format": LOG_FORMAT,
            }
            line = canonical_json(record) + b"\n"
            _append_line(store, line, size)
            _write_head(store, seq, hash_bytes(line[:-1]), size, size + len(line))
    except OSError as exc:
        raise StoreError(f"cannot repair the audit log: {os_error_text(exc)}") from None
    return record
