"""`accrue bench` end to end on local Ray (one Ray session for the module): a tiny spec (two methods x two
seeds, a hundred env steps, the scripted stand-in reference as base policy) runs through, a failing cell
is retried, reported, and does not stop the others; a bench killed mid-run (`kill -9` of the process
that drives it) finishes only the missing cells when run again, leaving the finished ones untouched."""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from rich.console import Console

from artifacts.refs import read_ref
from artifacts.store import Store
from stages.bench.execute import run_bench, start_ray
from stages.bench.report import build_report
from stages.bench.spec import load_spec
from stages.bench.state import cell_states, counts, is_done
from stages.runner import step_ref
from stages.runner_types import STEP_NAMES

pytestmark = pytest.mark.slow  # Ray's start-up and a few real cells: ~1.5 min on an idle 2-core machine
ROOT = Path(__file__).resolve().parents[1]
TASKS = ["nist/rect_peg", "nist/gear"]
BASE = {
    "name": "tiny",
    "tasks": TASKS,
    "method": "accrue",
    "horizon": 4,
    "task_features": 8,
    "base_policy": {"init": "scripted-reference:0.0"},
    "learner": {
        "actor_hidden": [32, 32],
        "critic_hidden": [32, 32],
        "projector_dim": 16,
        "batch_size": 32,
        "num_atoms": 11,
        "utd": 1,
    },
    "budgets": {
        "env_steps": 96,
        "eval_every": 48,
        "eval_episodes": 2,
        "num_envs": 2,
        "warmup_episodes": 1,
        "retained_episodes": 2,
        "checkpoint_every": 0,
        "log_episodes": 0,
    },
}
BROKEN = {"method": "accrue", "base_policy": {"init": "embedded-mlp", "demos": {t: "no-such-demos" for t in TASKS}}}


def write_spec(root: Path, name: str, seeds: list[int], broken: bool = False) -> Path:
    (root / "tiny.yaml").write_text(yaml.safe_dump(BASE))
    methods = {"accrue": {}, "sequential": {}, **({"broken": BROKEN} if broken else {})}
    path = root / f"{name}.yaml"
    path.write_text(
        yaml.safe_dump(
            {"base": "tiny.yaml", "methods": methods, "orderings": {"A": TASKS}, "seeds": seeds, "retries": 1}
        )
    )
    return path


@pytest.fixture(scope="module")
def ray_address():
    ray = pytest.importorskip("ray")
    start_ray(None, 2)  # the bench's own start: retried when a busy machine delays it
    yield ray.get_runtime_context().gcs_address
    ray.shutdown()


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    return Store.init(tmp_path_factory.mktemp("bench") / "store")[0]


def quiet() -> Console:
    return Console(file=io.StringIO())


def step_records(store: Store, cell) -> dict:
    return {(k, s): read_ref(store, step_ref(cell.name, k, s)) for k in (1, 2) for s in STEP_NAMES}


def test_tiny_grid_on_ray_with_a_failing_method(ray_address, store, tmp_path):
    spec = load_spec(write_spec(tmp_path, "grid", [0, 1], broken=True))
    results = run_bench(spec, store, executor="ray", console=quiet(), logs_dir=tmp_path / "logs")
    by_state = {(r.cell.method, r.cell.seed): r for r in results}
    for method in ("accrue", "sequential"):
        for seed in (0, 1):
            r = by_state[(method, seed)]
            assert r.state == "done" and r.tries == 1 and is_done(store, r.cell)
    for seed in (0, 1):
        r = by_state[("broken", seed)]
        assert r.state == "failed" and r.tries == 2 and "no-such-demos" in r.error
    # the second method reused the first one's steps that do not depend on the method
    assert by_state[("sequential", 0)].steps_cached > 0
    assert counts(cell_states(store, spec)) == {"done": 4, "running": 0, "failed": 2, "partial": 0, "pending": 0}
    report = build_report(store, spec)
    runs = {m["method"]: m["runs"] for m in report["aggregate"]["methods"]}
    assert runs == {"accrue": 2, "sequential": 2, "broken": 0}
    assert {m["method"] for m in report["missing"]} == {"broken"}
    assert (tmp_path / "logs" / f"{spec.cell('accrue', 'A', 0).name}.log").stat().st_size > 0
    # running it again does nothing for the finished cells (and tries the failed ones again)
    again = run_bench(spec, store, executor="ray", console=quiet(), logs_dir=tmp_path / "logs", retries=0)
    assert sorted(r.state for r in again) == ["failed"] * 2 + ["skipped"] * 4


def test_killed_bench_resumes_only_the_missing_cells(ray_address, store, tmp_path):
    path = write_spec(tmp_path, "resume", [2, 3])
    spec = load_spec(path)
    env = {**os.environ, "ACCRUE_STORE": str(store.root), "OMP_NUM_THREADS": "1"}
    with open(tmp_path / "bench.err", "w") as err:
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "cli.main",
                "bench",
                str(path),
                "--address",
                ray_address,
                "--logs",
                str(tmp_path / "logs"),
            ],
            cwd=ROOT,
            env=env,
            stdout=err,
            stderr=err,
            start_new_session=True,
        )
        deadline = time.monotonic() + 600
        while not any(is_done(store, c) for c in spec.cells):
            assert proc.poll() is None, (tmp_path / "bench.err").read_text()[-2000:]
            assert time.monotonic() < deadline, "no cell finished in 10 minutes"
            time.sleep(0.3)
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    finished = [c for c in spec.cells if is_done(store, c)]
    assert 0 < len(finished) < len(spec.cells), "the bench must be killed with cells still missing"
    before = {c.name: step_records(store, c) for c in finished}
    results = run_bench(spec, store, executor="ray", console=quiet(), logs_dir=tmp_path / "logs")
    assert {r.cell.name for r in results if r.state == "skipped"} == {c.name for c in finished}
    assert all(r.state in ("skipped", "done") for r in results)
    assert all(is_done(store, c) for c in spec.cells)
    for c in finished:  # finished cells: the very same committed records
        assert step_records(store, c) == before[c.name]
