"""What the store must keep: the objects reachable from refs and attempt records.

Shared by verify (everything reachable must exist) and gc (everything else may go), so the two
can never disagree. Roots: every ref; every committed attempt's step record; the inputs and
checkpoints of attempts that did not commit (so `continue` still works).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from artifacts.errors import StoreError
from artifacts.links import links
from artifacts.records import list_attempts
from artifacts.refs import list_refs
from artifacts.store import Store


@dataclass
class Reach:
    sizes: dict[str, int | None] = field(default_factory=dict)  # id -> expected size (None: manifest)
    problems: list[str] = field(default_factory=list)


def roots(store: Store, problems: list[str] | None = None) -> list[tuple[str, str]]:
    """(id, where it is named) for every gc root."""
    out = [(oid, f"ref {name}") for name, oid in _refs(store, problems).items()]
    for a in list_attempts(store, problems=problems):
        where = f"attempt {a['cache_key'][:12]}/{a['attempt']:04d} ({a['step']})"
        if a["state"] == "committed" and a.get("record_id"):
            out.append((a["record_id"], where))
        elif a["state"] != "committed":
            out += [(c["id"], where + " checkpoint") for c in a.get("checkpoints", [])]
            out += [(i, where + f" input {r}") for r, i in a.get("inputs", {}).items()]
    return out


def _refs(store: Store, problems: list[str] | None) -> dict[str, str]:
    """Every readable ref; a damaged or foreign file under refs/ is a problem (gc then refuses:
    whatever it named is unknown), and the other refs still count."""
    return list_refs(store, problems=problems)


def walk(store: Store) -> Reach:
    reach = Reach()
    stack = [(oid, where, None) for oid, where in roots(store, reach.problems)]
    while stack:
        oid, where, size = stack.pop()
        if oid in reach.sizes:
            continue
        reach.sizes[oid] = size
        actual = store.object_size(oid)
        if actual is None:
            if not store.is_promised(oid):  # a partial pull left it on a remote on purpose
                reach.problems.append(f"missing object {oid[:12]} (named by {where})")
            continue
        if size is not None:  # a data object: its size is all a quick check can know
            if actual != size:
                reach.problems.append(f"object {oid[:12]} has size {actual}, expected {size} (named by {where})")
            continue
        try:
            obj = store.read_json(oid)
        except StoreError as exc:
            reach.problems.append(f"{exc} (named by {where})")
            continue
        try:
            named = links(oid, obj)
        except StoreError:
            reach.problems.append(f"object {oid[:12]} named by {where} is not a manifest")
            continue
        here = f"{obj['type']} {oid[:12]}"
        stack += [(link.id, here + link.role, link.size) for link in named]
    return reach
