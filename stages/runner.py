"""The runner: executes step invocations with caching, per-attempt records, locks and resume.

    Runner(store).run(invocation, mode="normal"|"continue"|"rerun") -> StepResult
    Runner(store).run_plan(plan, only_step=None, mode=...) -> list[StepResult]

A step's cache key has at most one attempt running (kernel lock per key). Publish order on
commit: output objects -> artifact manifests -> step-record object -> attempt file -> log
line -> workflow ref.
"""

from __future__ import annotations

import os
import socket
import time
from pathlib import Path
from typing import Any, Literal

from rich.console import Console

from artifacts.auditlog import append_event
from artifacts.errors import StoreError
from artifacts.locks import Timeout, store_lock
from artifacts.manifests import MANIFEST_FORMAT, materialize, now_iso, publish_artifact, read_artifact, verify_artifact
from artifacts.records import list_attempts, next_attempt_number, write_attempt
from artifacts.refs import read_ref, set_ref
from artifacts.resolve import resolve
from artifacts.store import Store, remove_tree
from stages.errors import StageError
from stages.runner_context import StepContext
from stages.runner_types import FromRef, FromStep, StagePlan, StepInvocation, StepResult, cache_key, code_version_of

Mode = Literal["normal", "continue", "rerun"]
MODES = ("normal", "continue", "rerun")


def step_ref(workflow: str, stage: int, step: str) -> str:
    """The ref naming the committed step record of a workflow's stage step."""
    return f"workflow/{workflow}/stage/{stage}/{step}"


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}".strip()


def reap_abandoned(store: Store, key: str, holding_lock: bool = False) -> int:
    """Mark attempts of key that say `running` but whose process is gone as `abandoned`.

    The key's lock is the proof: a live attempt holds it for its whole life, so if we can take
    it, every `running` record of that key belongs to a dead process."""
    running = [a for a in list_attempts(store, key) if a["state"] == "running"]
    if not running:
        return 0
    lock = None
    if not holding_lock:
        lock = store_lock(store.locks_dir, f"step-{key}")
        try:
            lock.acquire(timeout=0)
        except Timeout:
            return 0
    try:
        for a in list_attempts(store, key):
            if a["state"] == "running":
                a.update(state="abandoned", finished=now_iso(), error="process died (lock was free)")
                write_attempt(store, a)
                append_event(
                    store, "step-abandoned", step=a["step"], cache_key=key, attempt=a["attempt"], dead_pid=a.get("pid")
                )
        return len(running)
    finally:
        if lock is not None:
            lock.release()


class Runner:
    def __init__(
        self,
        store: Store,
        console: Console | None = None,
        wait: bool = False,
        verify_hits: Literal["full", "quick"] = "full",
    ) -> None:
        self.store = store
        self.console = console or Console(stderr=True)
        self.wait = wait
        self.verify_hits = verify_hits

    # ================================================================= plans
    def run_plan(self, plan: StagePlan, only_step: str | None = None, mode: Mode = "normal") -> list[StepResult]:
        """Run a stage's steps in order (cached ones are no-ops). With only_step, run the steps
        before it (normally: they are usually cached) and that step in `mode`, then stop."""
        if mode not in MODES:
            raise StageError(f"bad mode {mode!r} (use one of {', '.join(MODES)})")
        names = plan.names()
        if only_step is not None and only_step not in names:
            raise StageError(
                f"stage {plan.stage} of workflow {plan.workflow} has no step {only_step!r} (steps: {', '.join(names)})"
            )
        results: dict[str, StepResult] = {}
        for inv in plan.steps:
            name = inv.step.name
            inputs = {role: self._resolve_source(inv, role, src, results) for role, src in inv.inputs.items()}
            step_mode: Mode = mode if only_step in (None, name) else "normal"
            labelled = StepInvocation(
                step=inv.step,
                config=inv.config,
                inputs=inputs,
                workflow=inv.workflow or plan.workflow,
                stage=inv.stage if inv.stage is not None else plan.stage,
            )
            result = self.run(labelled, mode=step_mode)
            results[name] = result
            ref = step_ref(plan.workflow, plan.stage, name)
            if read_ref(self.store, ref) != result.record_id:
                set_ref(self.store, ref, result.record_id)
            if name == only_step:
                break
        return list(results.values())

    def _resolve_source(self, inv: StepInvocation, role: str, src: Any, results: dict[str, StepResult]) -> str:
        name = inv.step.name
        if isinstance(src, FromStep):
            if src.step not in results:
                raise StageError(
                    f"step {name}: input {role!r} is wired to step {src.step}, which does not "
                    "run before it in this plan"
                )
            outputs = results[src.step].outputs
            if src.role not in outputs:
                raise StageError(
                    f"step {name}: input {role!r} wants output {src.role!r} of step {src.step}, "
                    f"which only has {', '.join(sorted(outputs)) or 'none'}"
                )
            return outputs[src.role]
        if isinstance(src, FromRef):
            try:
                return resolve(self.store, src.ref)
            except StoreError as exc:
                raise StageError(
                    f"step {name}: input {role!r} comes from {src.ref}, which cannot be read "
                    f"({exc}); run the earlier stage first"
                ) from None
        if isinstance(src, str):
            return src
        raise StageError(f"step {name}: input {role!r} has unsupported source {src!r}")

    # ================================================================= one step
    def run(self, inv: StepInvocation, mode: Mode = "normal", wait: bool | None = None) -> StepResult:
        if mode not in MODES:
            raise StageError(f"bad mode {mode!r} (use one of {', '.join(MODES)})")
        step = inv.step
        pinned = self._pin_inputs(inv)
        config = dict(inv.config)
        key = cache_key(step, config, pinned)
        lock = store_lock(self.store.locks_dir, f"step-{key}")
        self._acquire(lock, step.name, key, self.wait if wait is None else wait)
        try:
            reap_abandoned(self.store, key, holding_lock=True)
            if mode != "rerun":
                hit = self._find_hit(step.name, key)
                if hit is not None:
                    self.console.print(
                        f"step [bold]{step.name}[/]: cached — committed record "
                        f"{hit.record_id[:12]} (attempt {hit.attempt}); nothing to do"
                    )
                    return hit
            resume = self._choose_checkpoint(step.name, key, mode)
            return self._attempt(inv, pinned, config, key, mode, resume)
        finally:
            lock.release()

    def _pin_inputs(self, inv: StepInvocation) -> dict[str, str]:
        step = inv.step
        pinned: dict[str, str] = {}
        for role, src in inv.inputs.items():
            if not isinstance(src, str):
                raise StageError(
                    f"step {step.name}: input {role!r} is {src!r}; run it through run_plan or pass an artifact id"
                )
            try:
                oid = resolve(self.store, src)
                read_artifact(self.store, oid)
            except StoreError as exc:
                raise StoreError(f"step {step.name} refuses input {role!r} ({src[:12]}): {exc}") from None
            pinned[role] = oid
        declared = set(step.inputs) | set(step.optional_inputs)
        missing = [r for r in step.inputs if r not in pinned]
        if missing:
            raise StageError(f"step {step.name}: missing input {', '.join(map(repr, missing))}")
        extra = sorted(set(pinned) - declared) if declared else []
        if extra:
            raise StageError(
                f"step {step.name}: unexpected input {', '.join(map(repr, extra))} "
                f"(it takes: {', '.join(sorted(declared))})"
            )
        return pinned

    def _acquire(self, lock, name: str, key: str, wait: bool) -> None:
        try:
            lock.acquire(timeout=0)
            return
        except Timeout:
            pass
        holder = [a for a in list_attempts(self.store, key) if a["state"] == "running"]
        who = (
            f"pid {holder[-1].get('pid')} on {holder[-1].get('host')}, attempt {holder[-1]['attempt']}"
            if holder
            else "another process"
        )
        if not wait:
            raise StageError(f"step {name} is already running ({who}); wait for it or pass --wait")
        self.console.print(f"step [bold]{name}[/]: waiting for {who} to finish…")
        lock.acquire(timeout=-1)

    def _find_hit(self, name: str, key: str) -> StepResult | None:
        """The newest committed attempt whose record and outputs are intact; damaged ones are misses."""
        for a in reversed(list_attempts(self.store, key)):
            if a["state"] != "committed":
                continue
            try:
                record = self.store.read_json(a["record_id"])
                for oid in record["outputs"].values():
                    verify_artifact(self.store, oid, full=self.verify_hits == "full", quarantine=True)
            except StoreError as exc:
                self.console.print(
                    f"[yellow]step {name}: cached result of attempt {a['attempt']} is "
                    f"damaged ({exc}); it does not count[/]"
                )
                continue
            return StepResult(
                step=name,
                outputs=dict(record["outputs"]),
                cached=True,
                record_id=a["record_id"],
                cache_key=key,
                attempt=a["attempt"],
            )
        return None

    def _choose_checkpoint(self, name: str, key: str, mode: Mode) -> tuple[str, dict] | None:
        if mode == "rerun":
            return None
        candidates = [
            (a["attempt"], c)
            for a in list_attempts(self.store, key)
            if a["state"] != "committed"
            for c in a.get("checkpoints", [])
        ]
        if not candidates:
            if mode == "continue":
                other = [
                    a
                    for a in list_attempts(self.store, problems=[])
                    if a["step"] == name
                    and a["cache_key"] != key
                    and a["state"] != "committed"
                    and a.get("checkpoints")
                ]
                why = (
                    (
                        f" (attempt {other[-1]['attempt']} of key {other[-1]['cache_key'][:12]} has checkpoints, "
                        "but its inputs, config or code version differ from this run's)"
                    )
                    if other
                    else ""
                )
                self.console.print(
                    f"step [bold]{name}[/]: no checkpoint to continue from{why}; starting at the beginning"
                )
            return None
        if mode == "normal":
            attempt, c = candidates[-1]
            raise StageError(
                f"step {name} was interrupted (attempt {attempt}, last checkpoint at "
                f"{_progress_text(c['progress'])}); pass --continue to resume it or --rerun to start over"
            )
        for attempt, c in reversed(candidates):
            try:
                verify_artifact(self.store, c["id"], full=True, quarantine=True)
            except StoreError as exc:
                self.console.print(
                    f"[yellow]step {name}: checkpoint {c['id'][:12]} is damaged ({exc}); trying an older one[/]"
                )
                continue
            self.console.print(
                f"step [bold]{name}[/]: continuing from checkpoint {c['id'][:12]} "
                f"(attempt {attempt}, {_progress_text(c['progress'])})"
            )
            return c["id"], c["progress"]
        self.console.print(f"[yellow]step {name}: every checkpoint is damaged; starting at the beginning[/]")
        return None

    # ================================================================= an attempt
    def _attempt(
        self,
        inv: StepInvocation,
        pinned: dict[str, str],
        config: dict,
        key: str,
        mode: Mode,
        resume: tuple[str, dict] | None,
    ) -> StepResult:
        store, step = self.store, inv.step
        number = next_attempt_number(store, key)
        attempt: dict[str, Any] = {
            "cache_key": key,
            "attempt": number,
            "step": step.name,
            "state": "running",
            "mode": mode,
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "started": now_iso(),
            "inputs": pinned,
            "config": config,
            "code_version": code_version_of(step),
            "workflow": inv.workflow,
            "stage": inv.stage,
            "checkpoints": [],
            "resumed_from": resume[0] if resume else None,
        }
        write_attempt(store, attempt)
        append_event(
            store,
            "step-started",
            step=step.name,
            cache_key=key,
            attempt=number,
            mode=mode,
            inputs=pinned,
            workflow=inv.workflow,
            stage=inv.stage,
        )
        self.console.print(f"step [bold]{step.name}[/]: running attempt {number} ({mode})")
        work_dir = store.new_tmp_dir(f"attempt-{key[:12]}-{number:04d}")
        started = time.monotonic()
        try:
            ctx = self._context(inv, pinned, config, key, attempt, work_dir, resume)
            step.run(ctx)
            outputs = self._commit_outputs(inv, ctx, pinned, config, key, number)
            record = {
                "type": "step-record",
                "format": MANIFEST_FORMAT,
                "step": step.name,
                "cache_key": key,
                "attempt": number,
                "state": "committed",
                "inputs": pinned,
                "config": config,
                "code_version": code_version_of(step),
                "outputs": outputs,
                "started": attempt["started"],
                "finished": now_iso(),
                "host": attempt["host"],
                "pid": attempt["pid"],
                "resumed_from": attempt["resumed_from"],
                "workflow": inv.workflow,
                "stage": inv.stage,
            }
            record_id = store.put_json(record)
            attempt.update(state="committed", record_id=record_id, finished=record["finished"], outputs=outputs)
            write_attempt(store, attempt)
            append_event(
                store,
                "step-committed",
                step=step.name,
                cache_key=key,
                attempt=number,
                record=record_id,
                outputs=outputs,
            )
        except KeyboardInterrupt as exc:
            # a hardware step's SessionStop names what stopped it (Ctrl-C or SIGTERM); a bare
            # KeyboardInterrupt is Python's default SIGINT handler, i.e. Ctrl-C
            self._close(attempt, "abandoned", getattr(exc, "how", None) or "interrupted (Ctrl-C)")
            raise
        except BaseException as exc:
            self._close(attempt, "failed", _one_line(exc))
            raise
        finally:
            remove_tree(work_dir)
        self.console.print(
            f"step [bold]{step.name}[/]: committed record {record_id[:12]} in {time.monotonic() - started:.1f} s"
        )
        return StepResult(
            step=step.name, outputs=outputs, cached=False, record_id=record_id, cache_key=key, attempt=number
        )

    def _close(self, attempt: dict, state: str, error: str) -> None:
        attempt.update(state=state, finished=now_iso(), error=error)
        try:
            write_attempt(self.store, attempt)
            append_event(
                self.store,
                "step-failed" if state == "failed" else "step-abandoned",
                step=attempt["step"],
                cache_key=attempt["cache_key"],
                attempt=attempt["attempt"],
                error=error,
            )
        except Exception:  # noqa: BLE001 - the original error matters more; the lock rule reaps it
            pass

    def _context(
        self,
        inv: StepInvocation,
        pinned: dict[str, str],
        config: dict,
        key: str,
        attempt: dict,
        work_dir: Path,
        resume: tuple[str, dict] | None,
    ) -> StepContext:
        store, step = self.store, inv.step
        paths: dict[str, Path] = {}
        manifests: dict[str, dict] = {}
        for role, oid in pinned.items():
            try:
                manifests[role] = read_artifact(store, oid)
                paths[role] = materialize(store, oid, work_dir / "inputs" / role, quarantine=True)
            except StoreError as exc:
                raise StoreError(f"step {step.name} refuses input {role!r} ({oid[:12]}): {exc}") from None

        def save_checkpoint(directory: Path, progress: dict) -> str:
            if not directory.is_dir():
                raise StageError(f"step {step.name}: checkpoint {directory} is not a directory")
            cid = publish_artifact(
                store,
                directory,
                "checkpoint",
                producer={"step": step.name, "cache_key": key, "attempt": attempt["attempt"]},
                inputs=pinned,
                config=config,
                code_version=attempt["code_version"],
                meta={"progress": progress},
                how="checked",
            )
            attempt["checkpoints"].append({"id": cid, "progress": progress, "time": now_iso()})
            write_attempt(store, attempt)
            append_event(
                store,
                "checkpoint-saved",
                step=step.name,
                cache_key=key,
                attempt=attempt["attempt"],
                checkpoint=cid,
                progress=progress,
            )
            return cid

        def log_event(event: str, **fields: Any) -> None:
            append_event(store, event, step=step.name, cache_key=key, attempt=attempt["attempt"], **fields)

        return StepContext(
            store=store,
            step=step.name,
            config=config,
            inputs=pinned,
            input_paths=paths,
            input_manifests=manifests,
            work_dir=work_dir,
            save_checkpoint=save_checkpoint,
            resume_from=resume,
            console=self.console,
            log_event=log_event,
        )

    def _commit_outputs(
        self, inv: StepInvocation, ctx: StepContext, pinned: dict[str, str], config: dict, key: str, number: int
    ) -> dict[str, str]:
        step = inv.step
        missing = [r for r in step.outputs if r not in ctx.outputs]
        if missing:
            raise StageError(f"step {step.name} did not produce output {', '.join(map(repr, missing))}")
        for role, kind in step.outputs.items():
            if ctx.outputs[role][0] != kind:
                raise StageError(f"step {step.name}: output {role!r} should be kind {kind}, got {ctx.outputs[role][0]}")
        outputs = {}
        for role, (kind, path) in sorted(ctx.outputs.items()):
            oid = publish_artifact(
                self.store,
                path,
                kind,
                producer={"step": step.name, "cache_key": key, "attempt": number},
                inputs=pinned,
                config=config,
                code_version=code_version_of(step),
                meta={"role": role},
                how="adopt",
            )
            append_event(self.store, "artifact-written", artifact=oid, kind=kind, role=role, step=step.name)
            outputs[role] = oid
        return outputs


def _progress_text(progress: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in progress.items()) or "no progress recorded"
