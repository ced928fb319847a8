"""Refs: mutable names (e.g. workflow/quick/stage/2/handoff) that point at durable objects.

A ref file holds one id and a newline. Updates happen under a kernel lock and by atomic
replace, and only after the target object exists, so a ref never points at nothing.
"""
from __future__ import annotations

import re
from pathlib import Path

from artifacts.atomic import write_replace
from artifacts.errors import StoreError
from artifacts.hashing import is_full_id
from artifacts.locks import store_lock
from artifacts.store import Store

_SEGMENT = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._+-]{0,99}$")


def check_ref_name(name: str) -> str:
    parts = name.split("/")
    if not name or any(not _SEGMENT.match(p) for p in parts):
        raise StoreError(f"bad ref name {name!r}: use '/'-separated parts of letters, digits, '.', '_', '-', '+'")
    return name


def _ref_path(store: Store, name: str) -> Path:
    return store.refs_dir / check_ref_name(name)


def read_ref(store: Store, name: str) -> str | None:
    path = _ref_path(store, name)
    if not path.is_file():
        return None
    oid = path.read_text().strip()
    if not is_full_id(oid):
        raise StoreError(f"ref {name} is damaged (holds {oid[:20]!r}, not an id)")
    return oid


def set_ref(store: Store, name: str, oid: str, log: bool = True) -> str | None:
    """Point name at oid (which must exist). Returns the previous target. Logs a ref-moved event."""
    path = _ref_path(store, name)
    if not is_full_id(oid) or not store.has_object(oid):
        raise StoreError(f"refusing to point ref {name} at {oid[:12]}: no such object in the store")
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
            write_replace(path, (oid + "\n").encode(), tmp_dir=path.parent if path.parent.exists() else None)
            if log:
                from artifacts.auditlog import append_event

                append_event(store, "ref-moved", ref=name, old=old, new=oid)
    return old


def list_refs(store: Store, prefix: str = "") -> dict[str, str]:
    """All refs (name -> id) whose name starts with prefix; a damaged ref raises StoreError."""
    out: dict[str, str] = {}
    if not store.refs_dir.is_dir():
        return out
    for path in sorted(store.refs_dir.rglob("*")):
        if path.is_file() and not path.name.startswith("."):
            name = path.relative_to(store.refs_dir).as_posix()
            if name.startswith(prefix):
                oid = read_ref(store, name)
                if oid:
                    out[name] = oid
    return out
