"""`accrue run WORKFLOW`: every stage of a workflow, in order, over the store.

Committed steps are no-ops, so the command resumes after any interruption: run it again (with
--continue when a step was cut off mid-way, to resume it from its last checkpoint).
"""

from __future__ import annotations

import contextlib
import sys
import time
from pathlib import Path
from typing import Annotated, Optional

import typer

from cli.stage_cmds import run_mode, session_stops
from cli.store_cmds import JsonOpt, StoreOpt, console, open_store, print_json

WorkflowArg = Annotated[Path, typer.Argument(metavar="WORKFLOW", help="Workflow YAML file.", show_default=False)]


def run(
    workflow: WorkflowArg,
    budget: Annotated[
        Optional[str],
        typer.Option(
            "--budget",
            metavar="FRACTION_OR_STEPS",
            help="Scale each stage's env-step budget (0.01) or set it (5000); the eval grid scales alike.",
        ),
    ] = None,
    stages: Annotated[
        Optional[str], typer.Option("--stages", metavar="A-B", help="Run only these stages, e.g. 1-2 (default: all).")
    ] = None,
    cont: Annotated[
        bool, typer.Option("--continue", help="Resume interrupted steps from their last checkpoint.")
    ] = False,
    rerun: Annotated[bool, typer.Option("--rerun", help="Run every step again from scratch, ignoring caches.")] = False,
    wait: Annotated[bool, typer.Option("--wait", help="If another process runs the same step, wait for it.")] = False,
    store: StoreOpt = None,
    as_json: JsonOpt = False,
) -> None:
    """Run every stage of WORKFLOW (finished steps are skipped; interrupted ones need --continue or --rerun)."""
    from stages.plan import apply_budget, plan_stage
    from stages.runner import Runner
    from stages.workflow import load_workflow

    mode = run_mode(cont, rerun)
    wf = apply_budget(load_workflow(workflow), budget)
    first, last = parse_stages(stages, wf.num_stages)
    st = open_store(store)
    if wf.robot is not None:  # the robot, its keys, the base policy's inputs, the learner: before any step
        from stages.steps.robot_preflight import preflight

        preflight(wf, str(workflow), st, (1, last))
        if wf.robot.learner_address is None:  # warmup starts train's learner, so it is up when train begins
            from accrue.robot.learner_client import start_learner_ahead

            start_learner_ahead()
    out = console()
    runner = Runner(st, console=out if not as_json else None, wait=wait)
    started, summary = time.monotonic(), []
    with contextlib.redirect_stdout(sys.stderr) if as_json else contextlib.nullcontext(), session_stops():
        for k in range(first, last + 1):  # with --json, stdout carries the JSON summary only
            if not as_json:
                out.rule(f"workflow {wf.name} · stage {k}/{wf.num_stages} · {wf.task(k)}")
            results = runner.run_plan(plan_stage(wf, k, st), mode=mode)
            summary += [
                {"stage": k, "step": r.step, "cached": r.cached, "record": r.record_id, "outputs": r.outputs}
                for r in results
            ]
    if as_json:
        print_json(summary)
    else:
        done = sum(not r["cached"] for r in summary)
        out.print(
            f"workflow {wf.name}: stages {first}-{last} done ({done} steps run, "
            f"{len(summary) - done} cached) in {time.monotonic() - started:.0f} s"
        )
        out.print(report_line(wf, workflow, st), soft_wrap=True)


def report_line(wf, workflow: Path, store) -> str:
    """What `accrue report` makes of the run, and where: the line `accrue run` ends with."""
    from stages.report.build import FILES, default_out_dir

    if wf.robot is not None:
        from stages.report.hardware import INTERVENTIONS_FILE, REPORT_FILES

        names = [*REPORT_FILES.values(), *([INTERVENTIONS_FILE] if wf.robot.intervention is not None else [])]
    else:
        names = list(FILES.values())
    return f"report: `accrue report {workflow}` writes {default_out_dir(wf, store)}/: {', '.join(names)}"


def parse_stages(text: str | None, num_stages: int) -> tuple[int, int]:
    from stages.errors import StageError

    if text is None:
        return 1, num_stages
    a, _, b = text.partition("-")
    try:
        first, last = int(a), int(b or a)
    except ValueError:
        raise StageError(f"--stages: expected A-B or K (got {text!r})") from None
    if not 1 <= first <= last <= num_stages:
        raise StageError(f"--stages: must lie within 1-{num_stages} (got {text!r})")
    return first, last


def register(app: typer.Typer) -> None:
    app.command("run")(run)
