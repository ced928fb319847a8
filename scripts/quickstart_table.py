"""The quickstart over several seeds: run what is missing, then tabulate mean and range per task, the
stage-start figures (the inherited actor at env step 0 next to the base policy alone), and the paper's
metrics. The quickstart table in docs/benchmark/quickstart.md is this script's output, not typed.

    .venv/bin/python scripts/quickstart_table.py --seeds 0 1 2 --doc   # into docs/benchmark/quickstart.md
    .venv/bin/python scripts/quickstart_table.py --seeds 0 1 2 --variant old-norm \
        --set learner.obs_norm_update=every-stage --set learner.obs_norm_min_std=0 --set learner.obs_norm_clip=0

Every seed runs as its own workflow (`quickstart-s<seed>-<variant>`) in its seed's store (--store, with
{seed} in the path), so variants of the learner reuse the seed's demonstrations and fine-tuned base
policies through the step cache. Re-running
resumes (committed steps are skipped). Results: benchmarks/results/quickstart-<variant>.json.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import statistics
import subprocess
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
START, END = "<!-- quickstart-table:start -->", "<!-- quickstart-table:end -->"


def derived_workflow(base: Path, seed: int, variant: str, overrides: list[str], out_dir: Path) -> Path:
    data = yaml.safe_load(base.read_text())
    data["seed"] = seed
    data["name"] = f"{data['name']}-s{seed}-{variant}"
    for item in overrides:
        key, _, value = item.partition("=")
        node = data
        *parents, leaf = key.split(".")
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = yaml.safe_load(value)
    path = out_dir / f"{data['name']}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def run_workflow(path: Path, store: Path) -> None:
    env = dict(os.environ, ACCRUE_STORE=str(store), OMP_NUM_THREADS=os.environ.get("OMP_NUM_THREADS", "1"))
    accrue = [sys.executable, "-m", "cli.main"]
    if not (store / "config").exists():
        subprocess.run(accrue + ["init"], check=True, env=env, cwd=ROOT)
    subprocess.run(accrue + ["run", str(path), "--continue", "--wait"], check=True, env=env, cwd=ROOT)


def summarize(path: Path, store: Path) -> dict:
    from artifacts.store import Store
    from stages.report.data import load_run
    from stages.report.summary import summarize as summary_of
    from stages.workflow import load_workflow

    wf = load_workflow(path)
    run = load_run(Store(store), wf)
    s = summary_of(run)
    # stage-start: task k at stage k, env step 0 (the inherited actor with π_base^k), next to π_base^k alone
    s["stage_start"] = [
        {
            "stage": st["stage"],
            "task": st["task"],
            "actor_at_e0": st["success"][st["task"]][0],
            "base_alone": next(e["base_success"][st["task"]] for e in s["evaluations"] if e["stage"] == st["stage"]),
        }
        for st in s["stages"]
    ]
    return s


def spread(values: list[float]) -> dict:
    return {"mean": statistics.fmean(values), "min": min(values), "max": max(values), "n": len(values)}


def fmt(d: dict) -> str:
    return f"{d['mean']:.2f} ({d['min']:.2f}–{d['max']:.2f})"


def aggregate(summaries: list[dict]) -> dict:
    tasks = summaries[0]["tasks"]
    per_task = {
        t: {
            key: spread([next(p for p in s["per_task"] if p["task"] == t)[key] for s in summaries])
            for key in ("base_success", "after_rl_success", "best_in_own_stage")
        }
        for t in tasks
    }
    stage_start = {}
    for k in range(2, len(tasks) + 1):
        rows = [next(r for r in s["stage_start"] if r["stage"] == k) for s in summaries]
        stage_start[k] = {
            "task": rows[0]["task"],
            "actor_at_e0": spread([r["actor_at_e0"] for r in rows]),
            "base_alone": spread([r["base_alone"] for r in rows]),
        }
    metrics = {
        m: spread([s["metrics"][m] for s in summaries])
        for m in summaries[0]["metrics"]
        if all(s["metrics"][m] is not None for s in summaries)
    }
    return {"per_task": per_task, "stage_start": stage_start, "metrics": metrics}


def markdown(result: dict) -> str:
    agg, seeds = result["aggregate"], result["seeds"]
    lines = [
        f"Seeds {', '.join(map(str, seeds))}; mean (min–max) over seeds; 100 evaluation episodes per task "
        f"and point. Made by `{result['command']}`.",
        "",
        "| task | base policy alone | base + RL actor | best during its stage |",
        "|---|---|---|---|",
    ]
    for t, row in agg["per_task"].items():
        lines.append(
            f"| {t} | {fmt(row['base_success'])} | **{fmt(row['after_rl_success'])}** | "
            f"{fmt(row['best_in_own_stage'])} |"
        )
    lines += [
        "",
        "At the start of each later stage (env step 0), on the new task:",
        "",
        "| stage | task | inherited actor + new base | new base alone |",
        "|---|---|---|---|",
    ]
    for k, row in agg["stage_start"].items():
        lines.append(f"| {k} | {row['task']} | {fmt(row['actor_at_e0'])} | {fmt(row['base_alone'])} |")
    lines += ["", "Metrics (paper Sec. V-A): " + ", ".join(f"{m} {fmt(v)}" for m, v in agg["metrics"].items()) + "."]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--workflow", type=Path, default=ROOT / "workflows" / "quickstart.yaml")
    ap.add_argument(
        "--store",
        default=str(ROOT / "runs" / "quickstart-seeds" / "store-s{seed}"),
        help="store directory; {seed} is replaced by the seed",
    )
    ap.add_argument("--variant", default="main", help="a name for the overrides (part of workflow names)")
    ap.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="workflow override, dotted path, YAML value (repeatable)",
    )
    ap.add_argument("--no-run", action="store_true", help="only tabulate what the store already has")
    ap.add_argument(
        "--doc",
        "--readme",
        dest="readme",
        action="store_true",
        help="rewrite the table in docs/benchmark/quickstart.md",
    )
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()

    summaries = []
    for seed in args.seeds:
        store = Path(args.store.format(seed=seed))
        store.parent.mkdir(parents=True, exist_ok=True)
        path = derived_workflow(args.workflow, seed, args.variant, args.overrides, store.parent)
        if not args.no_run:
            run_workflow(path, store)
        summaries.append(summarize(path, store))
    command = "python scripts/quickstart_table.py " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    result = {
        "command": command.strip(),
        "workflow": str(args.workflow.relative_to(ROOT)),
        "seeds": args.seeds,
        "variant": args.variant,
        "overrides": args.overrides,
        "aggregate": aggregate(summaries),
        "runs": [
            {k: s[k] for k in ("workflow", "seed", "metrics", "per_task", "stage_start", "success_matrix")}
            for s in summaries
        ],
    }
    out = args.out or ROOT / "benchmarks" / "results" / f"quickstart-{args.variant}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1) + "\n")
    table = markdown(result)
    print(table)
    if args.readme:
        readme = ROOT / "docs" / "benchmark" / "quickstart.md"
        text = readme.read_text()
        if START not in text or END not in text:
            sys.exit(f"error: {readme.relative_to(ROOT)} has no {START} ... {END} block")
        head, rest = text.split(START, 1)
        readme.write_text(head + START + "\n" + table + "\n" + END + rest.split(END, 1)[1])


if __name__ == "__main__":
    from stages.errors import StageError

    try:
        main()
    except subprocess.CalledProcessError as exc:  # accrue already printed its one-line error
        sys.exit(f"error: {' '.join(map(str, exc.cmd[3:]))} exited with {exc.returncode}")
    except StageError as exc:
        sys.exit(f"error: {exc}")
