"""Bench scheduler benchmark (a script, not a test): cells per hour of a tiny bench spec run on local
Ray (one cell per core) vs the same cells run one after another in one process (`--serial`), each in a
fresh store, so neither finds the other's cached steps; then Ray with one CPU (one cell at a time, like
serial), whose difference from serial is the scheduler's own cost. Prints both rates, Ray's start-up time, and the
rate with and without it; writes the figures as JSON (default benchmarks/results/bench_grid.json).

    nice -n 10 .venv/bin/python benchmarks/bench_grid.py [--seeds 3] [--env-steps 192] [--num-cpus N]

The tiny cells (two stages, the scripted stand-in reference as base policy, a few hundred env steps)
make the fixed costs per cell (imports, step bookkeeping, Ray) visible: a scheduler that costs more than
it gives shows up here first.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
TASKS = ["nist/rect_peg", "nist/gear"]


def write_spec(root: Path, seeds: int, env_steps: int) -> Path:
    base = {
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
            "env_steps": env_steps,
            "eval_every": env_steps // 2,
            "eval_episodes": 4,
            "num_envs": 2,
            "warmup_episodes": 1,
            "retained_episodes": 2,
            "checkpoint_every": 0,
            "log_episodes": 0,
        },
    }
    (root / "tiny.yaml").write_text(yaml.safe_dump(base))
    spec = root / "grid.yaml"
    spec.write_text(
        yaml.safe_dump(
            {
                "base": "tiny.yaml",
                "methods": {"accrue": {}, "sequential": {}},
                "orderings": {"A": TASKS},
                "seeds": list(range(seeds)),
                "retries": 0,
            }
        )
    )
    return spec


def run(spec_path: Path, store_dir: Path, executor: str, num_cpus: int) -> dict:
    from rich.console import Console

    from artifacts.store import Store
    from stages.bench.execute import run_bench
    from stages.bench.spec import load_spec

    spec = load_spec(spec_path)
    store = Store.init(store_dir)[0]
    init_s = 0.0
    if executor == "ray":
        from stages.bench.execute import start_ray

        t = time.monotonic()
        start_ray(None, num_cpus)  # the bench's own start (retried when the machine is too busy)
        init_s = time.monotonic() - t
    t = time.monotonic()
    results = run_bench(
        spec,
        store,
        executor=executor,
        console=Console(file=io.StringIO()),
        logs_dir=store_dir.parent / f"logs-{executor}",
    )
    cells_s = time.monotonic() - t
    if executor == "ray":
        import ray

        ray.shutdown()
    failed = [r.cell.name for r in results if r.state != "done"]
    if failed:
        raise SystemExit(f"{executor}: cells failed: {failed}")
    n = len(results)
    per_cell = sorted(r.seconds for r in results)
    return {
        "executor": executor,
        "cells": n,
        "seconds_cells": round(cells_s, 2),
        "ray_init_s": round(init_s, 2),
        "cell_seconds_median": round(per_cell[n // 2], 2),
        "cell_seconds_sum": round(sum(per_cell), 2),
        "load_average_after": round(os.getloadavg()[0], 2),
        "cells_per_hour": round(n / cells_s * 3600, 1),
        "cells_per_hour_incl_startup": round(n / (cells_s + init_s) * 3600, 1),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3, help="seeds per method (2 methods): cells = 2 x seeds")
    ap.add_argument("--env-steps", type=int, default=192)
    ap.add_argument("--num-cpus", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "bench_grid.json")
    args = ap.parse_args()
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    with tempfile.TemporaryDirectory(prefix="bench-grid-") as tmp:
        root = Path(tmp)
        spec = write_spec(root, args.seeds, args.env_steps)
        serial = run(spec, root / "store-serial", "serial", args.num_cpus)
        ray_run = run(spec, root / "store-ray", "ray", args.num_cpus)
        # Ray with one CPU runs one cell at a time, like serial: the difference is the scheduler's own cost
        ray_one = run(spec, root / "store-ray-1", "ray", 1) if args.num_cpus > 1 else None
    speedup = ray_run["cells_per_hour"] / serial["cells_per_hour"]
    speedup_all = ray_run["cells_per_hour_incl_startup"] / serial["cells_per_hour"]
    print(
        f"{serial['cells']} tiny cells (2 stages, {args.env_steps} env steps each), {args.num_cpus} CPUs, "
        f"load average at the end {os.getloadavg()[0]:.1f}"
    )
    print(
        f"  serial (one process): {serial['seconds_cells']:7.1f} s  {serial['cells_per_hour']:7.1f} cells/hour"
        f"  (median cell {serial['cell_seconds_median']:.1f} s)"
    )
    print(
        f"  Ray (local):          {ray_run['seconds_cells']:7.1f} s  {ray_run['cells_per_hour']:7.1f} cells/hour"
        f"  (x{speedup:.2f}); with Ray's start-up ({ray_run['ray_init_s']:.1f} s): "
        f"{ray_run['cells_per_hour_incl_startup']:.1f} cells/hour (x{speedup_all:.2f}); median cell "
        f"{ray_run['cell_seconds_median']:.1f} s"
    )
    if ray_one is not None:
        print(
            f"  Ray, 1 CPU:           {ray_one['seconds_cells']:7.1f} s  {ray_one['cells_per_hour']:7.1f} cells/hour"
            f"  (x{ray_one['cells_per_hour'] / serial['cells_per_hour']:.2f}: the scheduler's own cost, "
            f"no parallelism)"
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(
        json.dumps(
            {
                "command": "nice -n 10 .venv/bin/python benchmarks/bench_grid.py " + " ".join(sys.argv[1:]),
                "machine": {
                    "cpus": os.cpu_count(),
                    "platform": platform.platform(),
                    "load_average_end": os.getloadavg(),
                },
                "seeds": args.seeds,
                "env_steps": args.env_steps,
                "num_cpus": args.num_cpus,
                "serial": serial,
                "ray": ray_run,
                "ray_one_cpu": ray_one,
                "speedup": round(speedup, 3),
                "speedup_incl_startup": round(speedup_all, 3),
            },
            indent=2,
        )
        + "\n"
    )
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
