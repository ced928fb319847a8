"""The rows of issue 19's speed table, one command each, written to benchmarks/results/perf.json.

    .venv/bin/python benchmarks/perf_report.py --row finetune   # finetune-base fixed cost
    .venv/bin/python benchmarks/perf_report.py --row cell       # a quickstart-scale 3-stage cell, fine-tunes cached
    .venv/bin/python benchmarks/perf_report.py --row update     # ACCRUE update vs the plain FastTD3 reference
    .venv/bin/python benchmarks/perf_report.py --row eval       # evaluation episodes/s vs raw env stepping
    .venv/bin/python benchmarks/perf_report.py --row grid --store S   # issue 18's grid, projected from store S
    .venv/bin/python benchmarks/perf_report.py --row model   # the same grid from benchmarks/cost_model.py's coefficients
    .venv/bin/python benchmarks/perf_report.py --row all

Each row is stored with the command that made it, the machine's core count and load average before and
after (a shared machine only ever slows a figure down), and whether Python could cache bytecode (without
it, every process compiles torch and lerobot again: ~10 s here).
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
ACCRUE = [sys.executable, "-m", "cli.main"]
QUICKSTART = ROOT / "workflows" / "quickstart.yaml"
OUT = ROOT / "benchmarks" / "results" / "perf.json"


def machine() -> dict:
    return {
        "cores": os.cpu_count(),
        "load_avg_1min": round(os.getloadavg()[0], 2),
        "bytecode_cached": not os.environ.get("PYTHONDONTWRITEBYTECODE"),
    }


def accrue(store: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "ACCRUE_STORE": str(store), "HF_HUB_OFFLINE": "1", "MUJOCO_GL": "egl", "RERUN": "off"}
    return subprocess.run([*ACCRUE, *args], cwd=ROOT, env=env, capture_output=True, text=True, check=True)


# --------------------------------------------------------------------------- finetune
class DirCache:
    """A training-set cache in a directory (the step's is the store; the figure is the same)."""

    def __init__(self, root: Path) -> None:
        self.root = root

    def _path(self, key: dict) -> Path:
        import hashlib

        return self.root / hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()

    def find(self, key: dict) -> Path | None:
        return self._path(key) if self._path(key).is_dir() else None

    def keep(self, key: dict, root: Path) -> None:
        shutil.copytree(root, self._path(key))


def bare_loop_seconds(checkpoint: Path, steps: int, batch: int, lr: float, threads: int) -> float:
    """The same gradient steps in a plain torch loop: the checkpoint's MLP widths, AdamW, L1, random rows."""
    import torch
    from torch import nn

    config = json.loads((checkpoint / "config.json").read_text())
    widths = [sum(f["shape"][0] for f in config["input_features"].values()), *config["hidden_dims"]]
    out = config["chunk_size"] * config["output_features"]["action"]["shape"][0]
    saved = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        layers: list[nn.Module] = []
        for a, b in zip(widths, widths[1:]):
            layers += [nn.Linear(a, b), nn.ReLU()]
        net = nn.Sequential(*layers, nn.Linear(widths[-1], out))
        opt = torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=config.get("optimizer_weight_decay", 0.0))
        g = torch.Generator().manual_seed(0)
        xs, ys = torch.rand(16, batch, widths[0], generator=g), torch.rand(16, batch, out, generator=g)
        start = time.perf_counter()
        for i in range(steps):
            loss = (net(xs[i % 16]) - ys[i % 16]).abs().mean()
            loss.backward()
            nn.utils.clip_grad_norm_(net.parameters(), 10.0)
            opt.step()
            opt.zero_grad()
        return time.perf_counter() - start
    finally:
        torch.set_num_threads(saved)


def quickstart_demos(work: Path) -> Path:
    """Stage 1's recorded demonstrations of the quickstart (record-demos in a fresh store)."""
    from artifacts.manifests import materialize
    from artifacts.resolve import resolve
    from artifacts.store import Store

    store = work / "store"
    accrue(store, "init")
    accrue(store, "stage", "run", str(QUICKSTART), "--stage", "1", "--step", "record-demos")
    st = Store.open(store)
    record = st.read_json(resolve(st, "workflow/quickstart/stage/1/record-demos"))
    return materialize(st, record["outputs"]["demos"], work / "demos")


def row_finetune(args) -> dict:
    with tempfile.TemporaryDirectory(prefix="perf-ft-") as tmp:
        work = Path(tmp)
        demos = quickstart_demos(work)
        started = time.perf_counter()
        import lerobot.scripts.lerobot_train  # noqa: F401 - the imports a process pays once

        import accrue.policy.train_inprocess  # noqa: F401
        from accrue.policy import FinetuneSettings, finetune

        imports_s = time.perf_counter() - started
        settings = FinetuneSettings(steps=args.steps, batch_size=64, lr=1e-3, seed=0, chunk_size=4)
        cache = DirCache(work / "cache")
        times = {}
        for name, kw in (
            ("in_process_training_set_built_s", {"training_sets": cache}),
            ("in_process_training_set_cached_s", {"training_sets": cache}),
            (
                "lerobot_train_subprocess_s",
                {"settings": FinetuneSettings(**{**settings.__dict__, "trainer": "lerobot-train"})},
            ),
        ):
            t = time.perf_counter()
            finetune("embedded-mlp", [demos], work / name, **{"settings": settings, **kw})
            times[name] = round(time.perf_counter() - t, 2)
        bare = round(bare_loop_seconds(work / "in_process_training_set_cached_s", args.steps, 64, 1e-3, 1), 2)
    return {
        "what": f"finetune-base of embedded-mlp on the quickstart's stage-1 demos, {args.steps} steps of 64, "
        "1 torch thread; fixed cost = time minus the same steps in a bare torch loop",
        "imports_once_per_process_s": round(imports_s, 2),
        **times,
        "bare_torch_loop_s": bare,
        "fixed_cost_cached_s": round(times["in_process_training_set_cached_s"] - bare, 2),
        "fixed_cost_built_s": round(times["in_process_training_set_built_s"] - bare, 2),
        "fixed_cost_subprocess_s": round(times["lerobot_train_subprocess_s"] - bare, 2),
        "goal_fixed_cost_s": 5.0,
    }


# --------------------------------------------------------------------------- cell
def step_attempts(store: Path) -> list[dict]:
    """Every step attempt that started, in order, from the store's event log: its workflow (the cell), stage,
    step and seconds (None when it never committed: cut off, or still running). A step found in the cache
    has no attempt, so it costs its cell nothing."""
    from datetime import datetime

    attempts, by_key = [], {}
    for line in (store / "log" / "events.jsonl").read_text().splitlines():
        event = json.loads(line)
        key = (event.get("cache_key"), event.get("attempt"))
        if event.get("event") == "step-started":
            by_key[key] = {
                "workflow": event.get("workflow"),
                "stage": event.get("stage"),
                "step": event.get("step"),
                "seconds": None,
                "ts": event["ts"],
            }
            attempts.append(by_key[key])
        elif event.get("event") == "step-committed" and key in by_key and by_key[key]["seconds"] is None:
            a = by_key[key]
            a["seconds"] = (datetime.fromisoformat(event["ts"]) - datetime.fromisoformat(a["ts"])).total_seconds()
    for a in attempts:
        del a["ts"]
    return attempts


def committed_attempts(store: Path) -> list[dict]:
    """The step attempts that committed (see step_attempts)."""
    return [a for a in step_attempts(store) if a["seconds"] is not None]


def step_seconds(store: Path) -> list[list]:
    """[step, seconds] of every step attempt that ran, in order, from the store's event log."""
    return [[a["step"], round(a["seconds"], 1)] for a in committed_attempts(store)]


def row_cell(args) -> dict:
    """Two cells that share fine-tunes: accrue fills the store, sequential then finds every fine-tune cached."""
    with tempfile.TemporaryDirectory(prefix="perf-cell-") as tmp:
        store = Path(tmp) / "store"
        accrue(store, "init")
        budget = ["--budget", str(args.budget)] if args.budget != 1.0 else []
        t = time.perf_counter()
        accrue(store, "run", str(QUICKSTART), *budget)
        first = time.perf_counter() - t
        other = Path(tmp) / "quickstart-sequential.yaml"
        other.write_text(QUICKSTART.read_text().replace("method: accrue", "method: sequential", 1))
        t = time.perf_counter()
        summary = json.loads(accrue(store, "run", str(other), *budget, "--json").stdout)
        second = time.perf_counter() - t
        steps = step_seconds(store)
    cached = sorted({f"{r['stage']}/{r['step']}" for r in summary if r["cached"]})
    return {
        "what": "quickstart (3 stages) with accrue, then the same cell with method sequential in the same store "
        f"(its record-demos and finetune-base cached), budget {args.budget}",
        "first_cell_s": round(first, 1),
        "cell_with_finetunes_cached_s": round(second, 1),
        "cached_steps_of_second_cell": cached,
        "step_seconds": steps,
        "goal_cell_s": 60.0,
    }


# --------------------------------------------------------------------------- update
def _bench_learner(*extra: str) -> tuple[list[str], dict]:
    cmd = [sys.executable, str(ROOT / "benchmarks" / "bench_learner.py"), "--threads", "1", *extra]
    out = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=True).stdout
    ratios = {}
    for line in out.splitlines():
        if "updates/s" in line:
            ratios[line.split("(critic")[0].strip()] = float(line.rsplit("(", 1)[1].split("x")[0])
    return [line for line in out.splitlines() if "updates/s" in line or line.startswith("device=")], ratios


def row_update(args) -> dict:
    eager_out, eager = _bench_learner()
    compiled_out, compiled = _bench_learner("--compile")
    return {
        "what": "benchmarks/bench_learner.py --threads 1 (CPU defaults: batch 256, hidden 256x256, 101 atoms), "
        "then with --compile (accrue's loss functions compiled; the reference stays eager)",
        "output": eager_out,
        "output_compiled": compiled_out,
        "accrue_vs_reference": eager.get("accrue.learner ACCRUE update"),
        "sequential_vs_reference": eager.get("accrue.learner sequential update"),
        "accrue_compiled_vs_eager_reference": compiled.get("accrue.learner ACCRUE update"),
        "goal_ratio": 1.0,
    }


# --------------------------------------------------------------------------- eval
def row_eval(args) -> dict:
    """Evaluator.success_rate vs a raw loop stepping the same env the same number of chunks, same policy."""
    import numpy as np

    from accrue import rl_loop
    from accrue.scripted_reference import ScriptedReference
    from stages.steps.common import make_env, reference_fn

    task, episodes, num_envs, horizon = "nist/rect_peg", args.episodes, 8, 4
    policy = ScriptedReference(0.5)
    reference = reference_fn(policy, task, horizon)
    features = lambda obs: obs["state"]  # noqa: E731
    calls = []

    def counted_env(t, n):
        env = make_env(t, n, 0, "state")
        step = env.step_chunk

        def step_chunk(a, gamma):
            calls.append(1)
            return step(a, gamma)

        env.step_chunk = step_chunk
        return env

    evaluator = rl_loop.Evaluator(counted_env, {task: reference}, features, episodes, num_envs, horizon, 0.99)
    env = make_env(task, num_envs, 0, "state")
    evaluator.success_rate(task)  # warm: env built, first episodes
    eval_s, raw_s = [], []
    for _ in range(3):  # interleaved, best of 3: a shared machine only ever slows a run down
        calls.clear()
        t = time.perf_counter()
        evaluator.success_rate(task)
        eval_s.append(time.perf_counter() - t)
        chunks = len(calls)
        obs = env.reset()
        t = time.perf_counter()
        for _ in range(chunks):
            a = rl_loop.execute_reference(features(obs), reference(obs), np.ones(num_envs, bool))
            res = env.step_chunk(np.asarray(a, np.float32), 0.99)
            done = res.terminated | res.truncated
            obs = env.reset(done) if done.any() else res.obs
        raw_s.append(time.perf_counter() - t)
    evaluator.close()
    env.close()
    eval_s, raw_s = min(eval_s), min(raw_s)
    return {
        "what": f"{episodes} evaluation episodes of {task} with the scripted reference (bias 0.5) on {num_envs} "
        "envs, against the same number of step_chunk calls on the same env in a bare loop with the same policy",
        "episodes_per_s": round(episodes / eval_s, 2),
        "raw_equivalent_episodes_per_s": round(episodes / raw_s, 2),
        "ratio": round(raw_s / eval_s, 3),
        "chunks_stepped": chunks,
        "goal_ratio": 0.8,
    }


# --------------------------------------------------------------------------- grid
GRID_SPECS = ("contact-headline", "contact-ablations", "bias-control")  # issue 18's full grid


def project_grid(specs: list, done: dict[str, bool], spent: dict[str, float], cores: int) -> dict:
    """Issue 18's grid on `cores` cores, from the cells run so far. A cell's cost is what its own committed
    steps took (steps it found in the cache cost it nothing). A cell costs, from scratch, the mean of the
    run cells of its spec and method; else of its spec; else of every run cell. The measured cells ran
    `cores` at a time, so the grid's wall time is the sum over cells / cores."""
    measured: dict[tuple[str, str], list[float]] = {}
    for spec in specs:
        for c in spec.cells:
            if done.get(c.name) and spent.get(c.name, 0.0) > 0:
                measured.setdefault((spec.name, c.method), []).append(spent[c.name])
    if not measured:
        raise SystemExit("error: no cell of the grid has run in this store: nothing to project from")
    mean = lambda xs: sum(xs) / len(xs)  # noqa: E731
    every = [x for xs in measured.values() for x in xs]
    full = left = 0.0
    borrowed = set()
    for spec in specs:
        in_spec = [x for (name, _), xs in measured.items() if name == spec.name for x in xs]
        for c in spec.cells:
            own = measured.get((spec.name, c.method))
            if not own:
                borrowed.add(f"{spec.name}/{c.method}")
            cost = mean(own or in_spec or every)
            full += cost
            left += 0.0 if done.get(c.name) else cost
    return {
        "cells": sum(len(spec.cells) for spec in specs),
        "cells_done": sum(1 for spec in specs for c in spec.cells if done.get(c.name)),
        "cells_measured": len(every),
        "measured_core_h": round(sum(every) / 3600, 2),
        "mean_cell_min": {f"{s}/{m}": round(mean(xs) / 60, 1) for (s, m), xs in sorted(measured.items())},
        "costed_from_other_methods": sorted(borrowed),
        "full_grid_h": round(full / cores / 3600, 1),
        "remaining_h": round(left / cores / 3600, 1),
        "cores_for_8h": round(full / 8 / 3600, 1),
        "goal_h": 8.0,
    }


def cell_costs(attempts: list[dict]) -> tuple[dict[str, float], set[str]]:
    """Seconds per cell (workflow) of its committed steps, and the cells with a cut-off attempt. Such a cell
    resumed from a checkpoint: the work before the cut has no end time, so its committed steps under-state
    its cost, and it is left out (done, it still costs the grid nothing more)."""
    cut = {a["workflow"] for a in attempts if a["seconds"] is None}
    spent: dict[str, float] = {}
    for a in attempts:
        if a["seconds"] is not None and a["workflow"] not in cut:
            spent[a["workflow"]] = spent.get(a["workflow"], 0.0) + a["seconds"]
    return spent, cut


def row_grid(args) -> dict:
    from artifacts.store import Store
    from stages.bench.spec import load_spec
    from stages.bench.state import cell_states

    if args.store is None or not (args.store / "objects").is_dir():
        raise SystemExit("error: the grid row reads a bench store: give --store DIR (an accrue store)")
    store = Store.open(args.store)
    attempts = step_attempts(args.store)
    spent, cut = cell_costs(attempts)
    specs = [load_spec(ROOT / "workflows" / "bench" / f"{name}.yaml") for name in GRID_SPECS]
    done = {name: st.state == "done" for spec in specs for name, st in cell_states(store, spec).items()}
    return {
        "what": f"issue 18's grid ({', '.join(GRID_SPECS)}) on {os.cpu_count()} cores, projected from the cells "
        "run in the store without a cut-off attempt (their committed steps' wall times; as many cells at a time "
        "as cores)",
        "cells_cut_off": len(cut),
        **project_grid(specs, done, spent, os.cpu_count() or 1),
    }


# --------------------------------------------------------------------------- model
def row_model(args) -> dict:
    """Issue 18's grid projected by issue 48's cost model (benchmarks/cost_model.py) from its committed
    coefficients, under the old and the new evaluation protocol; `python benchmarks/cost_model.py --measure`
    re-measures them."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import cost_model

    coef, dated = cost_model.committed(cost_model.OUT)
    proj = cost_model.projections(list(GRID_SPECS), coef)
    loads = [v["load_avg_1min"] for part in ("physics", "learner") for v in coef[part].values()]
    return {
        "what": f"issue 18's grid ({', '.join(GRID_SPECS)}) projected from benchmarks/results/cost_model.json's "
        "coefficients (physics, learner updates, finetune, overhead): cells one core each, steps shared through "
        "the step cache paid once; old protocol = every task at every grid point, new = earlier tasks once",
        **dated,
        "coefficients_load_avg_1min": [min(loads), max(loads)],
        "cell_min": {name: p["cell_min"] for name, p in proj.items()},
        "full_grid_h": proj["full grid"]["grid_h"],
        "core_h": proj["full grid"]["core_h_cache_shared"],
        "goal_h": 10.0,
    }


ROWS = {
    "finetune": row_finetune,
    "cell": row_cell,
    "update": row_update,
    "eval": row_eval,
    "grid": row_grid,
    "model": row_model,
}
README = ROOT / "docs" / "benchmark" / "speed.md"  # the page whose speed table --doc rewrites
MARKERS = ("<!-- perf-table:start -->", "<!-- perf-table:end -->")


def software() -> dict:
    """What a row was measured with: a figure from another Python or lerobot is another figure."""
    from importlib.metadata import version

    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    return {
        "commit": commit.stdout.strip() or None,
        "python": ".".join(map(str, sys.version_info[:3])),
        "lerobot": version("lerobot"),
        "torch": version("torch"),
    }


def software_line(results: dict) -> str:
    seen = sorted({(r["software"]["python"], r["software"]["lerobot"]) for r in results.values() if r.get("software")})
    if not seen:
        return "the rows do not record the Python and lerobot they ran on"
    return "measured with " + "; ".join(f"Python {py} / lerobot {lr}" for py, lr in seen)


def _figure(results: dict, row: str, key: str, unit: str = "", fmt: str = "{:.1f}") -> str:
    value = results.get(row, {}).get(key)
    return "not measured" if value is None else fmt.format(value) + unit


ENV_STEP = ROOT / "benchmarks" / "results" / "env_step.json"


def _train_share(cell: dict) -> str:
    steps = cell.get("step_seconds") or []
    total = sum(s for _, s in steps)
    train = sum(s for name, s in steps if name == "train")
    if not total:
        return "no step times stored"
    return f"`train` (the RL budget itself) is {train / total:.0%} of its steps' time: the goal needs a smaller budget"


def _physics_share() -> str:
    """The share of an evaluation control step that MuJoCo's physics takes on the contact tasks, measured by
    benchmarks/bench_env_step.py (its JSON, if committed)."""
    if not ENV_STEP.is_file():
        return "physics share not measured"
    tasks = json.loads(ENV_STEP.read_text())["current"]["tasks"]
    shares = [t["share"]["physics"] for name, t in tasks.items() if name.startswith("contact/")]
    return f"physics is {min(shares) * 100:.0f}–{max(shares):.0%} of an evaluation step on the contact tasks"


def why_not_met(results: dict, row: str, figure: float | None, goal: float, higher_is_better: bool = False) -> str:
    """'met', or the measured reason it is not (each from a stored measurement, not from prose)."""
    if figure is None:
        return "not measured"
    if (figure >= goal) if higher_is_better else (figure <= goal):
        return "met"
    if row == "cell":
        return _train_share(results["cell"])
    if row == "grid":
        g = results["grid"]
        return (
            f"needs ~{g['cores_for_8h']:.0f} cores at the measured cell cost; a cell's evaluation is bound by MuJoCo: "
            f"{_physics_share()} (`python benchmarks/bench_env_step.py --json`)"
        )
    return "not met"


def readme_table(results: dict) -> str:
    """The docs' speed table, from perf.json: the figure before the speed work, the measured one, its goal, met or
    the measured reason it is not, and its command."""

    def cmd(row: str) -> str:
        return f"`{results[row]['command']}`" if row in results else f"`python benchmarks/perf_report.py --row {row}`"

    def value(row: str, key: str) -> float | None:
        return results.get(row, {}).get(key)

    ft, grid = results.get("finetune", {}), results.get("grid", {})
    rows = [
        (
            "quickstart `accrue run` (3 stages)",
            "440 s",
            _figure(results, "cell", "first_cell_s", " s", "{:.0f}"),
            "≤ 240 s",
            why_not_met(results, "cell", value("cell", "first_cell_s"), 240),
            cmd("cell"),
        ),
        (
            "finetune-base fixed cost (time − the same steps in a bare torch loop)",
            "~50 s",
            f"{_figure(results, 'finetune', 'fixed_cost_cached_s', ' s')} (training set cached), "
            f"{_figure(results, 'finetune', 'fixed_cost_built_s', ' s')} (built); lerobot-train subprocess in "
            f"the same run: {_figure(results, 'finetune', 'fixed_cost_subprocess_s', ' s')}",
            "≤ 5 s",
            why_not_met(results, "finetune", ft.get("fixed_cost_cached_s"), 5) + " (training set cached)",
            cmd("finetune"),
        ),
        (
            "a quickstart-scale 3-stage cell, fine-tunes cached",
            "~4–5 min",
            _figure(results, "cell", "cell_with_finetunes_cached_s", " s", "{:.0f}"),
            "≤ 60 s",
            why_not_met(results, "cell", value("cell", "cell_with_finetunes_cached_s"), 60),
            cmd("cell"),
        ),
        (
            "ACCRUE update vs plain FastTD3 reference, CPU",
            "0.97×",
            f"{_figure(results, 'update', 'accrue_vs_reference', '×', '{:.2f}')} eager; "
            f"{_figure(results, 'update', 'accrue_compiled_vs_eager_reference', '×', '{:.2f}')} with "
            "`learner.compile: true` (the reference eager)",
            "≥ 1.0×",
            why_not_met(results, "update", value("update", "accrue_compiled_vs_eager_reference"), 1.0, True)
            + " (compiled)",
            cmd("update"),
        ),
        (
            "evaluation episodes/s vs raw env stepping, same policy",
            "not measured",
            _figure(results, "eval", "ratio", "×", "{:.2f}"),
            "≥ 0.8×",
            why_not_met(results, "eval", value("eval", "ratio"), 0.8, True),
            cmd("eval"),
        ),
        (
            "ACCRUE update on a GPU, batch ≥ 4096",
            "not measured",
            "not measured (no GPU lent)",
            "≥ 1.5×",
            "not measured on a GPU yet; the script runs on CPU in CI",
            "`python benchmarks/gpu_path.py`",
        ),
        (
            "the benchmark's full contact grid on this machine",
            "~30 h (projection)",
            f"{_figure(results, 'grid', 'full_grid_h', ' h')} projected for {grid.get('cells', '?')} cells from "
            f"{grid.get('cells_measured', '?')} run ({grid.get('measured_core_h', '?')} core-h)"
            if grid
            else "not measured",
            "≤ 8 h",
            why_not_met(results, "grid", value("grid", "full_grid_h"), 8),
            cmd("grid"),
        ),
    ]
    loads = sorted({results[r]["machine_before"]["load_avg_1min"] for r in results if "machine_before" in results[r]})
    lines = [
        f"Measured on a {ft.get('machine_before', {}).get('cores', 2)}-core machine **shared with other jobs** "
        f"(1-min load average {loads[0] if loads else '?'}–{loads[-1] if loads else '?'} at the rows' starts), "
        "so every figure is an upper bound on an idle machine's; written by `python benchmarks/perf_report.py --doc` "
        f"from `benchmarks/results/perf.json`; {software_line(results)}.",
        "",
        "| measure | before | measured | goal | met, or the measured reason not | command |",
        "|---|---|---|---|---|---|",
        *(f"| {' | '.join(r)} |" for r in rows),
    ]
    return "\n".join(lines)


def write_readme(results: dict) -> None:
    text = README.read_text(encoding="utf-8")
    start, end = text.index(MARKERS[0]) + len(MARKERS[0]), text.index(MARKERS[1])
    README.write_text(text[:start] + "\n" + readme_table(results) + "\n" + text[end:], encoding="utf-8")


def _measuring_args(argv: list[str]) -> list[str]:
    """argv without what does not change a figure (--note TEXT, --out FILE, --doc)."""
    kept, skip = [], False
    for a in argv:
        if skip:
            skip = False
        elif a in ("--note", "--out"):
            skip = True
        elif not (a.startswith(("--note=", "--out=")) or a in ("--doc", "--readme")):
            kept.append(a)
    return kept


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--row", choices=[*ROWS, "all"], help="measure this row (or all) and store it")
    ap.add_argument(
        "--doc",
        "--readme",
        dest="readme",
        action="store_true",
        help="rewrite the speed table in docs/benchmark/speed.md",
    )
    ap.add_argument("--steps", type=int, default=800, help="finetune: gradient steps (quickstart: 800)")
    ap.add_argument("--budget", type=float, default=1.0, help="cell: the workflows' --budget (1.0 = the quickstart)")
    ap.add_argument("--episodes", type=int, default=64, help="eval: episodes per measurement")
    ap.add_argument("--store", type=Path, help="grid: the store the bench cells ran in")
    ap.add_argument("--note", default="", help="stored with the row (e.g. 'machine shared with 4 other jobs')")
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args()
    results = json.loads(args.out.read_text()) if args.out.is_file() else {}
    if args.row is None and not args.readme:
        ap.error("give --row and/or --doc")
    every = [r for r in ROWS if r != "grid" or args.store is not None]  # `all` includes grid given a store
    for name in [] if args.row is None else every if args.row == "all" else [args.row]:
        before = machine()
        t = time.perf_counter()
        row = ROWS[name](args)
        row.update(
            command=shlex.join(["python", "benchmarks/perf_report.py", *_measuring_args(sys.argv[1:])]),
            machine_before=before,
            machine_after=machine(),
            software=software(),
            wall_s=round(time.perf_counter() - t, 1),
            note=args.note,
            date=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        )
        results[name] = row
        print(json.dumps({name: row}, indent=2), flush=True)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(results, indent=2) + "\n")
    if args.readme:
        write_readme(results)


if __name__ == "__main__":
    main()
