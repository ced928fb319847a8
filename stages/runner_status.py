"""What `accrue stage status` shows: per stage and step, in the order the stage runs them, the committed
record (from the workflow's refs) or the latest attempt (running, failed, or abandoned with its last
checkpoint), with when it started, how long it ran and on which host."""

from __future__ import annotations

from artifacts.diff import _seconds
from artifacts.errors import StoreError
from artifacts.records import list_attempts
from artifacts.refs import read_ref
from artifacts.store import Store
from stages.runner import reap_abandoned, step_ref
from stages.runner_types import STEP_NAMES
from stages.workflow import Workflow


def workflow_status(store: Store, wf: Workflow) -> list[dict]:
    attempts = [a for a in list_attempts(store) if a.get("workflow") == wf.name]
    for key in {a["cache_key"] for a in attempts if a["state"] == "running"}:
        if reap_abandoned(store, key):  # a dead process's attempt is abandoned on the next look
            attempts = [a for a in list_attempts(store) if a.get("workflow") == wf.name]
    rows = []
    for k, task in enumerate(wf.tasks, 1):
        order = stage_step_names(wf, k)
        names = order + sorted({a["step"] for a in attempts if a.get("stage") == k} - set(order))
        for name in names:
            mine = [a for a in attempts if a.get("stage") == k and a["step"] == name]
            mine.sort(key=lambda a: a.get("started", ""))
            record = read_ref(store, step_ref(wf.name, k, name))
            latest = mine[-1] if mine else None
            row = {"stage": k, "task": task, "step": name, "record": record, "state": "not run", "detail": ""}
            row.update(started=None, finished=None, duration_s=None, host=None)
            if (
                latest is not None
                and latest["state"] != "committed"
                and (record is None or latest.get("started", "") > _started_of(mine, record))
            ):
                row["state"] = latest["state"]
                ckpts = latest.get("checkpoints", [])
                detail = f"attempt {latest['attempt']} pid {latest.get('pid')}"
                if latest.get("error"):
                    detail += f": {latest['error']}"
                if ckpts:
                    detail += " — last checkpoint " + ", ".join(f"{a}={b}" for a, b in ckpts[-1]["progress"].items())
                row["detail"] = detail
                row.update(_when(latest))
            elif record is not None:
                row.update(state="committed", detail=record[:12])
                row.update(_when(_record_fields(store, record, mine)))
            rows.append(row)
    return rows


def stage_step_names(wf: Workflow, stage: int) -> list[str]:
    """The steps stage k runs, in run order (stages/plan.py): record-demos first when it records demos."""
    from stages.demo_rules import stage_records_demos

    records = stage_records_demos(wf, stage)
    return (["record-demos"] if records else []) + list(STEP_NAMES)


def _record_fields(store: Store, record_id: str, attempts: list[dict]) -> dict:
    """started/finished/host of a committed step: its record when the object is here (a pulled store
    has the record, not the attempt), else the attempt that committed it; never a remote fetch."""
    if store.has_object(record_id):
        try:
            return store.read_json(record_id)
        except StoreError:
            pass  # a damaged record: verify reports it; status shows what the attempt says
    return next((a for a in attempts if a.get("record_id") == record_id), {})


def _when(fields: dict) -> dict:
    started, finished = fields.get("started"), fields.get("finished")
    duration = _seconds(started, finished) if started and finished else None
    return {"started": started, "finished": finished, "duration_s": duration, "host": fields.get("host")}


def _started_of(attempts: list[dict], record_id: str) -> str:
    for a in attempts:
        if a.get("record_id") == record_id:
            return a.get("started", "")
    return ""
