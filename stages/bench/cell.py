"""One bench cell: an ordinary workflow run, every stage in order, through the same planner and runner
as `accrue run` — in a Ray worker or in the bench's own process.

    result = run_cell(CellJob(...))     # {"ok", "error", "seconds", "steps_run", "steps_cached"}; never raises

The runner waits (wait=True) when another cell holds a step's lock, so two cells that need the same
fine-tune compute it once: the second finds the first's committed result when the lock frees. Steps
run in `continue` mode: an attempt cut off by a killed bench resumes from its last checkpoint.
The step output goes to the cell's log file, not to the bench's terminal; its scalars (accrue.tracking)
go to <tracking>/<cell>/ (beside the logs: runs/bench/<spec>/tracking/<cell>/stage-<k>/train and
.../<cell>/cell), so `tensorboard --logdir runs/bench/<spec>/tracking` compares the cells.

With a remote (`accrue bench run --remote NAME`) the cell runs on the node's own store instead
(stages/bench/node_store.py): it pulls the remote's refs and step records first, fetches the data
its steps read, and pushes its workflow's refs when done (after a failure too, what it committed).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import time
import traceback
from dataclasses import dataclass, field, replace
from pathlib import Path

# environment a worker takes over from the bench process (offline hubs, headless GL, thread counts)
ENV_PREFIXES = ("ACCRUE_", "HF_", "TRANSFORMERS_", "MUJOCO_", "RERUN", "OMP_", "MKL_")


@dataclass(frozen=True)
class CellJob:
    store: str  # absolute store path (a shared filesystem on a cluster); unused with a remote
    workflow: dict  # the cell's validated workflow as JSON (stages.bench.spec.workflow_data)
    source: str  # where it came from, for error messages
    log: str  # the cell's log file (appended)
    cwd: str  # the bench's working directory (relative paths in workflows)
    env: dict = field(default_factory=dict, repr=False)  # may hold the remote's credentials: never shown
    remote: dict | None = None  # node_store.remote_target: the cell runs on the node's own store
    node_store: str | None = None  # that store's path on the node ({host}, {node} filled in there)
    tracking: str | None = None  # the bench's tracking directory (runs/bench/<spec>/tracking)


def job_env() -> dict:
    return {k: v for k, v in os.environ.items() if k.startswith(ENV_PREFIXES)}


def one_line(exc: BaseException) -> str:
    from accrue.errors import AccrueError
    from artifacts.errors import StoreError
    from stages.errors import StageError

    text = (str(exc).strip().splitlines() or [""])[0]
    return text if isinstance(exc, (AccrueError, StoreError, StageError)) else f"{type(exc).__name__}: {text}"


def run_cell(job: CellJob) -> dict:
    started = time.monotonic()
    with (
        open(log_path(job), "a", encoding="utf-8") as log,
        contextlib.redirect_stdout(log),
        contextlib.redirect_stderr(log),
    ):
        try:
            run, cached = _run_stages(job, log)
            return {
                "ok": True,
                "error": None,
                "seconds": time.monotonic() - started,
                "steps_run": run,
                "steps_cached": cached,
            }
        except BaseException as exc:  # noqa: BLE001 - a cell's failure is data for the bench, not a crash
            if isinstance(exc, KeyboardInterrupt):
                raise
            log.write(traceback.format_exc())
            return {
                "ok": False,
                "error": one_line(exc),
                "seconds": time.monotonic() - started,
                "steps_run": 0,
                "steps_cached": 0,
            }


def tracking_root(job: CellJob) -> Path | None:
    """The bench's tracking directory, or, on a node that cannot write there, its temporary directory's."""
    if job.tracking is None:
        return None
    path = Path(job.tracking)
    try:
        path.mkdir(parents=True, exist_ok=True)
        if os.access(path, os.W_OK):
            return path
    except OSError:
        pass
    return Path(tempfile.gettempdir()) / "accrue-bench-tracking" / path.parent.name


def log_path(job: CellJob) -> Path:
    """The bench's log path, or, on a node that cannot write there (no shared filesystem), the same
    name in the node's temporary directory."""
    path = Path(job.log)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        if os.access(path.parent, os.W_OK):
            return path
    except OSError:
        pass
    fallback = Path(tempfile.gettempdir()) / "accrue-bench-logs" / path.name
    fallback.parent.mkdir(parents=True, exist_ok=True)
    return fallback


def _run_stages(job: CellJob, log) -> tuple[int, int]:
    from rich.console import Console

    from accrue.tracking import open_tracker
    from artifacts.store import Store
    from stages.plan import plan_stage
    from stages.runner import Runner
    from stages.steps.train import bind_tracking
    from stages.workflow import parse_workflow

    os.environ.update(job.env)
    if Path(job.cwd).is_dir():  # on another node the bench's directory may not exist
        os.chdir(job.cwd)
    wf = parse_workflow(job.workflow, job.source)
    console = Console(file=log, width=120, force_terminal=False, highlight=False)
    console.rule(f"cell {wf.name} ({wf.method}, seed {wf.seed}): {' → '.join(wf.tasks)}")
    if job.remote is None:
        store = Store.open(Path(job.store))
    else:
        from stages.bench.node_store import DEFAULT_NODE_STORE, open_node_store, sync_in

        store = open_node_store(job.node_store or DEFAULT_NODE_STORE, job.remote)
        sync_in(store, job.remote)
        console.print(f"node store {store.root}: refs and step records pulled from remote {job.remote['name']}")
    runner = Runner(store, console=console, wait=True)
    run = cached = 0
    root = tracking_root(job)
    started = time.monotonic()
    try:
        for k in range(1, wf.num_stages + 1):
            plan = plan_stage(wf, k, store)
            plan = replace(plan, steps=bind_tracking(plan.steps, wf.tracking, wf.name, root and str(root)))
            for r in runner.run_plan(plan, mode="continue"):
                run, cached = run + (not r.cached), cached + r.cached
        if root is not None:  # the cell as a whole, one point: what it cost this try
            with open_tracker(
                wf.tracking,
                root / wf.name / "cell",
                f"{wf.name}/cell",
                warn=lambda line: console.print(f"warning: {line}", markup=False),
            ) as tracker:
                seconds = time.monotonic() - started
                tracker.scalars({"cell/seconds": seconds, "cell/steps_run": run, "cell/steps_cached": cached}, k)
    except BaseException:
        if job.remote is not None:  # what it committed lets a retry on any node go on from there
            with contextlib.suppress(Exception):
                _push_results(store, job, wf.name, console)
        raise
    if job.remote is not None:
        _push_results(store, job, wf.name, console)
    return run, cached


def _push_results(store, job: CellJob, workflow: str, console) -> None:
    from stages.bench.node_store import sync_out

    sync_out(store, job.remote, workflow)
    console.print(f"pushed workflow/{workflow} to remote {job.remote['name']}")
