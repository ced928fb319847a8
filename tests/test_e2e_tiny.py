"""A tiny two-stage workflow end to end through the CLI: every step commits, the artifacts follow the
report's format, a second run is a no-op, changing one setting re-runs exactly what reads it, a
handoff's lineage reaches the demos and the seed, and a `kill -9` during `train` followed by
`--continue` ends with the same artifact contents as a run that was never interrupted."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from test_runner_support import KILL_AT

ROOT = Path(__file__).resolve().parents[1]
ACCRUE = [sys.executable, "-m", "cli.main"]

TINY = """
name: {name}
tasks: [nist/rect_peg, nist/gear]
method: accrue
seed: {seed}
horizon: 4
task_features: 8
base_policy: {base_policy}
learner: {{actor_hidden: [32, 32], critic_hidden: [32, 32], projector_dim: 16, batch_size: 32, num_atoms: 11, utd: 1}}
budgets: {{env_steps: {env_steps}, eval_every: {eval_every}, eval_episodes: 2, num_envs: 2, warmup_episodes: 2,
          retained_episodes: {retained}, checkpoint_every: {ckpt}, log_episodes: 1}}
"""
FINETUNE = "{init: embedded-mlp, finetune_steps: 2, batch_size: 8, demos_per_task: 2}"


def write_workflow(
    path: Path, name="tiny", seed=3, base_policy=FINETUNE, env_steps=160, eval_every=80, retained=2, ckpt=0
) -> Path:
    path.write_text(
        TINY.format(
            name=name,
            seed=seed,
            base_policy=base_policy,
            env_steps=env_steps,
            eval_every=eval_every,
            retained=retained,
            ckpt=ckpt,
        )
    )
    return path


def accrue(store: Path, *args: str, check: bool = True) -> subprocess.CompletedProcess:
    env = {**os.environ, "ACCRUE_STORE": str(store), "OMP_NUM_THREADS": "1"}
    proc = subprocess.run([*ACCRUE, *args], cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    if check and proc.returncode != 0:
        raise AssertionError(f"accrue {' '.join(args)} exited {proc.returncode}:\n{proc.stderr[-3000:]}")
    return proc


def run_json(store: Path, *args: str) -> list[dict]:
    return json.loads(accrue(store, *args, "--json").stdout)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    root = tmp_path_factory.mktemp("e2e")
    store = root / "store"
    accrue(store, "init")
    wf = write_workflow(root / "tiny.yaml")
    results = run_json(store, "run", str(wf))
    return {"root": root, "store": store, "wf": wf, "results": results}


def artifact_dir(store: Path, ref: str, tmp: Path) -> Path:
    """Materialise an artifact through `accrue show`'s resolution (ids, refs, ref:role)."""
    from artifacts.manifests import materialize
    from artifacts.resolve import resolve
    from artifacts.store import Store

    st = Store.open(store)
    return materialize(st, resolve(st, ref), tmp / ref.replace("/", "_").replace(":", "_"))


def content_ids(store: Path, outputs: dict) -> dict:
    """role -> content id (the BLAKE3 of the artifact's bytes; a manifest id also carries its creation time)."""
    from artifacts.manifests import read_artifact
    from artifacts.store import Store

    st = Store.open(store)
    return {role: read_artifact(st, oid)["content"] for role, oid in outputs.items()}


def test_every_step_of_both_stages_commits_in_order(tiny):
    steps = [(r["stage"], r["step"]) for r in tiny["results"]]
    order = ["record-demos", "finetune-base", "cache-teacher", "warmup", "train", "evaluate-all", "handoff"]
    assert steps == [(k, s) for k in (1, 2) for s in order]
    assert not any(r["cached"] for r in tiny["results"])
    status = run_json(tiny["store"], "stage", "status", str(tiny["wf"]))
    assert {(r["stage"], r["step"]): r["state"] for r in status if r["step"] in order} == {
        (k, s): "committed" for k in (1, 2) for s in order
    }


def test_artifacts_follow_the_report_format(tiny, tmp_path):
    store = tiny["store"]
    curve = json.loads((artifact_dir(store, "workflow/tiny/stage/2/train:curve", tmp_path) / "curve.json").read_text())
    assert curve["stage"] == 2 and curve["task_ids"] == ["nist/rect_peg", "nist/gear"]
    assert curve["grid"] == [0, 80, 160] and curve["method"] == "accrue" and curve["seed"] == 3
    assert curve["episodes_per_point"] == 2 and curve["curves"] == "chosen"
    current, earlier = curve["success"]["nist/gear"], curve["success"]["nist/rect_peg"]
    assert len(current) == 3 and all(v in (0.0, 0.5, 1.0) for v in current)
    # the earlier task is scored once, at the stage's chosen checkpoint (no report set here: on this one)
    e = curve["chosen"]
    assert e == current.index(max(current)) and earlier[e] in (0.0, 0.5, 1.0)
    assert [v for i, v in enumerate(earlier) if i != e] == [None, None]
    ev = json.loads(
        (artifact_dir(store, "workflow/tiny/stage/2/evaluate-all:eval", tmp_path) / "eval.json").read_text()
    )
    assert ev["stage"] == 2 and set(ev["success"]) == set(ev["base_success"]) == set(curve["task_ids"])
    assert ev["episodes"] == 2 and ev["method"] == "accrue" and ev["seed"] == 3
    logs = artifact_dir(store, "workflow/tiny/stage/2/evaluate-all:episodes", tmp_path)
    assert len(list(logs.rglob("episode-*.mcap"))) == 2  # one logged episode per task
    teacher1 = json.loads(
        (artifact_dir(store, "workflow/tiny/stage/1/cache-teacher:teacher", tmp_path) / "teacher.json").read_text()
    )
    assert teacher1["skipped"] and "stage 1" in teacher1["reason"]
    teacher2 = json.loads(
        (artifact_dir(store, "workflow/tiny/stage/2/cache-teacher:teacher", tmp_path) / "teacher.json").read_text()
    )
    handoff1 = json.loads(
        (artifact_dir(store, "workflow/tiny/stage/1/handoff:handoff", tmp_path) / "handoff.json").read_text()
    )
    assert not teacher2["skipped"] and teacher2["rows"] == handoff1["memory_rows"] > 0
    handoff2 = json.loads(
        (artifact_dir(store, "workflow/tiny/stage/2/handoff:handoff", tmp_path) / "handoff.json").read_text()
    )
    assert handoff2["memory_tasks"] == [0, 1]  # B^{<3} holds both tasks


def test_a_second_run_is_a_no_op(tiny):
    again = run_json(tiny["store"], "run", str(tiny["wf"]))
    assert all(r["cached"] for r in again)
    assert [r["record"] for r in again] == [r["record"] for r in tiny["results"]]


def test_handoff_lineage_reaches_demos_and_seed(tiny):
    tree = json.loads(accrue(tiny["store"], "lineage", "workflow/tiny/stage/2/handoff:handoff", "--json").stdout)
    kinds, seeds = set(), []

    def walk(node):
        kinds.add(node.get("kind"))
        if node.get("kind") == "demos":
            seeds.append(node.get("seeds", {}))
        for child in node.get("inputs", {}).values():
            walk(child)

    walk(tree)
    assert {"handoff", "checkpoint", "replay", "base-policy", "demos"} <= kinds
    assert any(s.get("seed") == 3 for s in seeds)


def test_changing_one_setting_reruns_exactly_its_readers(tiny, tmp_path):
    wf = write_workflow(tmp_path / "tiny.yaml", retained=1)  # same name, N 2 -> 1
    results = run_json(tiny["store"], "run", str(wf))
    rerun = {(r["stage"], r["step"]) for r in results if not r["cached"]}
    # N is read by handoff; stage 2's teacher, train, evaluation and handoff read handoff 1
    assert rerun == {(1, "handoff"), (2, "cache-teacher"), (2, "train"), (2, "evaluate-all"), (2, "handoff")}
    run_json(tiny["store"], "run", str(tiny["wf"]))  # back to the original (all cached)


def events(store: Path) -> list[dict]:
    from artifacts.auditlog import iter_events
    from artifacts.store import Store

    return list(iter_events(Store.open(store)))


def test_kill_9_during_train_then_continue_matches_an_uninterrupted_run(tiny, tmp_path):
    store = tiny["store"]
    base = [r for r in tiny["results"] if r["stage"] == 1 and r["step"] == "finetune-base"][0]
    policy_id = base["outputs"]["base-policy"]
    wf = write_workflow(
        tmp_path / "resume.yaml",
        name="resume",
        seed=5,
        env_steps=640,
        eval_every=320,
        ckpt=80,
        base_policy=f"{{init: {policy_id}, finetune: false}}",
    )
    run_json(store, "stage", "run", str(wf), "--stage", "1", "--step", "warmup")
    env = {**os.environ, "ACCRUE_STORE": str(store), "OMP_NUM_THREADS": "1", KILL_AT: "1"}

    def checkpoints():
        return [e for e in events(store) if e.get("event") == "checkpoint-saved" and e.get("step") == "train"]

    before = len(checkpoints())
    # train SIGKILLs itself right after its first committed checkpoint (checkpoints are at least two
    # episodes of every env apart, so 640 env steps have one or two), through the runner tests' fault
    # hook: no timing window to hit or miss
    killed = subprocess.run(
        [sys.executable, str(ROOT / "tests" / "test_runner_support.py"), "accrue", "stage", "run", str(wf)]
        + ["--stage", "1", "--step", "train"],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert killed.returncode == -signal.SIGKILL, killed.stderr[-3000:]
    assert len(checkpoints()) == before + 1
    interrupted = accrue(store, "stage", "run", str(wf), "--stage", "1", "--step", "train", check=False)
    assert interrupted.returncode == 2 and "--continue" in interrupted.stderr
    resumed = run_json(store, "stage", "run", str(wf), "--stage", "1", "--step", "train", "--continue")[-1]
    assert not resumed["cached"]
    from artifacts.records import list_attempts
    from artifacts.store import Store

    trains = [a for a in list_attempts(Store.open(store)) if a.get("workflow") == "resume" and a["step"] == "train"]
    assert [a["state"] for a in trains] == ["abandoned", "committed"]
    assert trains[1]["resumed_from"] in {c["id"] for c in trains[0]["checkpoints"]}
    assert trains[1]["resumed_from"] == trains[0]["checkpoints"][-1]["id"] == checkpoints()[before]["checkpoint"]
    killed_at = [c["progress"]["env_steps"] for c in trains[0]["checkpoints"]]
    assert len(killed_at) == 1 and 0 < killed_at[0] < 640
    fresh = run_json(store, "stage", "run", str(wf), "--stage", "1", "--step", "train", "--rerun")[-1]
    assert content_ids(store, resumed["outputs"]) == content_ids(store, fresh["outputs"])
    # committed now: a plain run does not run train again
    again = run_json(store, "stage", "run", str(wf), "--stage", "1", "--step", "train")[-1]
    assert again["cached"]


@pytest.mark.parametrize(
    "yaml_text, budget, message",
    [
        ("tasks: [nist/nope]", None, "tasks[0]: unknown task 'nist/nope'"),
        ("budgets: {env_steps: 10, eval_every: 20}", None, "eval_every must be <= env_steps"),
        ("method: bogus", None, "method: must be one of"),
        ("learner: {beta: -1}", None, "learner.beta: must be non-negative"),
        ("", "-3", "--budget: must be positive"),
        ("", "lots", "--budget: expected a fraction"),
    ],
)
def test_bad_workflow_values_give_one_line_errors(tmp_path, yaml_text, budget, message):
    import yaml

    data = yaml.safe_load(write_workflow(tmp_path / "w.yaml").read_text())
    data.update(yaml.safe_load(yaml_text) or {})
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    store = tmp_path / "store"
    accrue(store, "init")
    args = ["run", str(path)] + (["--budget", budget] if budget else [])
    proc = accrue(store, *args, check=False)
    assert proc.returncode == 2, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0], proc.stderr
