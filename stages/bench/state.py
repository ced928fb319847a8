"""Where each cell of a bench stands, read from the store alone (no Ray, no live process needed).

    states = cell_states(store, spec)             # {cell name: CellState}
    record_outcome(store, spec, cell, "failed", tries=2, seconds=31.0, error="...")

A cell is
    done      every step of every stage has its ref (workflow/<cell>/stage/<k>/<step>)
    running   one of its steps has a live attempt (the step's kernel lock is held)
    failed    its last outcome says so and nothing of it started since
    partial   some steps committed or an attempt was cut off, nothing running (re-running resumes it)
    pending   nothing yet
Outcomes are small JSON objects under the ref bench/<spec>/<cell> (one writer: the bench driver), so
a failure that happened before any step started (a missing input, a crashed worker) is kept too.
"""

from __future__ import annotations

import socket
from dataclasses import dataclass

from artifacts.manifests import now_iso
from artifacts.records import list_attempts
from artifacts.refs import read_ref, set_ref
from artifacts.store import Store
from stages.bench.spec import BenchSpec, Cell
from stages.runner import reap_abandoned, step_ref
from stages.runner_types import STEP_NAMES

STATES = ("done", "running", "failed", "partial", "pending")


@dataclass
class CellState:
    state: str
    stages_done: int = 0  # stages whose every step has committed
    running_step: str | None = None
    error: str | None = None
    tries: int = 0
    seconds: float | None = None  # wall time of the cell's last finished run (from its outcome)


def outcome_ref(spec: BenchSpec, cell: Cell) -> str:
    return f"bench/{spec.name}/{cell.name}"


def read_outcome(store: Store, spec: BenchSpec, cell: Cell) -> dict | None:
    oid = read_ref(store, outcome_ref(spec, cell))
    return None if oid is None else store.read_json(oid)


def record_outcome(
    store: Store, spec: BenchSpec, cell: Cell, state: str, *, tries: int, seconds: float, error: str | None = None
) -> None:
    oid = store.put_json(
        {
            "type": "bench-cell",
            "spec": spec.name,
            "cell": cell.name,
            "method": cell.method,
            "ordering": cell.ordering,
            "seed": cell.seed,
            "state": state,
            "tries": tries,
            "seconds": round(seconds, 3),
            "error": error,
            "finished": now_iso(),
            "host": socket.gethostname(),
        }
    )
    set_ref(store, outcome_ref(spec, cell), oid)


def stages_committed(store: Store, cell: Cell) -> int:
    """How many leading stages of the cell have every runner step committed."""
    for k in range(1, cell.workflow.num_stages + 1):
        if any(read_ref(store, step_ref(cell.name, k, s)) is None for s in STEP_NAMES):
            return k - 1
    return cell.workflow.num_stages


def is_done(store: Store, cell: Cell) -> bool:
    return stages_committed(store, cell) == cell.workflow.num_stages


def cell_states(store: Store, spec: BenchSpec, cells: list[Cell] | None = None) -> dict[str, CellState]:
    cells = spec.cells if cells is None else cells
    names = {c.name for c in cells}
    attempts: dict[str, list[dict]] = {}
    for a in list_attempts(store, problems=[]):
        if a.get("workflow") in names:
            attempts.setdefault(a["workflow"], []).append(a)
    for key in {a["cache_key"] for group in attempts.values() for a in group if a["state"] == "running"}:
        if reap_abandoned(store, key):  # a dead process's attempt is abandoned on the next look
            for group in attempts.values():
                for a in group:
                    if a["cache_key"] == key and a["state"] == "running":
                        a["state"] = "abandoned"
    out = {}
    for cell in cells:
        done = stages_committed(store, cell)
        outcome = read_outcome(store, spec, cell)
        mine = sorted(attempts.get(cell.name, []), key=lambda a: a.get("started", ""))
        st = CellState(
            "pending", stages_done=done, tries=(outcome or {}).get("tries", 0), seconds=(outcome or {}).get("seconds")
        )
        running = [a for a in mine if a["state"] == "running"]
        last_start = mine[-1].get("started", "") if mine else ""
        if done == cell.workflow.num_stages:
            st.state = "done"
        elif running:
            st.state, st.running_step = "running", f"stage {running[-1].get('stage')} {running[-1]['step']}"
        elif outcome is not None and outcome["state"] == "failed" and outcome.get("finished", "") >= last_start:
            st.state, st.error = "failed", outcome.get("error")
        elif mine or done:
            st.state = "partial"
        out[cell.name] = st
    return out


def counts(states: dict[str, CellState]) -> dict[str, int]:
    return {s: sum(1 for c in states.values() if c.state == s) for s in STATES}


def eta_seconds(states: dict[str, CellState]) -> float | None:
    """Rough time left: the mean wall time of the finished cells (from their outcomes) times the cells
    left, over the cells running now (at least one). None before any cell has finished."""
    times = [c.seconds for c in states.values() if c.state == "done" and c.seconds]
    if not times:
        return None
    left = sum(1 for c in states.values() if c.state in ("pending", "partial", "running"))
    running = max(1, sum(1 for c in states.values() if c.state == "running"))
    return sum(times) / len(times) * left / running
