"""Run a bench's cells: on Ray (an embedded local instance, or a cluster by address) or one after
another in this process. Finished cells are skipped; a failed cell is tried again up to the spec's
`retries`, then recorded as failed while the others go on.

    results = run_bench(spec, store, executor="ray", address=None, console=console)
    results = run_bench(spec, store, remote="team")   # nodes without the store: they share the remote

With a remote (the argument, else the spec's `remote`) the bench store's refs go to the remote first,
each cell runs on its node's own store (stages/bench/node_store.py), and a finished cell's refs are
pulled back here before it counts as done, so `bench status` and `bench report` read this store.

Order of submission: method by method, each over orderings and seeds. Cells of one method never
share a fine-tune (they differ in ordering or seed), so the cells running at the same time rarely
wait on each other's step locks; later methods then find every shared step already committed.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path

from artifacts.store import Store
from stages.bench.cell import CellJob, job_env, one_line, run_cell
from stages.bench.progress import BenchProgress
from stages.bench.spec import BenchSpec, Cell, workflow_data
from stages.bench.state import cell_states, is_done, record_outcome
from stages.errors import StageError

EXECUTORS = ("ray", "serial")
POLL_S = 0.5


@dataclass
class CellResult:
    cell: Cell
    state: str  # done | failed | skipped (finished before this run)
    tries: int = 0
    seconds: float = 0.0
    error: str | None = None
    steps_run: int = 0
    steps_cached: int = 0


def default_logs_dir(spec: BenchSpec) -> Path:
    return Path("runs") / "bench" / spec.name / "logs"


def make_job(
    spec: BenchSpec,
    store: Store,
    cell: Cell,
    logs: Path,
    remote: dict | None = None,
    node_store: str | None = None,
    credentials: dict | None = None,
) -> CellJob:
    return CellJob(
        store=str(Path(store.root).resolve()),
        workflow=workflow_data(cell),
        source=f"{spec.path} (cell {cell.name})",
        log=str((logs / f"{cell.name}.log").resolve()),
        cwd=os.getcwd(),
        env={**job_env(), **(credentials or {})},  # the remote's credentials: the worker's environment only
        remote=remote,
        node_store=node_store,
        tracking=str((logs.parent / "tracking").resolve()),  # beside logs/: runs/bench/<spec>/tracking
    )


def run_bench(
    spec: BenchSpec,
    store: Store,
    *,
    executor: str = "ray",
    address: str | None = None,
    num_cpus: int | None = None,
    retries: int | None = None,
    logs_dir: Path | None = None,
    console=None,
    cells: list[Cell] | None = None,
    remote: str | None = None,
    node_store: str | None = None,
) -> list[CellResult]:
    if executor not in EXECUTORS:
        raise StageError(f"--executor: must be one of {', '.join(EXECUTORS)} (got {executor!r})")
    remote = remote or spec.remote
    tries_allowed = 1 + (spec.retries if retries is None else retries)
    logs = Path(logs_dir) if logs_dir is not None else default_logs_dir(spec)
    cells = list(spec.cells if cells is None else cells)  # the spec's order: method-major
    results: dict[str, CellResult] = {}
    todo = []
    for c in cells:
        if is_done(store, c):
            results[c.name] = CellResult(c, "skipped")
        else:
            todo.append(c)
    target, credentials = None, None
    if remote is not None and todo:
        from stages.bench.node_store import collect, remote_target, share, worker_credentials

        target, credentials = remote_target(store, remote), worker_credentials(store, remote)
        share(store, remote)  # the nodes find this store's demos, policies and earlier cells there

    def job(cell: Cell) -> CellJob:
        return make_job(spec, store, cell, logs, target, node_store, credentials)

    progress = BenchProgress(spec, store, cells, console=console, skipped=len(cells) - len(todo))

    def finish(cell: Cell, tries: int, out: dict) -> bool:
        """Record a try's result; True when the cell is settled (done, or out of tries)."""
        if out["ok"] and target is not None:
            try:  # its results come back here before it counts as done
                collect(store, remote, cell.name)
            except Exception as exc:  # noqa: BLE001 - like any failed try: retried, then reported
                out = {**out, "ok": False, "error": f"pulling its results: {one_line(exc)}"}
        if out["ok"]:
            record_outcome(store, spec, cell, "done", tries=tries, seconds=out["seconds"])
            results[cell.name] = CellResult(
                cell, "done", tries, out["seconds"], None, out["steps_run"], out["steps_cached"]
            )
            progress.finished(cell, "done", out["seconds"], tries, steps=(out["steps_run"], out["steps_cached"]))
            return True
        if tries < tries_allowed:
            progress.retrying(cell, tries, tries_allowed, out["error"])
            return False
        record_outcome(store, spec, cell, "failed", tries=tries, seconds=out["seconds"], error=out["error"])
        results[cell.name] = CellResult(cell, "failed", tries, out["seconds"], out["error"])
        progress.finished(cell, "failed", out["seconds"], tries, error=out["error"])
        return True

    # Ray starts (and a cell too big for the cluster is refused) before the live display, so such an
    # error is the only line on stderr
    use_ray = executor == "ray" and bool(todo)
    with ray_session(address, num_cpus) if use_ray else contextlib.nullcontext() as ray:
        if use_ray:
            _check_feasible(ray, todo)
        with progress.live():
            if use_ray:
                _run_ray(ray, todo, job, finish, progress)
            elif todo:
                _run_serial(todo, job, finish, progress)
    return [results[c.name] for c in cells]


# ------------------------------------------------------------------------- in this process
def _run_serial(todo, job, finish, progress) -> None:
    for cell in todo:
        tries = 0
        while True:
            tries += 1
            progress.started(cell)
            out = run_cell(job(cell))
            if finish(cell, tries, out):
                break


# ------------------------------------------------------------------------- on Ray
START_ATTEMPTS = 3


def start_ray(address: str | None, num_cpus: int | None, attempts: int = START_ATTEMPTS) -> None:
    """Join the cluster at `address`, or start a quiet local instance sized to this machine (no dashboard,
    worker output kept in Ray's log files). Ray gives a local node 30 s to register, which an overloaded
    machine can miss: the start is tried `attempts` times before it becomes a one-line StageError."""
    import ray

    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    if address:
        check_reachable(address)
    for attempt in range(1, attempts + 1):
        try:
            if address:
                ray.init(address=address, log_to_driver=False, logging_level=logging.ERROR)
            else:
                ray.init(
                    num_cpus=num_cpus or os.cpu_count() or 1,
                    include_dashboard=False,
                    log_to_driver=False,
                    logging_level=logging.ERROR,
                )
            return
        except Exception as exc:  # noqa: BLE001 - Ray raises bare Exception for a node that timed out
            with contextlib.suppress(Exception):
                ray.shutdown()
            if address or attempt == attempts:
                where = f"join Ray at {address}" if address else f"start a local Ray instance ({attempts} tries)"
                raise StageError(
                    f"cannot {where}: {one_line(exc)}; on a busy machine try again, or run the "
                    "cells one after another with --serial"
                ) from None


def check_reachable(address: str, timeout_s: float = 5.0) -> None:
    """A HOST:PORT that nothing answers is one line now, not minutes of Ray retrying to reach its GCS."""
    import socket

    host, sep, port = address.rpartition(":")
    if not sep or not port.isdigit() or "/" in address:
        return  # "auto", "ray://...": left to Ray
    try:
        socket.create_connection((host, int(port)), timeout=timeout_s).close()
    except OSError as exc:
        raise StageError(
            f"--address {address}: nothing answers there ({exc.strerror or exc}); start the "
            "cluster's head with `ray start --head` or check the address"
        ) from None


@contextlib.contextmanager
def ray_session(address: str | None, num_cpus: int | None):
    """Ray for the bench's lifetime (start_ray); an already initialised session is reused, not shut down."""
    import ray

    if ray.is_initialized():
        yield ray
        return
    start_ray(address, num_cpus)
    try:
        yield ray
    finally:
        ray.shutdown()


def _check_feasible(ray, todo: list[Cell]) -> None:
    """A cell asking more than the whole cluster has would wait for ever: say so instead."""
    have = ray.cluster_resources()
    for cell in todo:
        need = {"CPU": cell.resources.num_cpus, "GPU": cell.resources.num_gpus, **cell.resources.custom}
        for name, amount in need.items():
            if amount > have.get(name, 0.0) + 1e-9:
                raise StageError(
                    f"cell {cell.name} needs {amount:g} {name} but the Ray cluster has "
                    f"{have.get(name, 0.0):g} (set resources in the spec, or join a bigger cluster)"
                )


def _run_ray(ray, todo, job, finish, progress) -> None:
    remote = ray.remote(max_retries=0)(run_cell)
    flight: dict = {}

    def submit(cell: Cell, tries: int) -> None:
        ref = remote.options(**cell.resources.ray_options()).remote(job(cell))
        flight[ref] = (cell, tries, time.monotonic())
        progress.submitted(cell)

    for cell in todo:
        submit(cell, 1)
    while flight:
        ready, _ = ray.wait(list(flight), num_returns=1, timeout=POLL_S)
        progress.poll()
        for ref in ready:
            cell, tries, t0 = flight.pop(ref)
            try:
                out = ray.get(ref)
            except Exception as exc:  # noqa: BLE001 - a lost worker (crash, OOM kill) fails the try
                out = {
                    "ok": False,
                    "error": f"Ray task lost: {one_line(exc)}",
                    "seconds": time.monotonic() - t0,
                    "steps_run": 0,
                    "steps_cached": 0,
                }
            if not finish(cell, tries, out):
                submit(cell, tries + 1)


def summary_rows(results: list[CellResult]) -> list[dict]:
    return [
        {
            "cell": r.cell.name,
            "method": r.cell.method,
            "ordering": r.cell.ordering,
            "seed": r.cell.seed,
            "state": r.state,
            "tries": r.tries,
            "seconds": round(r.seconds, 1),
            "error": r.error,
            "steps_run": r.steps_run,
            "steps_cached": r.steps_cached,
        }
        for r in results
    ]


__all__ = ["run_bench", "ray_session", "start_ray", "CellResult", "EXECUTORS", "cell_states", "summary_rows"]
