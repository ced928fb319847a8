"""What a manifest names: the one rule that gc, verify, push, pull and repair all walk by
(artifacts/manifests.py writes manifests; this module reads the ids inside them).

A manifest is a JSON object whose "type" is artifact, tree or step-record; it names other
objects by full id, with the byte size of each data object (None for another manifest). A
leaf record (a bench cell's outcome) is kept but names nothing. Anything else is no manifest:
the store's and a remote's objects are anyone's bytes, so the shape is checked before a walk
follows it.
"""

from __future__ import annotations

from typing import NamedTuple

from artifacts.errors import StoreError
from artifacts.hashing import is_full_id

# JSON records a ref may name that name no object themselves: kept, walked no further
LEAF_RECORDS = ("bench-cell",)  # stages/bench/state.py: a bench cell's outcome


class Link(NamedTuple):
    id: str
    size: int | None  # bytes of a data object; None: another manifest
    role: str  # how the manifest names it, appended to the manifest's name in messages


def links(oid: str, obj: object) -> list[Link]:
    """Every object the manifest `oid` (already parsed to `obj`) names. StoreError for JSON of
    any other shape: a list, a missing field, an id that is no full id, a size that is no count."""
    try:
        named = _named(obj)
    except (AttributeError, KeyError, TypeError):  # JSON of another shape: a list, a missing field
        named = None
    if named is None or not all(_is_id(link.id) and (link.size is None or _is_size(link.size)) for link in named):
        raise StoreError(f"object {oid[:12]} is not a manifest")
    return named


def children(oid: str, obj: object) -> list[tuple[str, int | None]]:
    """(id, size) of every object the manifest names: `links` without the roles."""
    return [(link.id, link.size) for link in links(oid, obj)]


def _named(obj: object) -> list[Link] | None:
    kind = obj.get("type")  # AttributeError for JSON that is no object
    if kind == "artifact":
        content = Link(obj["content"], None if obj["layout"] == "dir" else obj["size"], "")
        return [content] + [Link(i, None, f" input {r}") for r, i in obj.get("inputs", {}).items()]
    if kind == "tree":
        return [Link(e["id"], e["size"], f":{e['path']}") for e in obj["entries"]]
    if kind == "step-record":
        return [Link(i, None, f" input {r}") for r, i in obj.get("inputs", {}).items()] + [
            Link(i, None, f" output {r}") for r, i in obj.get("outputs", {}).items()
        ]
    if kind in LEAF_RECORDS:  # e.g. a bench cell's outcome: travels, names nothing
        return []
    return None


def _is_id(oid: object) -> bool:
    return isinstance(oid, str) and is_full_id(oid)


def _is_size(size: object) -> bool:
    return isinstance(size, int) and not isinstance(size, bool) and size >= 0
