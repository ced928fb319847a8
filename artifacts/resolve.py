"""Turn what a user types into a full id: a ref name, a full id, or an unambiguous hex prefix;
`X:role` picks output `role` of the step record X (e.g. workflow/quick/stage/1/handoff:handoff)."""

from __future__ import annotations

from artifacts import writers
from artifacts.errors import StoreError, quote
from artifacts.refs import _SEGMENT, read_ref
from artifacts.store import Store


def resolve(store: Store, text: str) -> str:
    writers.hold(store)  # whoever looks an id up may name it next: gc waits until this handle closes
    base, _, role = text.partition(":")
    oid = None
    if base and all(_SEGMENT.match(p) for p in base.split("/")):
        oid = read_ref(store, base)
    if oid is None:
        oid = store.resolve_prefix(base)
    if role:
        record = store.read_json(oid)
        outputs = record.get("outputs") if record.get("type") == "step-record" else None
        if outputs is None:
            raise StoreError(f"{quote(base)}: not a step record, so it has no output {quote(role)}")
        if role not in outputs:
            raise StoreError(
                f"{quote(base)}: step {record['step']} has no output {quote(role)} "
                f"(it has: {', '.join(sorted(outputs)) or 'none'})"
            )
        oid = outputs[role]
    return oid
