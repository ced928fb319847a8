"""Provenance: when, where and by what an artifact was made — kept outside its manifest, so that its
id stays a function of its inputs (see manifests.py).

A format-2 artifact's provenance is the first audit-log event that wrote it (artifact-written for
step outputs and `accrue add`, checkpoint-saved for checkpoints): time, host, and the step,
attempt, cache key or source path the event names. This store's log is read first, then the logs
of other stores that pulls brought (remote-logs/), so a pulled artifact keeps the provenance of the
store that made it. A format-1 manifest carried its own `created` and producer fields, which are
used as they are.
"""

from __future__ import annotations

from typing import Iterator

from artifacts.auditlog import iter_events
from artifacts.remotes.config import list_remotes
from artifacts.remotes.logchain import remote_log_chains
from artifacts.store import Store

_WRITES = {"artifact-written": "artifact", "checkpoint-saved": "checkpoint"}
_FIELDS = ("step", "attempt", "cache_key", "source", "host")


def provenance_index(store: Store) -> dict[str, dict]:
    """artifact id -> {created, host, step, attempt, cache_key, source} (the fields its first
    writing event has), from one pass over the audit log."""
    out: dict[str, dict] = {}
    for event in _all_events(store):
        field = _WRITES.get(str(event.get("event")))
        oid = event.get(field) if field else None
        if isinstance(oid, str) and oid not in out:
            out[oid] = {"created": event.get("ts"), **{k: event[k] for k in _FIELDS if k in event}}
    return out


def provenance(manifest: dict, index: dict[str, dict], artifact_id: str) -> dict:
    """The provenance of one artifact: a format-1 manifest's own fields, else the log's."""
    if "created" in manifest:  # format 1
        return {"created": manifest["created"], **(manifest.get("producer") or {})}
    return dict(index.get(artifact_id, {}))


def _all_events(store: Store) -> Iterator[dict]:
    """This store's events, then those of every other store's log pulled from its remotes."""
    yield from iter_events(store)
    for name in list_remotes(store):
        for chain in remote_log_chains(store, name):
            yield from chain.events
