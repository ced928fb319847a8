"""Orders that put every object after the objects it names (what a manifest names: artifacts/links.py)."""

from __future__ import annotations


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
