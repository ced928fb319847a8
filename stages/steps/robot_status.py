"""What `accrue stage status` adds for a workflow with a robot: each robot step's sessions (start, end,
host, operator, episodes, robot time, how it ended), its running success and robot time so far, and how
far training is from the stop rule. Read from the step's newest sealed checkpoint (a step in progress
or interrupted) or its committed `episodes` output, without materialising transitions or logs."""

from __future__ import annotations

import json

from artifacts.errors import StoreError
from artifacts.manifests import read_artifact, read_tree
from artifacts.records import list_attempts
from artifacts.store import Store
from stages.workflow import Workflow

ROBOT_STEPS = ("warmup", "train", "evaluate-all")  # the steps a robot runs (stages.steps.robot_plan.bind_robot)
# what every robot step's code version starts with (stages.steps.robot_env.CODE_VERSIONS), older ones too: the
# simulator's attempts of the same steps are not the robot's
ROBOT_CODE_VERSION_PREFIX = "hw-"


def _sealed(store: Store, artifact_id: str) -> tuple[list[dict], list[dict]]:
    """(sessions, episode records) of a checkpoint or an `episodes` output."""
    manifest = read_artifact(store, artifact_id)
    sessions, episodes = [], []
    for entry in read_tree(store, manifest["content"]):
        path = entry["path"]
        if path == "sessions.json":
            sessions = json.loads(store.read_bytes(entry["id"]))
        elif path.endswith("episode.json"):
            episodes.append(json.loads(store.read_bytes(entry["id"])))
    return sessions, sorted(episodes, key=lambda e: e["index"])


def robot_status(store: Store, wf: Workflow) -> list[dict]:
    """Per stage and robot step run so far: its sessions, episodes, successes, robot time, faults (train:
    the running success and the stop rule)."""
    rows = []
    attempts = [
        a
        for a in list_attempts(store, problems=[])
        if a.get("workflow") == wf.name and str(a.get("code_version", "")).startswith(ROBOT_CODE_VERSION_PREFIX)
    ]
    for k in range(1, wf.num_stages + 1):
        for step in ROBOT_STEPS:
            mine = sorted(
                (a for a in attempts if a.get("stage") == k and a["step"] == step), key=lambda a: a.get("started", "")
            )
            if not mine:
                continue
            latest = mine[-1]
            source = (
                (latest.get("outputs") or {}).get("episodes")
                if latest["state"] == "committed"
                else (latest["checkpoints"][-1]["id"] if latest.get("checkpoints") else None)
            )
            if source is None:
                continue
            try:
                sessions, episodes = _sealed(store, source)
            except StoreError as exc:
                rows.append({"stage": k, "step": step, "state": latest["state"], "error": str(exc)})
                continue
            row = {
                "stage": k,
                "step": step,
                "state": latest["state"],
                "sessions": sessions,
                "episodes": len(episodes),
                "successes": sum(bool(e["label"]["success"]) for e in episodes),
                "robot_time_s": round(sum(e["robot_time_s"] for e in episodes), 3),
                "faults": sum(1 for e in episodes if e.get("faults")),
                # which episodes, and what happened in each (its first fault, and how many more)
                "fault_episodes": [
                    {"index": e["index"], "end": e.get("end"), "faults": list(e["faults"])}
                    for e in episodes
                    if e.get("faults")
                ],
            }
            if step == "train" and wf.robot is not None:
                r = wf.robot
                window = [bool(e["label"]["success"]) for e in episodes][-r.stop_window :]
                row["window"] = f"{sum(window)}/{len(window)}"
                need = (
                    max(0, r.stop_successes - sum(window))
                    if len(window) >= r.stop_window
                    else max(r.stop_window - len(window), r.stop_successes - sum(window))
                )
                row["stop_rule"] = (
                    f"reached ({r.stop_successes}/{r.stop_window})"
                    if len(window) >= r.stop_window and sum(window) >= r.stop_successes
                    else f"{r.stop_successes}/{r.stop_window} needed: at least {need} more successful "
                    f"episode(s); RL robot time {row['robot_time_s']:.0f} of {r.budget_s:.0f} s"
                )
            rows.append(row)
    return rows
