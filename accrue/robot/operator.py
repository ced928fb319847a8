"""The operator: labels each episode's success, says when the scene is reset, can pause, abort, end an
episode early and re-label the last one. Labels carry who gave them and when (they are sealed with the
episode, so an audit finds every one).

    TerminalOperator(name)            single keys on a terminal (rich): s/f label, r reset done, p pause,
                                      e end the episode now, l re-label the last episode, a abort
    ScriptedOperator(name, ...)       for tests and unattended dry runs: labels what the simulated robot
                                      reports, with an optional delay and deliberate mistakes
"""

from __future__ import annotations

import datetime as _dt
import os
import time
from dataclasses import asdict, dataclass, field
from typing import Callable

from accrue.errors import AccrueError


def now_iso() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds")


@dataclass(frozen=True)
class Label:
    success: bool
    by: str  # the operator's name, or "system" for an episode a fault ended
    at: str  # ISO time the label was given
    note: str = ""

    def to_json(self) -> dict:
        return asdict(self)


@dataclass
class ResetAnswer:
    go: bool  # False: the operator aborted the session
    relabel: Label | None = None  # a corrected label for the last episode, if the operator gave one


class Operator:
    name = "operator"

    def tell(self, line: str) -> None:
        """Show the operator something (a safety stop, a fault, the running success)."""

    def wait_reset(self, episode: int, task: str, last: int | None) -> ResetAnswer:
        raise NotImplementedError

    def label(self, episode: int, summary: str) -> Label | None:
        """None: the operator aborted instead of labelling (the episode is then discarded)."""
        raise NotImplementedError

    def poll(self) -> str | None:
        """Non-blocking, during an episode: "end" (stop it now), "abort", or None."""
        return None

    def close(self) -> None:
        """Release what the operator holds (the terminal's mode)."""


@dataclass
class ScriptedOperator(Operator):
    """Labels from the simulated robot's own success (what a person would see), `delay_s` to answer, and
    a wrong label on the episodes listed in `mistakes`; those also in `corrects` are re-labelled at the
    next reset (as a person who notices the slip would)."""

    oracle: Callable[[], bool] | None = None
    reset_scene: Callable[[], None] | None = None
    name: str = "scripted"
    delay_s: float = 0.0
    mistakes: set[int] = field(default_factory=set)
    corrects: set[int] = field(default_factory=set)
    abort_before: int | None = None  # abort the session before this episode index
    told: list[str] = field(default_factory=list)
    _pending: Label | None = None

    def tell(self, line: str) -> None:
        self.told.append(line)

    def wait_reset(self, episode: int, task: str, last: int | None) -> ResetAnswer:
        if self.abort_before is not None and episode >= self.abort_before:
            return ResetAnswer(go=False)
        if self.reset_scene is not None:
            self.reset_scene()
        fix, self._pending = self._pending, None
        return ResetAnswer(go=True, relabel=fix)

    def label(self, episode: int, summary: str) -> Label | None:
        if self.oracle is None:
            raise AccrueError(
                "the scripted operator needs a robot that reports its episode's success "
                "(the simulated robot accrue_sim does); use robot.operator: terminal"
            )
        time.sleep(self.delay_s)
        truth = bool(self.oracle())
        wrong = episode in self.mistakes
        label = Label(
            success=truth != wrong, by=self.name, at=now_iso(), note="deliberate mistake (scripted)" if wrong else ""
        )
        if wrong and episode in self.corrects:
            self._pending = Label(success=truth, by=self.name, at=now_iso(), note=f"corrects episode {episode}")
        return label


class TerminalOperator(Operator):
    """Single keys on the terminal the stage runs in (stdin in cbreak mode while waiting)."""

    KEYS = "s=success  f=failure  r=reset done  p=pause/resume  e=end episode  l=re-label last  a=abort"

    def __init__(self, name: str, console=None):
        import sys

        from rich.console import Console

        if not sys.stdin.isatty():
            raise AccrueError(
                "robot.operator: terminal needs an interactive terminal (stdin is not a tty); "
                "use robot.operator: scripted for an unattended run on the simulated robot"
            )
        import atexit
        import termios
        import tty

        self.name = name
        self.console = console or Console(stderr=True)
        # cbreak for the operator's whole session: keys typed at any moment are read one by one
        self._fd = sys.stdin.fileno()
        self._saved = termios.tcgetattr(self._fd)
        tty.setcbreak(self._fd, termios.TCSANOW)
        atexit.register(self.close)

    def close(self) -> None:
        """Give the terminal back as it was."""
        import termios

        if self._saved is not None:
            try:
                termios.tcsetattr(self._fd, termios.TCSADRAIN, self._saved)
            except termios.error:
                pass
            self._saved = None

    def _key(self, timeout: float | None) -> str | None:
        import select

        ready, _, _ = select.select([self._fd], [], [], timeout)
        # os.read, not sys.stdin.read: a buffered read would swallow keys typed together, and the next
        # select() would wait for keys already read
        return os.read(self._fd, 1).decode(errors="replace").lower() if ready else None

    def tell(self, line: str) -> None:
        self.console.print(f"[bold yellow]robot:[/] {line}")

    def wait_reset(self, episode: int, task: str, last: int | None) -> ResetAnswer:
        self.console.print(
            f"[bold]episode {episode}[/] ({task}): reset the scene, then press [bold]r[/]  ({self.KEYS})"
        )
        relabel = None
        paused = False
        while True:
            key = self._key(None)
            if key == "a":
                return ResetAnswer(go=False, relabel=relabel)
            if key == "p":
                paused = not paused
                self.console.print("paused: press p to resume" if paused else "resumed: press r when reset")
            elif key == "l" and last is not None:
                self.console.print(f"re-label episode {last}: s=success f=failure")
                k = None
                while k not in ("s", "f"):
                    k = self._key(None)
                relabel = Label(success=k == "s", by=self.name, at=now_iso(), note=f"re-label of episode {last}")
                self.console.print(f"episode {last} re-labelled {'success' if k == 's' else 'failure'}")
            elif key == "r" and not paused:
                return ResetAnswer(go=True, relabel=relabel)

    def label(self, episode: int, summary: str) -> Label | None:
        self.console.print(f"[bold]episode {episode}[/] ended ({summary}): s=success  f=failure  a=abort")
        while True:
            key = self._key(None)
            if key in ("s", "f"):
                return Label(success=key == "s", by=self.name, at=now_iso())
            if key == "a":
                return None

    def poll(self) -> str | None:
        key = self._key(0)
        return {"e": "end", "a": "abort"}.get(key or "")
