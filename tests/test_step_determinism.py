"""Artifacts are functions of their inputs (issue 23, item 3): the same tiny two-stage workflow, with
the real embedded-mlp fine-tune, run in two stores at different paths — the second in another
process with another hash seed — gives, step by step, the same artifact ids: record-demos,
finetune-base, cache-teacher, warmup, train, evaluate-all and handoff of both stages. An artifact's
id covers its kind, content, inputs, config and code version, so no temp path, timestamp, host name
or process-dependent order (lerobot's stats.json) may reach any output's bytes."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
TINY = """
name: det
tasks: [nist/rect_peg, nist/gear]
method: accrue
seed: 3
horizon: 4
task_features: 8
base_policy: {init: embedded-mlp, finetune_steps: 2, batch_size: 8, demos_per_task: 2}
learner: {actor_hidden: [32, 32], critic_hidden: [32, 32], projector_dim: 16, batch_size: 32, num_atoms: 11, utd: 1}
budgets: {env_steps: 80, eval_every: 40, eval_episodes: 2, num_envs: 2, warmup_episodes: 2,
          retained_episodes: 2, checkpoint_every: 40, log_episodes: 1}
"""
STEPS = {"record-demos", "finetune-base", "cache-teacher", "warmup", "train", "evaluate-all", "handoff"}


def run_workflow(root: Path) -> dict[str, dict]:
    """'stage/step/role' -> {artifact, content} of every output of both stages, in a fresh store."""
    from rich.console import Console

    from artifacts.manifests import read_artifact
    from artifacts.store import Store
    from stages.plan import plan_stage
    from stages.runner import Runner
    from stages.workflow import load_workflow

    root.mkdir(parents=True)
    (root / "det.yaml").write_text(TINY)
    store = Store.init(root / "store")[0]
    wf = load_workflow(root / "det.yaml")
    runner = Runner(store, console=Console(stderr=True, width=200))
    ids = {}
    for stage in (1, 2):
        for r in runner.run_plan(plan_stage(wf, stage, store)):
            for role, oid in r.outputs.items():
                ids[f"{stage}/{r.step}/{role}"] = {"artifact": oid, "content": read_artifact(store, oid)["content"]}
    return ids


def test_every_step_gives_the_same_artifact_ids_in_two_stores(tmp_path, monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    first = run_workflow(tmp_path / "machine-a")
    code = (
        "import json, sys; sys.path.insert(0, 'tests'); from pathlib import Path; "
        "from test_step_determinism import run_workflow; "
        f"print(json.dumps(run_workflow(Path({str(tmp_path / 'elsewhere' / 'machine-b')!r}))))"
    )
    env = {**os.environ, "PYTHONHASHSEED": "12345", "OMP_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-3000:]
    second = json.loads(out.stdout.strip().splitlines()[-1])
    assert {k.split("/")[1] for k in first} == STEPS
    assert first.keys() == second.keys()
    same_bytes = [k for k in first if first[k]["content"] == second[k]["content"]]
    differ = sorted(
        f"{k} ({'same bytes, other manifest' if k in same_bytes else 'other bytes'})"
        for k in first
        if first[k]["artifact"] != second[k]["artifact"]
    )
    assert not differ, f"outputs whose artifact ids differ between two stores: {differ}"
