"""A tiny hardware workflow on the simulated robot for the tests (not a test module itself)."""

from __future__ import annotations

from pathlib import Path

HW = """
name: {name}
tasks: [nist/rect_peg, nist/round_peg]
method: accrue
seed: 0
horizon: 4
base_policy: {{init: "scripted-reference:1.0"}}
learner: {{algo: fasttd3, actor_hidden: [32, 32], critic_hidden: [32, 32], projector_dim: 16, batch_size: 32,
          utd: 1, beta: 10.0, std_max: 0.05}}
budgets: {{env_steps: 1000, eval_every: 1000, warmup_episodes: 3, retained_episodes: 5}}
robot:
  type: accrue_sim
  config: {{calibration_dir: {calib}, estimate_noise: 0.3}}
  operator: scripted
  operator_name: scripted-test
  scripted: {scripted}
  clock: {clock}
  faults: {faults}
  timeouts: {{observation_s: 0.5, reconnect_wait_s: 0.0}}
  retention_trials: 3
  checkpoint_every: 20
  publish_every: 10
"""


def write_hw_workflow(
    path: Path, calib: Path, name: str = "hw", clock: float = 0, faults: str = "{}", scripted: str = "{}"
) -> Path:
    path.write_text(HW.format(name=name, calib=calib, clock=clock, faults=faults, scripted=scripted))
    return path


def run_stage(store_path: Path, workflow: Path, stage: int, step: str | None = None, mode: str = "normal"):
    """The stage in this process (lerobot and torch are imported once per test process)."""
    from rich.console import Console

    from artifacts.store import Store
    from stages.plan import plan_stage
    from stages.runner import Runner
    from stages.workflow import load_workflow

    store = Store.open(store_path)
    wf = load_workflow(workflow)
    runner = Runner(store, console=Console(stderr=True, width=200))
    return {r.step: r for r in runner.run_plan(plan_stage(wf, stage, store), only_step=step, mode=mode)}


def robot_events(store_path: Path, name: str | None = None) -> list[dict]:
    from artifacts.auditlog import iter_events
    from artifacts.store import Store

    return [
        e
        for e in iter_events(Store.open(store_path))
        if e.get("event", "").startswith("robot-") and (name is None or e["event"] == name)
    ]


def cli_report_json(store_path: Path, workflow: Path, out: Path) -> dict:
    """`accrue report WORKFLOW --out OUT --json` in a fresh process (the way a user runs it), its JSON summary;
    tests/ is on the path so a test arm's lerobot plugin (tests/fake_arms.py) loads there too."""
    import json
    import os
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[1]
    env = {
        **os.environ,
        "ACCRUE_STORE": str(store_path),
        "PYTHONPATH": os.pathsep.join([str(root), str(root / "tests")]),
        "HF_HUB_OFFLINE": "1",
    }
    done = subprocess.run(
        [sys.executable, "-m", "cli.main", "report", str(workflow), "--out", str(out), "--json"],
        cwd=root,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout)
