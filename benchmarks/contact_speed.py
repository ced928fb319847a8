"""Control steps per second of every contact and contact2 task, per core: the evaluation setting and the
scripted controllers, each timed several times in one process (issue 48 item 2's bar: >= 2,000 per core).

    .venv/bin/python benchmarks/contact_speed.py [--tasks ...] [--repeats 3] [--episodes 24] [--json]

Settings, MuJoCo on one thread throughout:

    evaluation    rl_loop.Evaluator.success_rate as benchmarks/bench_env_step.py runs it (its inputs and
                  learner: workflows/contact-quickstart.yaml's history and geometry descriptor, 8 envs, H = 4,
                  a fresh fasttd3 actor refining the scripted reference's chunks, torch on one thread):
                  the whole loop, physics, env and policy, over `episodes` episodes
    demonstrator  env.step alone, 16 envs, the scripted expert that never searches, episodes reset as they
                  end, 800 control steps (as benchmarks/contact_experts.py --speed, which takes 1,200)
    search        the same with the searching expert (more time in contact)

Each figure is control steps / seconds, seconds being the process's CPU time (`cpu`: the per-core figure)
and the wall clock (`wall`: what a shared machine gave). Every setting of every task is timed `repeats`
times, tasks interleaved within a repeat so that a burst of load spreads over them; the JSON keeps every
run and reports the best and the median, with the load average around each repeat.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
OUT = ROOT / "benchmarks" / "results" / "contact_speed.json"
NAMES = ["round_peg", "keyed_peg", "gear_mesh", "rect_peg"]
TASKS = [f"{family}/{name}" for family in ("contact", "contact2") for name in NAMES] + ["nist/rect_peg"]
SETTINGS = ("evaluation", "demonstrator", "search")


class Clocks:
    """CPU and wall seconds of a callable's calls, and the control steps they report."""

    def __init__(self) -> None:
        self.cpu = self.wall = 0.0
        self.steps = 0

    def wrap(self, fn):
        def timed(*args, **kw):
            cpu, wall = time.process_time(), time.perf_counter()
            res = fn(*args, **kw)
            self.cpu += time.process_time() - cpu
            self.wall += time.perf_counter() - wall
            self.steps += int(res.steps.sum())
            return res

        return timed

    def rates(self) -> dict:
        return {"cpu": self.steps / self.cpu, "wall": self.steps / self.wall}


class Evaluation:
    """One Evaluator for all tasks (its envs kept), a fresh actor, as bench_env_step.measure builds them."""

    def __init__(self, tasks: list[str], episodes: int, num_envs: int, horizon: int, seed: int):
        from bench_env_step import FEATURES, LEARNER

        from accrue import rl_loop
        from accrue.learner import LearnerConfig, make_learner
        from accrue.scripted_reference import ScriptedReference
        from accrue.sim import make_vec_env
        from stages.steps.common import deterministic, per_task_features, reference_fn

        deterministic(seed)
        features = per_task_features(FEATURES, tasks)
        references = {t: reference_fn(ScriptedReference(0.75), t, horizon) for t in tasks}
        probe = make_vec_env(tasks[0], num_envs=1, seed=0, nthread=1)
        state_dim = features[tasks[0]](probe.reset()).shape[1]
        probe.close()
        learner = make_learner(LearnerConfig.from_dict({**LEARNER, "seed": seed}), state_dim, horizon)
        self.clocks: dict[str, Clocks] = {}

        def make(task_id: str, n: int):
            env = make_vec_env(task_id, num_envs=n, seed=rl_loop.env_seed(seed, 1, "eval", 0), nthread=1)
            env.step_chunk = self.clocks[task_id].wrap(env.step_chunk)
            return env

        self.evaluator = rl_loop.Evaluator(make, references, features, episodes, num_envs, horizon, 0.99)
        self.act = rl_loop.actor_act(learner)

    def rates(self, task_id: str) -> dict:
        """Control steps/s of one success_rate call: the loop's whole time, charged from step to step."""
        clocks = self.clocks[task_id] = self.clocks.get(task_id) or Clocks()
        self.evaluator.success_rate(task_id, self.act)  # builds the env, fills the caches (not counted)
        clocks.cpu = clocks.wall = 0.0
        clocks.steps = 0
        cpu, wall = time.process_time(), time.perf_counter()
        self.evaluator.success_rate(task_id, self.act)
        cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
        return {"cpu": clocks.steps / cpu, "wall": clocks.steps / wall}


def scripted(task_id: str, search: bool, control_steps: int = 800, num_envs: int = 16) -> dict:
    from accrue.sim import make_expert, make_vec_env

    env = make_vec_env(task_id, num_envs=num_envs, seed=0, nthread=1)
    expert = make_expert(task_id, search=search)
    clocks = Clocks()
    step = clocks.wrap(env.step)
    obs, done = env.reset(), np.zeros(num_envs, bool)
    while clocks.steps < control_steps:
        if done.any():
            obs = env.reset(done)
        res = step(expert.act(obs["state"]))
        obs, done = res.obs, res.done
    env.close()
    return clocks.rates()


def summary(runs: list[float]) -> dict:
    return {
        "best": round(max(runs), 1),
        "median": round(statistics.median(runs), 1),
        "runs": [round(r, 1) for r in runs],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", nargs="+", default=TASKS)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--episodes", type=int, default=16, help="evaluation episodes per task")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true", help=f"write {OUT.relative_to(ROOT)}")
    args = ap.parse_args()
    from profile_contact_physics import commit_id

    evaluation = Evaluation(args.tasks, args.episodes, num_envs=8, horizon=4, seed=args.seed)
    runs = {t: {s: {"cpu": [], "wall": []} for s in SETTINGS} for t in args.tasks}
    loads = []
    for r in range(args.repeats):
        before = round(os.getloadavg()[0], 2)
        for task_id in args.tasks:
            got = {
                "evaluation": evaluation.rates(task_id),
                "demonstrator": scripted(task_id, search=False),
                "search": scripted(task_id, search=True),
            }
            for setting, rates in got.items():
                for clock, value in rates.items():
                    runs[task_id][setting][clock].append(value)
            line = "  ".join(f"{s} {got[s]['cpu']:6.0f} ({got[s]['wall']:5.0f})" for s in SETTINGS)
            print(f"repeat {r + 1}  {task_id:20s} cpu (wall) steps/s: {line}", flush=True)
        loads.append(
            {"repeat": r + 1, "load_avg_1min_before": before, "load_avg_1min_after": round(os.getloadavg()[0], 2)}
        )
    tasks = {t: {s: {c: summary(v) for c, v in runs[t][s].items()} for s in SETTINGS} for t in args.tasks}
    print(f"\n{'task':20s} " + "  ".join(f"{s + ' cpu best/median':>26s}" for s in SETTINGS))
    for t, row in tasks.items():
        cells = "  ".join(f"{row[s]['cpu']['best']:>12.0f} / {row[s]['cpu']['median']:<11.0f}" for s in SETTINGS)
        print(f"{t:20s} {cells}")
    print(
        "load average (1 min) per repeat: "
        + ", ".join(f"{x['load_avg_1min_before']}->{x['load_avg_1min_after']}" for x in loads)
    )
    ratios = {}
    for name in NAMES:
        old, new = tasks.get(f"contact/{name}"), tasks.get(f"contact2/{name}")
        if old and new:
            ratios[name] = {s: round(new[s]["cpu"]["median"] / old[s]["cpu"]["median"], 2) for s in SETTINGS}
    if args.json:
        result = {
            "command": " ".join([Path(sys.executable).name, *sys.argv]),
            "date": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "commit": commit_id(),
            "machine": {"cores": os.cpu_count(), "python": platform.python_version(), "load": loads},
            "note": "cpu = control steps per CPU second of this process (per core); wall = per wall-clock second",
            "episodes_per_evaluation": args.episodes,
            "repeats": args.repeats,
            "tasks": tasks,
            "contact2_over_contact_cpu_median": ratios,
        }
        OUT.write_text(json.dumps(result, indent=2) + "\n")
        print(f"wrote {OUT.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
