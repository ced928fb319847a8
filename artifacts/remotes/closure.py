"""What a manifest names, and orders that put every object after the objects it names."""

from __future__ import annotations

from artifacts.errors import StoreError
from artifacts.hashing import is_full_id
from artifacts.reachability import LEAF_RECORDS


def children(oid: str, obj: dict) -> list[tuple[str, int | None]]:
    """(id, size) of every object a manifest names; size None for another manifest (the same
    rules as reachability.walk). StoreError for JSON that is no manifest: a remote's objects are
    anyone's bytes, and their shape is checked before a walk follows them."""
    try:
        named = _named(obj)
    except (AttributeError, KeyError, TypeError):  # JSON of another shape: a list, a missing field
        named = None
    if named is None or not all(isinstance(i, str) and is_full_id(i) and (s is None or _is_size(s)) for i, s in named):
        raise StoreError(f"object {oid[:12]} is not a manifest")
    return named


def _named(obj: dict) -> list[tuple[str, int | None]] | None:
    kind = obj.get("type")
    if kind == "artifact":
        content = [(obj["content"], None if obj["layout"] == "dir" else obj["size"])]
        return content + [(i, None) for i in obj.get("inputs", {}).values()]
    if kind == "tree":
        return [(e["id"], e["size"]) for e in obj["entries"]]
    if kind == "step-record":
        return [(i, None) for i in obj.get("inputs", {}).values()] + [
            (i, None) for i in obj.get("outputs", {}).values()
        ]
    if kind in LEAF_RECORDS:  # e.g. a bench cell's outcome: travels, names nothing
        return []
    return None


def _is_size(size: object) -> bool:
    return isinstance(size, int) and not isinstance(size, bool) and size >= 0


def bottom_up(named: dict[str, list[str]]) -> list[list[str]]:
    """Manifests grouped by height (those naming only data first): writing group after group
    puts every manifest after everything it names, so a reader never meets a dangling id."""
    height: dict[str, int] = {}
    for start in named:
        stack = [(start, False)]
        while stack:
            oid, expanded = stack.pop()
            if oid in height:
                continue
            kids = [k for k in named.get(oid, ()) if k in named]
            if expanded:
                height[oid] = 1 + max((height.get(k, 0) for k in kids), default=0)
                continue
            stack.append((oid, True))
            stack += [(k, False) for k in kids if k not in height]
    groups: dict[int, list[str]] = {}
    for oid, h in height.items():
        groups.setdefault(h, []).append(oid)
    return [sorted(groups[h]) for h in sorted(groups)]
