"""Stage commands: `accrue stage run` and `accrue stage status`.

`stage run` asks stages.plan.plan_stage(workflow, k, store) for the stage's step invocations and
hands them to the runner; until the step bodies are installed it says so and stops.
"""

from __future__ import annotations

import contextlib
import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from cli.store_cmds import JsonOpt, StoreOpt, console, open_store, print_json

stage_app = typer.Typer(help="Run and inspect the steps of one stage of a workflow.", no_args_is_help=True)

WorkflowArg = Annotated[Path, typer.Argument(metavar="WORKFLOW", help="Workflow YAML file.", show_default=False)]


def run_mode(cont: bool, rerun: bool) -> str:
    """The runner mode the --continue/--rerun flags ask for (they exclude each other)."""
    from stages.errors import StageError

    if cont and rerun:
        raise StageError("--continue and --rerun exclude each other: continue resumes, rerun starts over")
    return "continue" if cont else "rerun" if rerun else "normal"


@contextlib.contextmanager
def session_stops():
    """A robot step stopped by Ctrl-C or SIGTERM (stages.steps.robot_session.SessionStop): its one line
    on stderr and exit 130 / 143; the session is already closed and the robot disconnected."""
    from stages.steps.robot_session import SessionStop

    try:
        yield
    except SessionStop as stop:
        print(str(stop), file=sys.stderr)
        raise typer.Exit(stop.code) from None


def load_plan_function():
    """stages.plan.plan_stage, or a one-line StageError if the step bodies are not installed."""
    import importlib

    from stages.errors import StageError

    try:
        module = importlib.import_module("stages.plan")
    except ModuleNotFoundError as exc:
        if exc.name == "stages.plan":
            raise StageError(
                "the step bodies are not installed (stages/plan.py is missing): this build "
                "can validate workflows and manage the store, but cannot run stages"
            ) from None
        raise
    if not hasattr(module, "plan_stage"):
        raise StageError("stages/plan.py does not define plan_stage(workflow, stage, store)")
    return module.plan_stage


@stage_app.command("run")
def run(
    workflow: WorkflowArg,
    stage: Annotated[int, typer.Option("--stage", help="Stage number k (1-based).", show_default=False)],
    step: Annotated[
        Optional[str], typer.Option("--step", help="Run this step (after the steps it needs, usually cached) and stop.")
    ] = None,
    cont: Annotated[
        bool, typer.Option("--continue", help="Resume an interrupted step from its last checkpoint.")
    ] = False,
    rerun: Annotated[
        bool, typer.Option("--rerun", help="Run the step(s) again from scratch, ignoring caches.")
    ] = False,
    wait: Annotated[bool, typer.Option("--wait", help="If another process runs the same step, wait for it.")] = False,
    store: StoreOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Run stage K of WORKFLOW: finished steps are no-ops, interrupted ones need --continue or --rerun."""
    from stages.runner import Runner
    from stages.workflow import load_workflow

    mode = run_mode(cont, rerun)
    wf = load_workflow(workflow)
    wf.check_stage(stage)
    st = open_store(store)
    if wf.robot is not None:  # the robot, its keys, the base policy's inputs, the learner: before any step
        from stages.steps.robot_preflight import preflight

        preflight(wf, str(workflow), st, (1, stage))
        if wf.robot.learner_address is None and step in (None, "train"):  # warmup starts train's learner
            from accrue.robot.learner_client import start_learner_ahead

            start_learner_ahead()
    plan_stage = load_plan_function()
    plan = plan_stage(wf, stage, st)
    runner = Runner(st, console=console() if not as_json else None, wait=wait)
    with session_stops():
        results = runner.run_plan(plan, only_step=step, mode=mode)
    if as_json:
        print_json(
            [
                {"step": r.step, "cached": r.cached, "record": r.record_id, "attempt": r.attempt, "outputs": r.outputs}
                for r in results
            ]
        )


@stage_app.command("status")
def status(workflow: WorkflowArg, store: StoreOpt = None, as_json: JsonOpt = False) -> None:
    """The state of every step of every stage of WORKFLOW."""
    from rich.table import Table

    from stages.runner_status import workflow_status
    from stages.workflow import load_workflow

    wf = load_workflow(workflow)
    rows = workflow_status(open_store(store), wf)
    if as_json:
        if wf.robot is not None:  # a workflow with a robot: {"steps": [...], "hardware": sessions per step}
            from stages.steps.robot_status import robot_status

            print_json({"steps": rows, "hardware": robot_status(open_store(store), wf)})
        else:
            print_json(rows)
        return
    table = Table(title=f"workflow {wf.name} ({wf.method}, {wf.num_stages} stages)", title_justify="left")
    for col in ("stage", "task", "step", "state", "started", "took", "host", "record / detail"):
        table.add_column(col, overflow="fold")
    colours = {"committed": "green", "running": "cyan", "failed": "red", "abandoned": "yellow", "not run": "dim"}
    for r in rows:
        table.add_row(
            str(r["stage"]),
            r["task"],
            r["step"],
            f"[{colours.get(r['state'], 'white')}]{r['state']}[/]",
            _when(r["started"]),
            _took(r["duration_s"]),
            r["host"] or "",
            r["detail"],
        )
    console().print(table)
    if wf.robot is not None:  # a workflow with a robot: sessions, running success, robot time, stop rule
        from cli.hw_status_view import print_hardware_status

        print_hardware_status(open_store(store), wf)


def _when(stamp: str | None) -> str:
    """2026-12-02T07:38:12.345+00:00 -> 2026-12-02 07:38:12 (the store writes UTC)."""
    return stamp[:19].replace("T", " ") if stamp else ""


def _took(seconds: float | None) -> str:
    from stages.steps.common import took_text

    return "" if seconds is None else took_text(seconds)


def register(app: typer.Typer) -> None:
    app.add_typer(stage_app, name="stage")
