"""How far each stage's handed-over actor has moved from the base policy's chunks: per finished bench cell
and stage k, the deterministic actor π̄_θ^k is run on the states of task k that the stage kept in its
memory (its last N complete episodes) and compared with the reference chunks ã stored with them:

    drift = sqrt(mean over rows and chunk entries of (a − ã)²)      (actions live in [-1, 1])

Eq. 1's β‖a − ã‖² is what holds this down; the β = 0 ablation removes it. The figure says whether a
method's refinement stayed local, which the success rates alone do not.

    python benchmarks/actor_drift.py workflows/bench/nist-ablations.yaml --store runs/bench/store \
        --methods accrue,beta-paper,beta0 --out benchmarks/results/actor_drift.json

Prints one line per method and stage (mean over the cells, min–max), and writes every cell's figures to
--out. Exit 2 with one line on a bad spec, a missing store or an unknown method.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def handoff_dir(store, workflow: str, stage: int, dest: Path) -> Path:
    """The stage's committed handoff artifact, materialised under dest (a StoreError names what is missing)."""
    from artifacts.manifests import materialize
    from artifacts.resolve import resolve
    from stages.runner import step_ref

    artifact_id = resolve(store, f"{step_ref(workflow, stage, 'handoff')}:handoff")
    return materialize(store, artifact_id, dest / f"{workflow}-{stage}")


def stage_drift(handoff: Path, stage: int) -> dict | None:
    """None when the memory holds no row of this stage's task."""
    import torch

    from accrue.learner import ReplayBuffer
    from accrue.learner.state import load_learner
    from stages.steps.handoff import LEARNER_DIR, MEMORY_DIR

    learner = load_learner(handoff / LEARNER_DIR, device="cpu")
    memory = ReplayBuffer.load(handoff / MEMORY_DIR)
    rows = memory.column("task") == stage - 1  # task index of stage k is k − 1
    if not bool(rows.any()):
        return None
    state, ref = memory.column("state")[rows], memory.column("ref")[rows]
    action = torch.as_tensor(learner.act(state, ref, explore=False)).view_as(ref)
    return {"stage": stage, "rows": int(rows.sum()), "drift": float((action - ref).square().mean().sqrt())}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("spec", type=Path)
    ap.add_argument("--store", type=Path, default=None, help="store (default $ACCRUE_STORE or ./.accrue)")
    ap.add_argument("--methods", default=None, help="comma list (default: every method of the spec)")
    ap.add_argument("--out", type=Path, default=None, help="write every cell's figures here (JSON)")
    args = ap.parse_args(argv)

    from accrue.errors import AccrueError
    from artifacts.errors import StoreError
    from artifacts.store import Store
    from stages.bench.spec import load_spec, select_cells
    from stages.bench.state import cell_states
    from stages.errors import StageError

    try:
        store = Store.open(args.store)
        spec = load_spec(args.spec)
        cells = select_cells(spec, methods=args.methods.split(",") if args.methods else None)
        states = cell_states(store, spec)
        done = [c for c in cells if states[c.name].state == "done"]
        rows = []
        with tempfile.TemporaryDirectory() as tmp:
            for cell in done:
                for k in range(1, len(cell.tasks) + 1):  # a done cell has committed every stage
                    drift = stage_drift(handoff_dir(store, cell.name, k, Path(tmp)), k)
                    if drift is not None:
                        rows.append({"method": cell.method, "ordering": cell.ordering, "seed": cell.seed, **drift})
    except (AccrueError, StoreError, StageError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2

    print(f"actor drift from ã on each stage's kept states, RMS per chunk entry ({len(done)} cells of {args.spec})")
    for method in dict.fromkeys(r["method"] for r in rows):
        for k in sorted({r["stage"] for r in rows if r["method"] == method}):
            v = [r["drift"] for r in rows if r["method"] == method and r["stage"] == k]
            print(f"  {method:<20} stage {k}: {sum(v) / len(v):.3f} ({min(v):.3f}–{max(v):.3f}, {len(v)} cells)")
    if args.out is not None:
        command = "python benchmarks/actor_drift.py " + " ".join(argv if argv is not None else sys.argv[1:])
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({"command": command, "cells": rows}, indent=2) + "\n", encoding="utf-8")
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
