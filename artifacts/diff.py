"""diff: what differs between two step records, two artifacts (handoffs, say) or two runs (ref
prefixes such as workflow/a and workflow/b, matched step by step) — inputs, config fields, code
versions, where and how long it ran — with their metrics side by side, as `dvc params diff` and
`dvc metrics diff` do. Metrics are the numbers in the small JSON files an output holds."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

from artifacts.errors import StoreError, quote
from artifacts.refs import list_refs
from artifacts.resolve import resolve
from artifacts.store import Store

METRICS_FILE_MAX = 1 << 20  # bigger JSON files are data, not metrics files: not read
METRICS_PER_OUTPUT = 200


@dataclass
class Diff:
    a: str
    b: str
    fields: dict[str, list] = field(default_factory=dict)  # name -> [A's, B's], only where they differ
    metrics: dict[str, list] = field(default_factory=dict)  # name -> [A's, B's] (None: absent on that side)
    only_a: list[str] = field(default_factory=list)  # runs: steps only one side has
    only_b: list[str] = field(default_factory=list)

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def _flat(prefix: str, value: Any, out: dict[str, Any]) -> None:
    if isinstance(value, dict) and value:
        for k in sorted(value):
            _flat(f"{prefix}.{k}" if prefix else str(k), value[k], out)
    else:
        out[prefix] = value


def _seconds(start: Any, end: Any) -> float | None:
    try:
        return round((datetime.fromisoformat(end) - datetime.fromisoformat(start)).total_seconds(), 3)
    except (TypeError, ValueError):
        return None


def describe(store: Store, oid: str) -> tuple[dict[str, Any], dict[str, Any]]:
    """(fields, metrics) of a step record or an artifact, flattened to dotted names."""
    if (store.object_size(oid) or 0) > METRICS_FILE_MAX:  # not read whole just to find it is data
        raise StoreError(f"{oid[:12]} is a data object; diff compares step records, artifacts or runs")
    obj = store.read_json(oid)
    fields: dict[str, Any] = {}
    metrics: dict[str, Any] = {}
    kind = obj.get("type")
    if kind == "step-record":
        for k in ("step", "code_version", "host"):
            fields[k] = obj.get(k)
        fields["duration_s"] = _seconds(obj.get("started"), obj.get("finished"))
        _flat("config", obj.get("config") or {}, fields)
        _flat("input", obj.get("inputs") or {}, fields)
        _flat("output", obj.get("outputs") or {}, fields)
        for role, out in sorted((obj.get("outputs") or {}).items()):
            metrics.update(_metrics(store, out, role))
    elif kind == "artifact":
        for k in ("kind", "code_version", "size", "files"):
            fields[k] = obj.get(k)
        fields["content"] = obj.get("content")
        _flat("producer", obj.get("producer") or {}, fields)
        _flat("config", obj.get("config") or {}, fields)
        _flat("input", obj.get("inputs") or {}, fields)
        metrics.update(_metrics(store, oid, obj.get("kind", "artifact")))
    else:
        raise StoreError(f"{oid[:12]} is a {kind or 'data'} object; diff compares step records, artifacts or runs")
    return fields, metrics


def _metrics(store: Store, artifact_id: str, label: str) -> dict[str, Any]:
    """Numbers in the artifact's top-level JSON files (a file artifact that is JSON counts too)."""
    manifest = store.read_json(artifact_id)
    if manifest.get("type") != "artifact":
        return {}
    files: list[tuple[str, str, int]] = []
    if manifest.get("layout") == "file":
        files.append((manifest.get("name", "content"), manifest["content"], manifest.get("size", 0)))
    elif manifest.get("layout") == "dir":
        tree = store.read_json(manifest["content"])
        files += [(e["path"], e["id"], e["size"]) for e in tree.get("entries", []) if "/" not in e["path"]]
    out: dict[str, Any] = {}
    for name, oid, size in files:
        if not name.endswith(".json") or size > METRICS_FILE_MAX:
            continue
        try:
            value = json.loads(store.read_bytes(oid))
        except (StoreError, ValueError):
            continue
        flat: dict[str, Any] = {}
        _flat("", value, flat)
        for k, v in flat.items():
            if isinstance(v, (int, float)) and not isinstance(v, bool) and len(out) < METRICS_PER_OUTPUT:
                out[f"{label}/{name}:{k}"] = v
    return out


def _run(store: Store, prefix: str) -> dict[str, str] | None:
    """A run: the step records under a ref prefix (e.g. workflow/quick), by the rest of the name."""
    refs = list_refs(store, prefix.rstrip("/") + "/")
    found = {}
    for name, oid in refs.items():
        try:
            if store.read_json(oid).get("type") == "step-record":
                found[name[len(prefix.rstrip("/")) + 1 :]] = oid
        except StoreError:
            continue
    return found or None


def diff(store: Store, a: str, b: str, show_all: bool = False) -> Diff:
    out = Diff(a=a, b=b)
    run_a, run_b = _run(store, a), _run(store, b)
    if run_a is not None and run_b is not None:
        out.only_a = sorted(set(run_a) - set(run_b))
        out.only_b = sorted(set(run_b) - set(run_a))
        for step in sorted(set(run_a) & set(run_b)):
            _compare(store, run_a[step], run_b[step], f"{step} ", out, show_all)
        return out
    if (run_a is None) != (run_b is None):
        run, other = (a, b) if run_a is not None else (b, a)
        raise StoreError(f"{quote(run)} is a run (a ref prefix) but {quote(other)} is not; compare like with like")
    _compare(store, resolve(store, a), resolve(store, b), "", out, show_all)
    return out


def _compare(store: Store, oid_a: str, oid_b: str, label: str, out: Diff, show_all: bool) -> None:
    fields_a, metrics_a = describe(store, oid_a)
    fields_b, metrics_b = describe(store, oid_b)
    for k in sorted(set(fields_a) | set(fields_b)):
        va, vb = fields_a.get(k), fields_b.get(k)
        if show_all or va != vb:
            out.fields[label + k] = [va, vb]
    for k in sorted(set(metrics_a) | set(metrics_b)):
        out.metrics[label + k] = [metrics_a.get(k), metrics_b.get(k)]
