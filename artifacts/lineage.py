"""Lineage: the tree of inputs that produced an artifact or step record, down to demos and seeds."""

from __future__ import annotations

from typing import Any

from artifacts.errors import StoreError
from artifacts.provenance import provenance, provenance_index
from artifacts.store import Store


def seed_like(config: Any, prefix: str = "") -> dict[str, Any]:
    """Config entries a reader needs to reproduce a result: any key naming a seed, flattened."""
    out: dict[str, Any] = {}
    if isinstance(config, dict):
        for k, v in config.items():
            name = f"{prefix}{k}"
            if "seed" in str(k).lower() and not isinstance(v, (dict, list)):
                out[name] = v
            else:
                out.update(seed_like(v, name + "."))
    return out


def lineage(store: Store, oid: str, _seen: set[str] | None = None, _index: dict | None = None) -> dict:
    """Nested {id, type, kind, step, seeds, created, inputs: {role: node}}; a node met twice is
    given once in full and then as {id, repeat: true}. An artifact's created, host and source
    come from its provenance (the audit log), not its manifest."""
    seen = _seen if _seen is not None else set()
    index = _index if _index is not None else provenance_index(store)
    if oid in seen:
        return {"id": oid, "repeat": True}
    seen.add(oid)
    try:
        obj = store.read_json(oid)
    except StoreError as exc:
        return {"id": oid, "error": str(exc)}
    node: dict[str, Any] = {"id": oid, "type": obj.get("type")}
    if obj.get("type") == "artifact":
        made = provenance(obj, index, oid)
        node.update(
            kind=obj["kind"],
            step=(obj.get("producer") or {}).get("step"),
            size=obj.get("size"),
            created=made.get("created"),
            seeds=seed_like(obj.get("config", {})),
        )
        if made.get("source"):
            node["source"] = made["source"]
    elif obj.get("type") == "step-record":
        node.update(
            step=obj["step"],
            seeds=seed_like(obj.get("config", {})),
            created=obj.get("finished"),
            outputs=obj.get("outputs", {}),
        )
    node["inputs"] = {role: lineage(store, i, seen, index) for role, i in sorted(obj.get("inputs", {}).items())}
    return node
