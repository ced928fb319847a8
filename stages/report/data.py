"""Read what a workflow's run has committed so far: per stage, the `train` step's learning curves
(`curve.json` in its output role `curve`) and the `evaluate-all` step's deployment evaluation
(`eval.json` in its output role `eval`), found through the runner's refs
`workflow/<name>/stage/<k>/<step>`.

    run = load_run(store, wf)      # RunData; raises StageError (one line) when nothing usable exists

Every file is read through the store (hashes checked) and its fields are checked against the
workflow, so a damaged or mismatched record is a one-line error naming the ref and the field.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

from artifacts.errors import StoreError
from artifacts.manifests import read_artifact, read_tree
from artifacts.refs import read_ref
from artifacts.store import Store
from stages.errors import StageError
from stages.runner import step_ref
from stages.steps import evaluate_all as evaluate_step
from stages.steps import train as train_step
from stages.workflow import Workflow

TRAIN, EVALUATE = "train", "evaluate-all"
# step name -> (output role, file inside that directory artifact)
SOURCES = {TRAIN: ("curve", train_step.CURVE_FILE), EVALUATE: ("eval", evaluate_step.EVAL_FILE)}


@dataclass(frozen=True)
class StageCurves:
    """Stage k's learning curves: success of tasks 1..k at each grid point (env steps of stage k)."""

    stage: int
    task_ids: list[str]
    grid: list[int]
    success: dict[str, list[float]]
    episodes_per_point: int
    record: str  # the committed train step record
    artifact: str  # its `curve` output
    # the same grid points on the disjoint report episodes (budgets.report_episodes; None before the split)
    report: dict[str, list[float]] | None = None
    report_episodes: int | None = None


@dataclass(frozen=True)
class StageEval:
    """Stage k's deployment evaluation on tasks 1..k: π_base^k alone and π_base^k + RL actor θ^k."""

    stage: int
    task_ids: list[str]
    success: dict[str, float]
    base_success: dict[str, float]
    episodes: int
    record: str
    artifact: str


@dataclass(frozen=True)
class Missing:
    stage: int
    step: str
    ref: str


@dataclass
class RunData:
    workflow: Workflow
    curves: list[StageCurves] = field(default_factory=list)  # stages 1..m, contiguous from 1
    evals: dict[int, StageEval] = field(default_factory=dict)  # stage -> evaluation (where committed)
    missing: list[Missing] = field(default_factory=list)  # every (stage, step) not committed

    @property
    def stages_done(self) -> int:
        return len(self.curves)

    @property
    def complete(self) -> bool:
        return not self.missing

    def latest_eval(self) -> StageEval | None:
        return self.evals[max(self.evals)] if self.evals else None


# ------------------------------------------------------------------------- reading the store
def read_step_file(store: Store, ref: str, step: str) -> tuple[dict, str, str] | None:
    """(parsed JSON file, record id, artifact id) of the step record `ref` points at, or None when
    the ref does not exist (the step has not committed)."""
    record_id = read_ref(store, ref)
    if record_id is None:
        return None
    role, filename = SOURCES[step]
    record = store.read_json(record_id)
    if record.get("type") != "step-record":
        raise StoreError(f"ref {ref} points at {record_id[:12]}, which is not a step record")
    outputs = record.get("outputs") or {}
    if role not in outputs:
        raise StageError(
            f"{ref}: step record {record_id[:12]} has no output {role!r} "
            f"(it has: {', '.join(sorted(outputs)) or 'none'})"
        )
    artifact_id = outputs[role]
    return _read_json_in_artifact(store, artifact_id, filename, ref), record_id, artifact_id


def _read_json_in_artifact(store: Store, artifact_id: str, filename: str, where: str) -> dict:
    manifest = read_artifact(store, artifact_id)
    if manifest["layout"] == "dir":
        entries = {e["path"]: e["id"] for e in read_tree(store, manifest["content"])}
        oid = entries.get(filename)
    else:
        oid = manifest["content"] if manifest.get("name") == filename else None
    if oid is None:
        raise StageError(f"{where}: artifact {artifact_id[:12]} has no {filename}")
    try:
        value = json.loads(store.read_bytes(oid))
    except ValueError:
        raise StageError(f"{where}: {filename} in artifact {artifact_id[:12]} is not valid JSON") from None
    if not isinstance(value, dict):
        raise StageError(f"{where}: {filename} in artifact {artifact_id[:12]} is not a JSON object")
    return value


# ------------------------------------------------------------------------- checking the files
def _rate(value, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= value <= 1.0:
        raise StageError(f"{where}: success rate must be a number in [0, 1] (got {value!r})")
    return float(value)


def _count(value, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise StageError(f"{where}: must be a positive integer (got {value!r})")
    return value


def _grid(value, where: str) -> list[int]:
    """Increasing env-step counts from 0; integral floats (e.g. 500.0) are taken as ints."""
    ok = (
        isinstance(value, list)
        and bool(value)
        and all(not isinstance(g, bool) and isinstance(g, (int, float)) and float(g).is_integer() for g in value)
    )
    grid = [int(g) for g in value] if ok else []
    if not ok or grid[0] != 0 or any(b <= a for a, b in zip(grid, grid[1:])):
        raise StageError(f"{where}: expected increasing env-step counts starting at 0 (got {value!r})")
    return grid


def _check_header(data: dict, k: int, wf: Workflow, where: str) -> list[str]:
    if data.get("stage") != k:
        raise StageError(f"{where}: stage: expected {k} (got {data.get('stage')!r})")
    expected = wf.tasks[:k]
    if data.get("task_ids") != expected:
        raise StageError(
            f"{where}: task_ids: expected the workflow's tasks 1..{k} {expected} (got {data.get('task_ids')!r})"
        )
    return list(expected)


def _rates_of(data: dict, key: str, tasks: list[str], where: str) -> dict:
    rates = data.get(key)
    if not isinstance(rates, dict):
        raise StageError(f"{where}: {key}: expected an object task id -> success")
    absent = [t for t in tasks if t not in rates]
    if absent:
        raise StageError(f"{where}: {key}: no entry for task {absent[0]}")
    return rates


def parse_curves(data: dict, k: int, wf: Workflow, where: str, record: str, artifact: str) -> StageCurves:
    tasks = _check_header(data, k, wf, where)
    grid = _grid(data.get("grid"), f"{where}: grid")
    success = _curves_of(data, "success", tasks, grid, where)
    episodes = _count(data.get("episodes_per_point"), f"{where}: episodes_per_point")
    if "report_success" not in data:  # a run from before the selection/report split
        return StageCurves(k, tasks, grid, success, episodes, record, artifact)
    report = _curves_of(data, "report_success", tasks, grid, where)
    report_episodes = _count(data.get("report_episodes"), f"{where}: report_episodes")
    return StageCurves(k, tasks, grid, success, episodes, record, artifact, report, report_episodes)


def _curves_of(data: dict, key: str, tasks: list[str], grid: list[int], where: str) -> dict[str, list]:
    """Per task, one success rate per grid point; an earlier task's points may be null (a run that scored
    earlier tasks only at the chosen checkpoint: rl_loop.LoopSettings.full_curves), the current task's not."""
    rates = _rates_of(data, key, tasks, where)
    out = {}
    for t in tasks:
        curve = rates[t]
        if not isinstance(curve, list) or len(curve) != len(grid):
            raise StageError(
                f"{where}: {key}[{t}]: expected {len(grid)} values, one per grid point "
                f"(got {len(curve) if isinstance(curve, list) else type(curve).__name__})"
            )
        earlier = t != tasks[-1]
        out[t] = [None if v is None and earlier else _rate(v, f"{where}: {key}[{t}][{e}]") for e, v in enumerate(curve)]
    return out


def parse_eval(data: dict, k: int, wf: Workflow, where: str, record: str, artifact: str) -> StageEval:
    tasks = _check_header(data, k, wf, where)
    success = _rates_of(data, "success", tasks, where)
    base = _rates_of(data, "base_success", tasks, where)
    return StageEval(
        k,
        tasks,
        {t: _rate(success[t], f"{where}: success[{t}]") for t in tasks},
        {t: _rate(base[t], f"{where}: base_success[{t}]") for t in tasks},
        _count(data.get("episodes"), f"{where}: episodes"),
        record,
        artifact,
    )


# ------------------------------------------------------------------------- the whole run
def load_run(store: Store, wf: Workflow) -> RunData:
    """Everything committed for wf; StageError when not even stage 1's learning curves exist."""
    run = RunData(workflow=wf)
    for k in range(1, wf.num_stages + 1):
        for step, parse in ((TRAIN, parse_curves), (EVALUATE, parse_eval)):
            ref = step_ref(wf.name, k, step)
            found = read_step_file(store, ref, step)
            if found is None:
                run.missing.append(Missing(k, step, ref))
                continue
            data, record, artifact = found
            parsed = parse(data, k, wf, ref, record, artifact)
            if step == EVALUATE:
                run.evals[k] = parsed
            elif run.stages_done == k - 1:  # metrics need stages 1..m without a gap
                run.curves.append(parsed)
    if not run.curves:
        raise StageError(
            f"workflow {wf.name} has no committed evaluations yet: stage 1 step {TRAIN} has "
            f"no record (ref {step_ref(wf.name, 1, TRAIN)}); run `accrue stage run WORKFLOW "
            f"--stage 1` first"
        )
    return run
