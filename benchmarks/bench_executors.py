"""Ray vs one-after-another on real cells (a script, not a test): two disjoint parts of one bench spec's
grid whose cells cost the same (the same methods, other seeds), one part run with `--serial`, the other
on local Ray, both in the given store (their shared demos and fine-tunes already cached there, so both
parts do the same kind of work: warmup, train, evaluate-all, handoff per stage). Prints and writes cells
per hour of each, Ray's start-up, and the ratio.

    .venv/bin/python benchmarks/bench_executors.py workflows/bench/nist-small.yaml --store runs/bench/store \
        --methods sequential --serial-seeds 0 --ray-seeds 1 2 [--out benchmarks/results/bench_executors.json]

Every cell of both parts must be unfinished (a finished cell would be skipped and flatter its part). Run
it on an otherwise idle machine: the figure is the scheduler's, not the load's (load averages recorded).
benchmarks/bench_grid.py measures the same on tiny cells, where fixed costs dominate.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import platform
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def run_part(spec, store, methods: list[str] | None, seeds: list[int], executor: str, logs: Path) -> dict:
    from rich.console import Console

    from stages.bench.execute import run_bench, start_ray
    from stages.bench.spec import select_cells
    from stages.bench.state import is_done

    cells = select_cells(spec, methods=methods, seeds=seeds)
    done = [c.name for c in cells if is_done(store, c)]
    if done:
        raise SystemExit(
            f"error: {executor} part: {len(done)} cells already finished ({done[0]} ...); pick other seeds"
        )
    load_before = os.getloadavg()[0]
    init_s = 0.0
    if executor == "ray":
        t = time.monotonic()
        start_ray(None, None)
        init_s = time.monotonic() - t
    t = time.monotonic()
    results = run_bench(spec, store, executor=executor, cells=cells, console=Console(file=io.StringIO()), logs_dir=logs)
    wall = time.monotonic() - t
    if executor == "ray":
        import ray

        ray.shutdown()
    failed = [r.cell.name for r in results if r.state != "done"]
    if failed:
        raise SystemExit(f"error: {executor} part: cells failed: {failed}")
    return {
        "executor": executor,
        "seeds": seeds,
        "cells": [r.cell.name for r in results],
        "cell_seconds": [round(r.seconds, 1) for r in results],
        "wall_s": round(wall, 1),
        "ray_init_s": round(init_s, 1),
        "cells_per_hour": round(len(results) / wall * 3600, 2),
        "cells_per_hour_incl_startup": round(len(results) / (wall + init_s) * 3600, 2),
        "load_average_before": round(load_before, 2),
        "load_average_after": round(os.getloadavg()[0], 2),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("spec", type=Path)
    ap.add_argument("--store", type=Path, required=True)
    ap.add_argument("--methods", nargs="+", default=None, help="only these methods of the spec (both parts)")
    ap.add_argument("--serial-seeds", type=int, nargs="+", required=True)
    ap.add_argument("--ray-seeds", type=int, nargs="+", required=True)
    ap.add_argument("--logs", type=Path, default=ROOT / "runs" / "bench" / "executors-logs")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "bench_executors.json")
    args = ap.parse_args()
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    from artifacts.errors import StoreError
    from artifacts.store import Store
    from stages.bench.spec import load_spec
    from stages.errors import StageError

    try:
        spec, store = load_spec(args.spec), Store.open(args.store)
    except (StageError, StoreError) as exc:
        raise SystemExit(f"error: {exc}") from None
    if set(args.serial_seeds) & set(args.ray_seeds):
        raise SystemExit("error: --serial-seeds and --ray-seeds must not overlap")
    serial = run_part(spec, store, args.methods, args.serial_seeds, "serial", args.logs)
    ray_part = run_part(spec, store, args.methods, args.ray_seeds, "ray", args.logs)
    figures = {
        "command": "python benchmarks/bench_executors.py " + " ".join(sys.argv[1:]),
        "spec": str(args.spec),
        "methods": args.methods,
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform()},
        "serial": serial,
        "ray": ray_part,
        "ray_over_serial": round(ray_part["cells_per_hour"] / serial["cells_per_hour"], 3),
        "ray_over_serial_incl_startup": round(ray_part["cells_per_hour_incl_startup"] / serial["cells_per_hour"], 3),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(figures, indent=2) + "\n")
    for part in (serial, ray_part):
        print(
            f"{part['executor']:>6}: {len(part['cells'])} cells in {part['wall_s']:.0f} s "
            f"(+{part['ray_init_s']:.0f} s start) = {part['cells_per_hour']:.1f} cells/h; "
            f"load {part['load_average_before']} -> {part['load_average_after']}"
        )
    print(f"Ray / serial: x{figures['ray_over_serial']} (x{figures['ray_over_serial_incl_startup']} with Ray's start)")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
