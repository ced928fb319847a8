"""StepContext: everything a step body may touch — verified inputs, its config, staging dirs for
outputs, intra-step checkpoints, console and audit events."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Mapping

from rich.console import Console

from artifacts.errors import StoreError
from artifacts.store import Store
from stages.errors import StageError


class StepContext:
    def __init__(
        self,
        *,
        store: Store,
        step: str,
        config: Mapping[str, Any],
        inputs: dict[str, str],
        input_paths: dict[str, Path],
        input_manifests: dict[str, dict],
        work_dir: Path,
        save_checkpoint: Callable[[Path, dict], str],
        resume_from: tuple[str, dict] | None,
        console: Console,
        log_event: Callable[..., None],
    ) -> None:
        self.store = store
        self.step = step
        self.config: Mapping[str, Any] = config
        self.inputs = dict(inputs)  # role -> pinned artifact id
        self.console = console
        self.work_dir = work_dir  # scratch space, removed after the attempt
        self._input_paths = input_paths
        self._input_manifests = input_manifests
        self._save = save_checkpoint
        self._resume_from = resume_from
        self._resume_path: Path | None = None
        self._log = log_event
        self.outputs: dict[str, tuple[str, Path]] = {}  # role -> (kind, staging dir)

    # ----------------------------------------------------------------- inputs
    def has_input(self, role: str) -> bool:
        return role in self.inputs

    def input_path(self, role: str) -> Path:
        """Read-only, verified view of input `role`: a directory copy, or the object file itself."""
        try:
            return self._input_paths[role]
        except KeyError:
            raise StageError(
                f"step {self.step} has no input {role!r} (it has: {', '.join(sorted(self.inputs)) or 'none'})"
            ) from None

    def input_manifest(self, role: str) -> dict:
        self.input_path(role)
        return self._input_manifests[role]

    # ----------------------------------------------------------------- outputs
    def new_output(self, role: str, kind: str) -> Path:
        """An empty directory to fill; committed as a directory artifact when the body returns."""
        if role in self.outputs:
            raise StageError(f"step {self.step}: output {role!r} was already created")
        from artifacts.manifests import check_kind

        check_kind(kind)
        path = self.work_dir / "outputs" / role
        path.mkdir(parents=True)
        self.outputs[role] = (kind, path)
        return path

    def scratch_dir(self, name: str) -> Path:
        """A scratch directory under the attempt's work dir (same filesystem as the store)."""
        path = self.work_dir / "scratch" / name
        path.mkdir(parents=True, exist_ok=True)
        return path

    # ----------------------------------------------------------------- checkpoints
    def save_checkpoint(self, dir_path: Path, progress: dict) -> str:
        """Publish dir_path as a checkpoint artifact and record it on the attempt; returns its id.

        Files already in the store (unchanged replay shards) are not written again. Earlier
        checkpoints are kept, only superseded. progress must be JSON-able (e.g. {"step": 1200}).
        """
        return self._save(Path(dir_path), dict(progress))

    def last_checkpoint(self) -> tuple[Path, dict] | None:
        """(materialised read-only copy, progress) of the checkpoint to resume from, in
        `continue` mode when one exists; None otherwise."""
        if self._resume_from is None:
            return None
        cid, progress = self._resume_from
        if self._resume_path is None:
            from artifacts.manifests import materialize

            try:
                self._resume_path = materialize(self.store, cid, self.work_dir / "resume")
            except StoreError as exc:
                raise StoreError(f"checkpoint {cid[:12]} of step {self.step}: {exc}") from None
        return self._resume_path, dict(progress)

    def progress(self):
        """A rich Progress on the step's console: `with ctx.progress() as p: t = p.add_task("train",
        total=n); p.advance(t)`."""
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        return Progress(
            TextColumn(f"{self.step} [progress.description]{{task.description}}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            TimeRemainingColumn(),
            console=self.console,
            transient=True,
        )

    def log_event(self, event: str, **fields: Any) -> None:
        """Add a step-specific event to the audit log (e.g. an evaluation summary)."""
        self._log(event, **fields)
