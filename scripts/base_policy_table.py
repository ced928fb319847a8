"""Fine-tune the embedded base policy stage by stage on a task sequence and print its success table.

For each task k of the sequence: write scripted demos for task k, fine-tune on D^1..D^k (starting
from the previous stage's checkpoint), and measure the base policy's success on every task so far.
The defaults are the quickstart's (workflows/quickstart.yaml): 20 demonstrations per task from the
non-searching demonstrator that corrects 75% of its fixture's bias, 800 steps of 64, lr 1e-3.

    .venv/bin/python scripts/base_policy_table.py --expert-episodes
    .venv/bin/python scripts/base_policy_table.py --init embedded-act --lr 5e-4 --batch-size 32
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from accrue.policy import EMBEDDED_DEFAULT, BasePolicy, FinetuneSettings, finetune
from accrue.policy.rollout import evaluate_success
from accrue.sim import expert_success_rate
from accrue.sim.demos import write_demos


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tasks", default="nist/rect_peg,nist/round_peg,nist/gear")
    parser.add_argument("--demos", type=int, default=20, help="scripted demos per task")
    parser.add_argument("--steps", type=int, default=800)
    parser.add_argument("--batch-size", type=int, default=64)
    parser.add_argument("--lr", type=float, default=1e-3)
    parser.add_argument(
        "--init", default=EMBEDDED_DEFAULT, help="from-scratch policy name (embedded-mlp, embedded-act)"
    )
    parser.add_argument("--retention", type=float, default=1.0)
    parser.add_argument(
        "--search",
        action="store_true",
        help="demos from the searching expert (default: the quickstart's non-searching one)",
    )
    parser.add_argument(
        "--bias-known",
        type=float,
        default=0.75,
        help="fraction of the fixture bias the demonstrator corrects (quickstart: 0.75)",
    )
    parser.add_argument(
        "--expert-episodes",
        action="store_true",
        help="also measure the demonstrator itself over --episodes episodes per task",
    )
    parser.add_argument("--horizon", type=int, default=4, help="H: actions executed per chunk (quickstart: 4)")
    parser.add_argument("--chunk-size", type=int, default=None, help="ACT chunk size (default: H, as the stages do)")
    parser.add_argument("--num-workers", type=int, default=2)
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("runs/base_policy_table"))
    args = parser.parse_args()

    tasks = [t.strip() for t in args.tasks.split(",") if t.strip()]
    settings = FinetuneSettings(
        steps=args.steps,
        batch_size=args.batch_size,
        lr=args.lr,
        seed=args.seed,
        retention=args.retention,
        chunk_size=args.chunk_size or args.horizon,
        num_workers=args.num_workers,
    )
    args.out.mkdir(parents=True, exist_ok=True)
    demo_dirs: list[Path] = []
    init: Path | str = args.init
    rows = []
    print(
        f"{'stage':>5} {'task':<18} {'demos':>5} {'frames':>6} {'finetune_s':>10} {'steps/s':>7}  success per task so far"
    )
    for stage, task_id in enumerate(tasks, start=1):
        demo_dir = args.out / "demos" / task_id.replace("/", "_")
        if not (demo_dir / "meta" / "info.json").is_file():
            write_demos(
                task_id,
                args.demos,
                demo_dir,
                seed=args.seed + stage,
                progress=False,
                search=args.search,
                bias_known=args.bias_known,
                max_attempts=10 * args.demos,
            )
        demo_dirs.append(demo_dir)
        ckpt = args.out / f"stage{stage}"
        start = time.perf_counter()
        finetune(init, demo_dirs, ckpt, settings)
        wall = time.perf_counter() - start
        record = json.loads((ckpt / "accrue_finetune.json").read_text())
        used = sum(len(e) for e in record["training_set"]["episodes_per_dataset"])
        policy = BasePolicy.load(ckpt, seed=args.seed)
        results = [evaluate_success(policy, t, episodes=args.episodes, horizon=args.horizon) for t in tasks[:stage]]
        cells = "  ".join(f"{r.task_id}={r.rate:.2f}" for r in results)
        if args.expert_episodes:
            # the demonstrator itself, acting every control step, on the same evaluation episodes
            rate = expert_success_rate(
                task_id, args.episodes, seed=10_000, search=args.search, bias_known=args.bias_known
            )
            cells += f"  (demonstrator on {task_id}: {rate:.2f})"
        print(
            f"{stage:>5} {task_id:<18} {used:>5} {record['training_set']['total_frames']:>6} "
            f"{wall:>10.1f} {args.steps / wall:>7.1f}  {cells}",
            flush=True,
        )
        rows.append(
            {
                "stage": stage,
                "task": task_id,
                "demos_used": used,
                "finetune_wall_s": wall,
                "success": {r.task_id: r.rate for r in results},
            }
        )
        init = ckpt
    (args.out / "table.json").write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
