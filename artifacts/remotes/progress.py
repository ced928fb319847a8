"""The progress bar of transfers: bytes, speed and objects, drawn on stderr (stdout stays clean for
--json), and only on a terminal (transient: nothing is left in logs or captured output)."""

from __future__ import annotations

import threading

from artifacts.remotes.transfer import Meter


class RichMeter(Meter):
    def __init__(self) -> None:
        self.bar, self.lock = None, threading.Lock()  # advanced from the transfer threads

    def start(self, what: str, objects: int, nbytes: int) -> None:
        from rich.console import Console

        console = Console(stderr=True)
        if not objects or not console.is_terminal:  # nothing to draw: no bar, no refresh thread
            return
        from rich.progress import BarColumn, DownloadColumn, Progress, TextColumn, TransferSpeedColumn

        self.bar = Progress(
            TextColumn(what),
            BarColumn(),
            DownloadColumn(),
            TransferSpeedColumn(),
            TextColumn("{task.fields[objects]} objects"),
            console=console,
            transient=True,
        )
        self.bar.start()
        self.task = self.bar.add_task("", total=nbytes or None, objects=f"0/{objects}")
        self.done, self.total = 0, objects

    def advance(self, nbytes: int) -> None:
        if self.bar is not None:
            with self.lock:
                self.done += 1
                self.bar.update(self.task, advance=nbytes, objects=f"{self.done}/{self.total}")

    def stop(self) -> None:
        if self.bar is not None:
            self.bar.stop()
            self.bar = None
