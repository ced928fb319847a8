"""Live progress of a bench run (rich): cells done / running / failed / pending, and an ETA.

One line per finished cell is printed above the live display, so a log (no terminal) keeps the story;
the live part (a bar and the running cells) is redrawn twice a second on a terminal.
"""

from __future__ import annotations

import contextlib
import sys
import time

from rich.console import Console, Group
from rich.progress_bar import ProgressBar
from rich.text import Text

from stages.bench.spec import BenchSpec, Cell
from stages.bench.state import cell_states

STORE_POLL_S = 5.0


def hms(seconds: float | None) -> str:
    if seconds is None:
        return "—"
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


class BenchProgress:
    def __init__(
        self, spec: BenchSpec, store, cells: list[Cell], console: Console | None = None, skipped: int = 0
    ) -> None:
        # its own file object: a cell run in this process redirects sys.stdout/stderr to its log
        self.console = console or Console(file=sys.stderr, highlight=False)
        self.spec, self.store, self.total, self.skipped = spec, store, len(cells), skipped
        self.done = self.failed = 0
        self.flight: dict[str, Cell] = {}  # submitted (Ray) or started (serial), not finished
        self.running: dict[str, str] = {}  # cell name -> what it runs now (from the store)
        self.started_at = time.monotonic()
        self._polled = 0.0

    # ---- events
    def submitted(self, cell: Cell) -> None:
        self.flight[cell.name] = cell

    def started(self, cell: Cell) -> None:
        self.flight[cell.name] = cell
        self.running[cell.name] = "in this process"

    def retrying(self, cell: Cell, tries: int, allowed: int, error: str) -> None:
        self.console.print(f"[yellow]✗ {cell.label}: try {tries}/{allowed} failed: {error} — trying again[/]")

    def finished(self, cell: Cell, state: str, seconds: float, tries: int, steps=None, error=None) -> None:
        self.flight.pop(cell.name, None)
        self.running.pop(cell.name, None)
        if state == "done":
            self.done += 1
            extra = f" ({steps[0]} steps run, {steps[1]} cached)" if steps else ""
            self.console.print(f"[green]✓[/] {cell.label} done in {hms(seconds)}{extra}")
        else:
            self.failed += 1
            self.console.print(f"[red]✗ {cell.label} failed after {tries} tries: {error}[/]")

    def poll(self) -> None:
        """Which in-flight cells really run (a live step attempt in the store), every few seconds."""
        if time.monotonic() - self._polled < STORE_POLL_S or not self.flight:
            return
        self._polled = time.monotonic()
        states = cell_states(self.store, self.spec, list(self.flight.values()))
        self.running = {n: s.running_step for n, s in states.items() if s.state == "running"}

    # ---- display
    def eta(self) -> float | None:
        finished = self.done + self.failed
        if finished == 0:
            return None
        left = self.total - self.skipped - finished
        return (time.monotonic() - self.started_at) / finished * left

    def line(self) -> Text:
        pending = self.total - self.skipped - self.done - self.failed - len(self.running)
        t = Text()
        t.append(f"bench {self.spec.name}: ", style="bold")
        t.append(f"{self.skipped + self.done}/{self.total} done")
        if self.skipped:
            t.append(f" ({self.skipped} before this run)", style="dim")
        t.append(f" · {len(self.running)} running")
        t.append(f" · {self.failed} failed", style="red" if self.failed else None)
        t.append(
            f" · {max(0, pending)} pending · ETA {hms(self.eta())} · {hms(time.monotonic() - self.started_at)} elapsed"
        )
        return t

    def __rich__(self):
        bar = ProgressBar(total=max(1, self.total), completed=self.skipped + self.done + self.failed, width=40)
        running = [
            Text(f"  running: {self.flight[n].label if n in self.flight else n} — {what}", style="cyan")
            for n, what in sorted(self.running.items())
        ]
        return Group(self.line(), bar, *running)

    @contextlib.contextmanager
    def live(self):
        from rich.live import Live

        with Live(
            self,
            console=self.console,
            refresh_per_second=2,
            redirect_stdout=False,
            redirect_stderr=False,
            transient=False,
        ):
            yield self
        if not self.console.is_terminal:  # the final frame of a non-terminal Live ends without a newline
            self.console.file.write("\n")
