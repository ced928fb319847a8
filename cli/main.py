"""The `accrue` command: parse, call, print. Sub-command groups live in their own modules.

Only typer/rich are imported at module level; every command imports its heavy libraries
(torch, mujoco, lerobot) inside its body so that `accrue --help` starts fast.
"""

from __future__ import annotations

import os
import sys

import typer

from cli import register_commands

app = typer.Typer(
    name="accrue",
    help="Continual off-policy RL for robot foundation models, run as resumable stages over a content-addressed store.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,  # plain click help: typer.rich_utils costs ~0.5 s of imports at start-up
)


@app.callback()
def _root() -> None:
    """Continual off-policy RL for robot foundation models."""


register_commands(app)


@app.command()
def version() -> None:
    """Print accrue's version."""
    from importlib.metadata import version as _v

    print(_v("accrue"))


def _user_error_types() -> tuple[type[BaseException], ...]:
    from accrue.errors import AccrueError
    from artifacts.errors import StoreError
    from stages.errors import StageError

    return (AccrueError, StoreError, StageError)


MESSAGE_LIMIT = 1000  # characters of one error line; what a message quotes is capped at the source


def _message(exc: BaseException) -> str | None:
    """The one-line message of an exception that is a user's mistake or the machine's state (a
    missing or unreadable file, a full or read-only disk, bad bytes, absurd input), else None (a
    bug: its traceback is shown)."""
    from artifacts.errors import os_error_text

    if isinstance(exc, _user_error_types()):
        text = str(exc)
    elif isinstance(exc, OSError):
        text = os_error_text(exc)
    elif isinstance(exc, UnicodeDecodeError):
        text = f"input is not valid {exc.encoding} (byte {exc.start}: {exc.reason})"
    elif isinstance(exc, UnicodeError):
        text = f"text cannot be encoded ({exc.__class__.__name__}: {getattr(exc, 'reason', exc)})"
    elif isinstance(exc, RecursionError):
        text = "input is nested too deeply to read"
    elif isinstance(exc, (ValueError, OverflowError)):
        text = str(exc) or exc.__class__.__name__
    else:
        return None
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    text = " ".join(lines) if len(lines) <= 3 else f"{lines[0]} (and {len(lines) - 1} more lines)"
    return text if len(text) <= MESSAGE_LIMIT else text[: MESSAGE_LIMIT - 1] + "…"


def main() -> None:
    """Console-script entry: user mistakes become one line on stderr and exit code 2.
    ACCRUE_DEBUG=1 shows the traceback instead."""
    try:
        # With standalone_mode=False, click returns a command's exit code instead of exiting.
        rc = app(standalone_mode=False)
        sys.exit(rc if isinstance(rc, int) else 0)
    except typer.Abort:
        print("aborted", file=sys.stderr)
        sys.exit(130)
    except KeyboardInterrupt:
        print("interrupted: committed work is kept; resume with --continue", file=sys.stderr)
        sys.exit(130)
    except Exception as exc:  # noqa: BLE001 - classify, then re-raise real bugs
        if isinstance(exc, typer.Exit):
            sys.exit(exc.exit_code)
        if hasattr(exc, "format_message") and hasattr(exc, "exit_code"):  # click usage errors
            print(f"error: {exc.format_message()}", file=sys.stderr)
            sys.exit(exc.exit_code)
        message = _message(exc)
        if message is None or os.environ.get("ACCRUE_DEBUG"):
            raise
        print(f"error: {message}", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":
    main()
