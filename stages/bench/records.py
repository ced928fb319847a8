"""Cell records: one JSON file per finished bench cell with what the report needs from it, so results
outlive the store they were measured in (only git survives a change of machine).

    record = store_record(spec, cell, run_record, curves, artifacts, store_root)   # from a done store cell
    record = report_row_record(spec_name, row, tasks, threshold, provenance)       # from a committed report row
    recorded = load_records(directory, spec)       # validated; StageError naming the file when one is bad
    written = write_records(directory, records)    # <directory>/<cell name>.json, deterministic JSON

A record holds the cell's run_record (method, ordering, seed, tasks, metrics, disjoint_report, and from a
store also per_stage, c and best_checkpoint), its stage curves (None when they were not kept: a record
made from a committed report) and its provenance: where it was read from (store artifacts and path, or
the report file and its commit), the host and its CPU, the git commit of the checkout that wrote the
record (the store keeps no commit for the code that ran the cell) and when it was written. The cell name
carries the hash of the cell's workflow, so a record is never taken for a cell of a changed workflow:
a record whose cell is not in the spec is ignored (and listed), one that names a cell of the spec but
disagrees with it (method, ordering, seed, tasks, success threshold) is an error.
"""

from __future__ import annotations

import json
import math
import os
import platform
import socket
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

from accrue.metrics import METRICS
from artifacts.clock import now_iso
from stages.bench.spec import BenchSpec, Cell
from stages.errors import StageError

RECORD_TYPE = "accrue-bench-cell-record"
RECORD_VERSION = 1
ROOT = Path(__file__).resolve().parents[2]
# provenance fields that change on every refresh without the measurement changing
VOLATILE = ("written", "git_commit")


@dataclass
class Recorded:
    """The valid records of a spec's cells in one directory, and the files that are not this spec's."""

    directory: Path
    by_cell: dict[str, dict] = field(default_factory=dict)  # cell name -> record
    files: dict[str, Path] = field(default_factory=dict)  # cell name -> its file
    ignored: list[dict] = field(default_factory=list)  # {"file", "spec", "cell"}: not a cell of the spec


def code_commit() -> str | None:
    """The git commit of this checkout, or None where git or the repository is not there."""
    try:
        out = subprocess.run(
            ["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10, check=False
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return (out.stdout.strip() or None) if out.returncode == 0 else None


def cpu_description(cpuinfo: Path = Path("/proc/cpuinfo")) -> str:
    """The CPU a cell ran on, e.g. "AMD EPYC (x86_64, family 26 model 2, 2 cores)": float results of the
    same cell differ between CPUs, so a record names it (host names of cloud machines say nothing)."""
    fields: dict[str, str] = {}
    try:
        for line in cpuinfo.read_text(encoding="utf-8", errors="replace").splitlines():
            key, sep, value = line.partition(":")
            if sep and key.strip() in ("model name", "cpu family", "model") and key.strip() not in fields:
                fields[key.strip()] = value.strip()
    except OSError:  # not Linux: platform's words are all there is
        pass
    name = fields.get("model name") or platform.processor() or "unknown CPU"
    detail = [platform.machine() or "unknown architecture"]
    if "cpu family" in fields and "model" in fields:
        detail.append(f"family {fields['cpu family']} model {fields['model']}")
    detail.append(f"{os.cpu_count() or '?'} cores")
    return f"{name} ({', '.join(detail)})"


def store_record(
    spec: BenchSpec, cell: Cell, run_record: dict, curves: list[dict], artifacts: list[dict], store_root: str
) -> dict:
    """The record of a done store cell; `artifacts`: per stage, the train step record and curve artifact
    ids its curves were read from."""
    return {
        "type": RECORD_TYPE,
        "version": RECORD_VERSION,
        "spec": spec.name,
        "cell": cell.name,
        "success_threshold": spec.success_threshold,
        "run_record": run_record,
        "stage_curves": curves,
        "provenance": {
            "source": "store",
            "store": store_root,
            "artifacts": artifacts,
            "host": socket.gethostname(),
            "cpu": cpu_description(),
            "git_commit": code_commit(),
            "written": now_iso(),
        },
    }


def report_row_record(spec_name: str, row: dict, tasks: list[str], threshold: float, provenance: dict) -> dict:
    """The record of one done row of a committed report.json (metrics only: a report keeps no per-cell
    curves)."""
    return {
        "type": RECORD_TYPE,
        "version": RECORD_VERSION,
        "spec": spec_name,
        "cell": row["cell"],
        "success_threshold": threshold,
        "run_record": {
            "method": row["method"],
            "ordering": row["ordering"],
            "seed": row["seed"],
            "tasks": list(tasks),
            "metrics": row["metrics"],
            "disjoint_report": row.get("disjoint_report"),
        },
        "stage_curves": None,
        "provenance": {"source": "report", **provenance, "written": now_iso()},
    }


def record_text(record: dict) -> str:
    """Deterministic JSON: sorted keys, two-space indent, one trailing newline."""
    return json.dumps(record, sort_keys=True, indent=2, allow_nan=False) + "\n"


def provenance_label(record: dict) -> str:
    """Where a record's measurement came from, in words (records of one origin share a label)."""
    p = record["provenance"]
    commit = (p.get("git_commit") or p.get("report_commit") or "")[:12] or "commit unknown"
    if p.get("source") == "report":
        return f"{p.get('report')} at {commit} ({p.get('note') or 'store not available'})"
    cpu = f" ({p['cpu']})" if p.get("cpu") else ""
    return f"store {p.get('store')} on {p.get('host') or 'an unknown host'}{cpu}, code at {commit}"


def _same_measurement(a: dict, b: dict) -> bool:
    def strip(r):
        return {**r, "provenance": {k: v for k, v in r["provenance"].items() if k not in VOLATILE}}

    return strip(a) == strip(b)


def write_records(directory: Path, records: list[dict]) -> list[Path]:
    """Write each record to <directory>/<cell>.json; a file that already holds the same measurement is
    left as it is (its time and commit stay those of when it was measured). Returns the files written."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    written = []
    for record in records:
        path = directory / f"{record['cell']}.json"
        try:
            old = json.loads(path.read_text(encoding="utf-8")) if path.exists() else None
        except (OSError, ValueError):
            old = None
        if isinstance(old, dict) and isinstance(old.get("provenance"), dict) and _same_measurement(old, record):
            continue
        try:
            text = record_text(record)
        except ValueError as exc:  # a NaN or infinity: JSON cannot hold it, and no reader could compare it
            raise StageError(f"{path}: cell {record['cell']} cannot be recorded ({exc})") from None
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(text, encoding="utf-8")
        tmp.replace(path)
        written.append(path)
    return written


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _numbers(value) -> bool:
    return isinstance(value, list) and bool(value) and all(_number(v) for v in value)


def _check_curves(curves, where: str) -> None:
    if curves is None:
        return
    if not isinstance(curves, list) or not curves:
        raise StageError(f"{where}: stage_curves must be a non-empty list or null")
    for k, stage in enumerate(curves, start=1):
        ok = isinstance(stage, dict) and _numbers(stage.get("grid")) and _numbers(stage.get("current"))
        earlier = stage.get("earlier") if isinstance(stage, dict) else None
        if ok:
            ok = len(stage["current"]) == len(stage["grid"]) and (
                earlier is None or (_numbers(earlier) and len(earlier) == len(stage["grid"]))
            )
        if not ok:
            raise StageError(f"{where}: stage_curves[{k}] needs grid, current (and earlier or null) of equal length")


def _check_shape(record, where: str) -> None:
    """The fields build_report reads, with their types; StageError naming the first one that is wrong."""
    if not isinstance(record, dict) or record.get("type") != RECORD_TYPE:
        raise StageError(f'{where}: not a bench cell record (no "type": "{RECORD_TYPE}")')
    if record.get("version") != RECORD_VERSION:
        raise StageError(f"{where}: record version {record.get('version')!r}, this code reads {RECORD_VERSION}")
    for key in ("spec", "cell"):
        if not isinstance(record.get(key), str) or not record[key]:
            raise StageError(f"{where}: {key} must be a non-empty string")
    if not _number(record.get("success_threshold")):
        raise StageError(f"{where}: success_threshold must be a number")
    if not isinstance(record.get("provenance"), dict):
        raise StageError(f"{where}: provenance must be an object")
    rr = record.get("run_record")
    if not isinstance(rr, dict):
        raise StageError(f"{where}: run_record must be an object")
    if not isinstance(rr.get("method"), str) or not isinstance(rr.get("ordering"), str):
        raise StageError(f"{where}: run_record.method and run_record.ordering must be strings")
    if not isinstance(rr.get("seed"), int) or isinstance(rr.get("seed"), bool):
        raise StageError(f"{where}: run_record.seed must be an integer")
    if not isinstance(rr.get("tasks"), list) or not all(isinstance(t, str) for t in rr["tasks"]):
        raise StageError(f"{where}: run_record.tasks must be a list of task ids")
    metrics = rr.get("metrics")
    if not isinstance(metrics, dict):
        raise StageError(f"{where}: run_record.metrics must be an object")
    for name, value in metrics.items():
        if name not in METRICS:
            raise StageError(f"{where}: run_record.metrics has unknown metric {name!r}")
        if value is not None and not _number(value):
            raise StageError(f"{where}: run_record.metrics.{name} must be a number or null (got {value!r})")
    if rr.get("disjoint_report") not in (True, False, None):
        raise StageError(f"{where}: run_record.disjoint_report must be true, false or null")
    _check_curves(record.get("stage_curves"), where)


def _check_against_cell(record: dict, spec: BenchSpec, cell: Cell, where: str) -> None:
    rr = record["run_record"]
    want = {"spec": spec.name, "method": cell.method, "ordering": cell.ordering, "seed": cell.seed}
    got = {"spec": record["spec"], "method": rr["method"], "ordering": rr["ordering"], "seed": rr["seed"]}
    for key, value in want.items():
        if got[key] != value:
            raise StageError(f"{where}: {key} {got[key]!r}, but the spec's cell {cell.name} has {value!r}")
    if rr["tasks"] != cell.tasks:
        raise StageError(f"{where}: tasks {rr['tasks']}, but the spec's cell {cell.name} runs {cell.tasks}")
    if record["success_threshold"] != spec.success_threshold:
        raise StageError(
            f"{where}: measured with success threshold {record['success_threshold']}, the spec says "
            f"{spec.success_threshold} (T_thr would not compare)"
        )


def load_records(directory: Path, spec: BenchSpec) -> Recorded:
    """Every <cell>.json in `directory` (none yet: an empty set), checked; a record whose cell is not one
    of the spec's (another spec, a changed workflow) is ignored and listed."""
    directory = Path(directory)
    out = Recorded(directory)
    if not directory.exists():
        return out
    if not directory.is_dir():
        raise StageError(f"--records {directory}: not a directory")
    cells = {c.name: c for c in spec.cells}
    for path in sorted(directory.glob("*.json")):
        where = str(path)
        try:
            record = json.loads(path.read_text(encoding="utf-8"))
        except OSError as exc:
            raise StageError(f"{where}: cannot read ({exc.__class__.__name__})") from None
        except ValueError as exc:
            raise StageError(f"{where}: not valid JSON ({exc})") from None
        _check_shape(record, where)
        if path.stem != record["cell"]:
            raise StageError(f"{where}: holds the record of cell {record['cell']}; its file must be named after it")
        cell = cells.get(record["cell"])
        if cell is None:
            out.ignored.append({"file": where, "spec": record["spec"], "cell": record["cell"]})
            continue
        _check_against_cell(record, spec, cell, where)
        out.by_cell[cell.name] = record
        out.files[cell.name] = path
    return out


def metric_differences(store_record_: dict, record: dict) -> dict:
    """{metric: {"store", "record"}} for every metric (and disjoint_report) where the two disagree."""
    a, b = store_record_["run_record"], record["run_record"]
    out = {}
    for name in METRICS:
        if a["metrics"].get(name) != b["metrics"].get(name):
            out[name] = {"store": a["metrics"].get(name), "record": b["metrics"].get(name)}
    if a.get("disjoint_report") != b.get("disjoint_report"):
        out["disjoint_report"] = {"store": a.get("disjoint_report"), "record": b.get("disjoint_report")}
    return out
