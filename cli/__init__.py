"""Command-line interface. Each group of commands registers itself from its own module."""

from __future__ import annotations

import importlib

import typer

# module name -> function register(app) it exports. A module that does not exist yet is skipped,
# so command groups can land one at a time.
_COMMAND_MODULES = [
    "cli.store_cmds",  # init, log, show, lineage, verify, gc, add
    "cli.stage_cmds",  # stage run/status, run, report
    "cli.run_cmds",  # run WORKFLOW (every stage)
    "cli.sim_cmds",  # sim tasks/demos/watch
    "cli.policy_cmds",  # policy finetune/chunk
    "cli.metrics_cmds",  # metrics FILE.json
    "cli.report_cmds",  # report WORKFLOW
    "cli.bench_cmds",  # bench SPEC / bench status / bench report
    "cli.remote_cmds",  # remote add/list/remove, push, fetch, pull
    "cli.sync_cmds",  # clone, status
    "cli.diff_cmds",  # diff A B
    "cli.robot_cmds",  # robot learner (the learner of a hardware stage on a second host)
]


def register_commands(app: typer.Typer) -> None:
    for name in _COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:
                continue
            raise
        module.register(app)
    # Plain click help everywhere: typer's rich help formatter costs ~0.5 s of imports per call.
    for group in app.registered_groups:
        if group.typer_instance is not None:
            group.typer_instance.rich_markup_mode = None
