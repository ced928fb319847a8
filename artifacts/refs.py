"""Refs: mutable names (e.g. workflow/quick/stage/2/handoff) that point at durable objects.

A ref file holds one id and a newline. Updates happen under a kernel lock and by atomic
replace, and only after the target object exists, so a ref never points at nothing.
"""

from __future__ import annotations

import re
from pathlib import Path

from artifacts import writers
from artifacts.atomic import write_replace
from artifacts.errors import StoreError, quote, store_os_error
from artifacts.hashing import ID_LENGTH, is_full_id
from artifacts.locks import store_lock
from artifacts.store import Store

_SEGMENT = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._+-]{0,99}$")


def check_ref_name(name: str) -> str:
    parts = name.split("/")
    if not name or any(not _SEGMENT.match(p) for p in parts):
        raise StoreError(f"bad ref name {quote(name)}: use '/'-separated parts of letters, digits, '.', '_', '-', '+'")
    return name


def _ref_path(store: Store, name: str) -> Path:
    return store.refs_dir / check_ref_name(name)


def read_ref(store: Store, name: str) -> str | None:
    return _read_ref_file(_ref_path(store, name), name)


def _read_ref_file(path: Path, name: str) -> str | None:
    """The id a ref file holds; StoreError naming the ref when it holds anything else (a foreign
    or binary file, say) — never more than a ref's worth of it is read."""
    try:
        with open(path, "rb") as f:
            raw = f.read(ID_LENGTH + 64)
    except (FileNotFoundError, IsADirectoryError, NotADirectoryError):
        return None
    except OSError as exc:
        raise StoreError(f"ref {name} cannot be read ({exc.strerror})") from None
    oid = raw.strip().decode("ascii", "replace")
    if not is_full_id(oid):
        raise StoreError(
            f"ref {name} is damaged (holds {quote(raw[:20])}, not an id): "
            f"not written by accrue? move {path} out of the store"
        )
    return oid


def set_ref(store: Store, name: str, oid: str, log: bool = True) -> str | None:
    """Point name at oid (which must exist). Returns the previous target. Logs a ref-moved event."""
    path = _ref_path(store, name)
    writers.hold(store)  # before the existence check: gc cannot sweep oid from now on
    if not is_full_id(oid) or not store.has_object(oid):
        raise StoreError(f"refusing to point ref {name} at {oid[:12]}: no such object in the store")
    try:
        return _move(store, name, path, oid, log)
    except OSError as exc:
        raise store_os_error(exc, f"cannot move ref {name}") from None


def _move(store: Store, name: str, path: Path, oid: str, log: bool) -> str | None:
    from artifacts.auditlog import append_event, ensure_appendable

    with store_lock(store.locks_dir, "refs"):
        old = read_ref(store, name)
        if old != oid:
            for parent in path.parents:  # a ref cannot also be a directory of refs
                if parent == store.refs_dir:
                    break
                if parent.is_file():
                    raise StoreError(f"ref {name} conflicts with existing ref {parent.relative_to(store.refs_dir)}")
            if path.is_dir():
                raise StoreError(f"ref {name} conflicts with existing refs under {name}/")
            if log:
                ensure_appendable(store)  # a move the log cannot record is not made
            write_replace(path, (oid + "\n").encode())
            if log:
                append_event(store, "ref-moved", ref=name, old=old, new=oid)
    return old


def delete_ref(store: Store, name: str, log: bool = True, expect: str | None = None) -> str | None:
    """Remove a ref (what it named stays until gc finds nothing else reaches it). Returns its id.
    With expect, only if it still names that id (compare-and-delete): else nothing changes and the
    id it names now is returned."""
    from artifacts.auditlog import append_event, ensure_appendable

    path = _ref_path(store, name)
    with store_lock(store.locks_dir, "refs"):
        old = read_ref(store, name)
        if old is None or (expect is not None and old != expect):
            return old
        if log:
            ensure_appendable(store)
        try:
            path.unlink()
        except OSError as exc:
            raise store_os_error(exc, f"cannot remove ref {name}") from None
        for parent in path.parents:  # drop directories the ref leaves empty
            if parent == store.refs_dir:
                break
            try:
                parent.rmdir()
            except OSError:
                break
        if log:
            append_event(store, "ref-deleted", ref=name, old=old)
    return old


def list_refs(store: Store, prefix: str = "", problems: list[str] | None = None) -> dict[str, str]:
    """All refs (name -> id) whose name starts with prefix. A damaged or foreign file under refs/
    raises StoreError, or, when a `problems` list is given, is reported there and skipped."""
    out: dict[str, str] = {}
    if not store.refs_dir.is_dir():
        return out
    for path in sorted(store.refs_dir.rglob("*")):
        if path.name.startswith(".") or not path.is_file():
            continue  # temp files of ref updates; directories of refs
        name = path.relative_to(store.refs_dir).as_posix()
        if not name.startswith(prefix):
            continue
        try:
            oid = _read_ref_file(path, check_ref_name(name))
        except StoreError as exc:
            if problems is None:
                raise
            problems.append(str(exc))
            continue
        if oid:
            out[name] = oid
    return out
