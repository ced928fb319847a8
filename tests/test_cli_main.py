"""The CLI entry point: exit codes and one-line errors for user mistakes."""

import subprocess
import sys

import pytest
import typer

import cli.main as cli_main
from accrue.errors import AccrueError


@pytest.fixture()
def extra_commands():
    """Commands added to the real app for one test, removed afterwards."""
    before = list(cli_main.app.registered_commands)
    yield cli_main.app
    cli_main.app.registered_commands[:] = before


def _run_main(monkeypatch, *argv: str) -> int:
    monkeypatch.setattr(sys, "argv", ["accrue", *argv])
    with pytest.raises(SystemExit) as exit_info:
        cli_main.main()
    return exit_info.value.code


def test_typer_exit_code_reaches_the_shell(extra_commands, monkeypatch):
    @extra_commands.command("exit-three")
    def _exit_three() -> None:
        raise typer.Exit(3)

    assert _run_main(monkeypatch, "exit-three") == 3


def test_user_error_is_one_line_and_exit_2(extra_commands, monkeypatch, capsys):
    @extra_commands.command("user-mistake")
    def _user_mistake() -> None:
        raise AccrueError("task 'nope' does not exist")

    assert _run_main(monkeypatch, "user-mistake") == 2
    err = capsys.readouterr().err
    assert err.strip() == "error: task 'nope' does not exist"


def test_unknown_command_is_a_one_line_usage_error():
    proc = subprocess.run([sys.executable, "-m", "cli.main", "no-such-command"], capture_output=True, text=True)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == ["error: No such command 'no-such-command'."]
    assert "Traceback" not in proc.stderr
