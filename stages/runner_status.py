"""What `accrue stage status` shows: per stage and step, the committed record (from the workflow's
refs) or the latest attempt (running, failed, or abandoned with its last checkpoint)."""

from __future__ import annotations

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
        names = list(STEP_NAMES) + sorted({a["step"] for a in attempts if a.get("stage") == k} - set(STEP_NAMES))
        for name in names:
            mine = [a for a in attempts if a.get("stage") == k and a["step"] == name]
            mine.sort(key=lambda a: a.get("started", ""))
            record = read_ref(store, step_ref(wf.name, k, name))
            latest = mine[-1] if mine else None
            row = {"stage": k, "task": task, "step": name, "record": record, "state": "not run", "detail": ""}
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
            elif record is not None:
                row.update(state="committed", detail=record[:12])
            rows.append(row)
    return rows


def _started_of(attempts: list[dict], record_id: str) -> str:
    for a in attempts:
        if a.get("record_id") == record_id:
            return a.get("started", "")
    return ""
