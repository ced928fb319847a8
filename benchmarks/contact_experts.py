"""Scripted-expert success with and without search on the contact (shared-skill) and nist (negative-control)
families: the gap a contact skill can close, per task.

    .venv/bin/python benchmarks/contact_experts.py [--episodes 50] [--seed 0] [--speed]
        [--out benchmarks/results/contact_experts.json]

Each rate is one batch of `episodes` parallel episodes (one per env, seeded by (seed, env index, 0)), the
expert acting every control step. Rows: `search` (the searching expert; on contact tasks its wide search),
`no_search` (the limited demonstrator the base policy's demos come from: no search, and on nist the
workflows' 75% knowledge of the fixture bias), and on contact tasks `narrow_search` (the nist expert's
search: no rotation under contact, no light touch).

--speed adds env control steps/s (env.step only, 16 envs, one thread, episodes reset as they end) of each
task under the limited demonstrator and under the searching expert: a contact-heavy policy costs more
physics per step (more contact points while it searches), so both are given. Wall-clock figures: on a
shared machine they are indicative only.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

CONTACT = ["contact/round_peg", "contact/keyed_peg", "contact/gear_mesh", "contact/rect_peg"]
NIST = ["nist/rect_peg", "nist/round_peg", "nist/gear"]
DEMO_BIAS_KNOWN = 0.75  # workflows/quickstart.yaml's demonstrator on the nist tasks


def measure(task_id: str, episodes: int, seed: int) -> dict:
    from accrue.sim import expert_success_rate, get_task

    contact = get_task(task_id).family == "contact"
    limited = {"search": False} if contact else {"search": False, "bias_known": DEMO_BIAS_KNOWN}
    row = {"role": get_task(task_id).role}
    t0 = time.perf_counter()
    row["search"] = expert_success_rate(task_id, episodes, seed=seed)
    row["no_search"] = expert_success_rate(task_id, episodes, seed=seed, **limited)
    row["no_search_kwargs"] = limited
    if contact:
        row["narrow_search"] = expert_success_rate(task_id, episodes, seed=seed, wide=False)
    row["gap"] = round(row["search"] - row["no_search"], 4)
    row["seconds"] = round(time.perf_counter() - t0, 2)
    return row


def steps_per_s(task_id: str, search: bool, control_steps: int = 1200, num_envs: int = 16) -> float:
    import numpy as np

    from accrue.sim import make_expert, make_vec_env

    env = make_vec_env(task_id, num_envs=num_envs, seed=0, nthread=1)
    expert = make_expert(task_id, search=search)
    obs, done, executed, spent = env.reset(), np.zeros(num_envs, bool), 0, 0.0
    while executed < control_steps:
        if done.any():
            obs = env.reset(done)
        act = expert.act(obs["state"])
        t0 = time.perf_counter()
        res = env.step(act)
        spent += time.perf_counter() - t0
        executed += int(res.steps.sum())
        obs, done = res.obs, res.done
    env.close()
    return round(executed / spent, 1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=50)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--speed", action="store_true", help="also time env steps per task (shared machine: indicative)")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/contact_experts.json"))
    args = ap.parse_args()
    tasks = {}
    for task_id in CONTACT + NIST:
        tasks[task_id] = measure(task_id, args.episodes, args.seed)
        r = tasks[task_id]
        extra = f"  narrow {r['narrow_search']:.2f}" if "narrow_search" in r else ""
        print(
            f"{task_id:20s} {r['role']:17s} search {r['search']:.2f}  no search {r['no_search']:.2f}{extra}", flush=True
        )
        if args.speed:
            r["env_steps_per_s"] = {"no_search": steps_per_s(task_id, False), "search": steps_per_s(task_id, True)}
            print(f"{'':20s} env control steps/s (16 envs, 1 thread): {r['env_steps_per_s']}", flush=True)
    result = {
        "command": " ".join([Path(sys.executable).name, *sys.argv]),
        "episodes": args.episodes,
        "seed": args.seed,
        "seeding": "one batch per rate: env i's episode 0 is seeded by (seed, i, 0)",
        "python": platform.python_version(),
        "cpu_count": os.cpu_count(),
        **({"speed_note": "env.step wall clock on a machine shared with other jobs: indicative"} if args.speed else {}),
        "tasks": tasks,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
