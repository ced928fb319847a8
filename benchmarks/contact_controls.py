"""Scripted controls on the contact family and its successor contact2, on the same episodes: how far each
scripted controller gets, so that a new family version can be held to the old one's figures.

    .venv/bin/python benchmarks/contact_controls.py [--tasks ...] [--episodes 100] [--seeds 0 1]
        [--controllers ...] [--out benchmarks/results/contact_controls.json]

Controllers (each acts every control step on the current observation):

    demonstrator  the scripted expert that never searches (make_expert(search=False)): the base policy's
                  demonstrator on the contact family
    search        the searching expert (its wide search on these tasks)
    compliance    the demonstrator plus a memoryless contact response that reads only the current wrist
                  force and the episode clock: while the part presses on something outside the hole it
                  presses lightly and yields sideways along the lateral contact force, and while it presses
                  on anything it twists its yaw on a clock-driven sine (issue 52's force/clock controller,
                  rebuilt here from its description: none was committed)
    dither_0.2    the demonstrator plus white noise of std 0.2 on every action dimension, clipped to [-1, 1]
    dither_0.5    the same with std 0.5 (issue 52: noise alone is a strong strategy in this simulator)

Each rate is over `episodes` parallel episodes per seed (env i's first episode seeded (seed, i, 0), so task
contact/<name> and contact2/<name> start from the same poses and draw the same errors), pooled over the
seeds. The JSON keeps every seed's rate, the pooled rate, and per task pair the difference new - old.
Rows merge into an existing --out file (one run per family or controller keeps each run short).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "contact_controls.json"
NAMES = ["round_peg", "keyed_peg", "gear_mesh", "rect_peg"]
TASKS = [f"{family}/{name}" for family in ("contact", "contact2") for name in NAMES]
CONTROLLERS = ["demonstrator", "search", "compliance", "dither_0.2", "dither_0.5"]
YIELD_PER_N = 0.25e-3  # m of sideways yield per N of lateral contact force (compliance)


class Compliance:
    """The demonstrator plus a contact response that depends on the current force and the clock only."""

    def __init__(self, task_id: str):
        from accrue.sim import get_task, make_expert

        self.task = get_task(task_id)
        self.demo = make_expert(task_id, search=False)
        self.twist, self.rate = self.demo.reach_yaw, self.demo.yaw_rate

    def __call__(self, state: np.ndarray) -> np.ndarray:
        from accrue.sim.expert import CONTACT_FORCE, ENTERED, LIGHT_PRESS
        from accrue.sim.observation import decode_state, rotate_xy

        act = self.demo.act(state).astype(np.float64)
        d = decode_state(state)
        force_xy = rotate_xy(d["force"][:, :2], d["yaw"])
        fz = np.abs(d["force"][:, 2])
        outside = d["pos"][:, 2] - d["est_pos"][:, 2] > -ENTERED
        touching = fz > CONTACT_FORCE
        pressing = touching & outside
        clock = d["time_frac"] * self.task.max_steps
        yielded = (d["est_pos"][:, :2] - d["pos"][:, :2] - force_xy * YIELD_PER_N) / self.task.max_delta_pos
        act[:, :2] = np.where(pressing[:, None], yielded, act[:, :2])
        act[:, 2] = np.where(pressing, np.where(fz > LIGHT_PRESS, 0.25, -0.25), act[:, 2])
        if self.task.yaw_symmetry != 0:  # twist while blocked, outside the hole or jammed inside it
            act[:, 5] += np.where(touching, self.twist * np.sin(self.rate * clock) / self.task.max_delta_rot, 0.0)
        return np.clip(act, -1.0, 1.0).astype(np.float32)


def controller(name: str, task_id: str, seed: int):
    from accrue.sim import make_expert

    if name == "demonstrator":
        return make_expert(task_id, search=False).act
    if name == "search":
        return make_expert(task_id).act
    if name == "compliance":
        return Compliance(task_id)
    if name.startswith("dither_"):
        sigma = float(name.split("_")[1])
        demo, rng = make_expert(task_id, search=False), np.random.default_rng([seed, int(round(sigma * 1000))])

        def noisy(state):
            act = demo.act(state)
            return np.clip(act + rng.normal(0.0, sigma, act.shape), -1.0, 1.0).astype(np.float32)

        return noisy
    raise SystemExit(f"unknown controller {name!r}; known: {', '.join(CONTROLLERS)}")


def success_rate(task_id: str, name: str, episodes: int, seed: int) -> float:
    from accrue.sim import make_vec_env

    env = make_vec_env(task_id, num_envs=episodes, seed=seed, nthread=1)
    act = controller(name, task_id, seed)
    obs, won, done = env.reset(), np.zeros(episodes, bool), np.zeros(episodes, bool)
    while not done.all():
        res = env.step(act(obs["state"]))
        won |= res.success & ~done
        done |= res.done
        obs = res.obs
    env.close()
    return float(won.mean())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", nargs="+", default=TASKS)
    ap.add_argument("--controllers", nargs="+", default=CONTROLLERS)
    ap.add_argument("--episodes", type=int, default=100, help="episodes per seed")
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from profile_contact_physics import commit_id

    commit = commit_id()
    result = json.loads(args.out.read_text()) if args.out.is_file() else {"runs": [], "tasks": {}}
    start = time.perf_counter()
    for task_id in args.tasks:
        row = result["tasks"].setdefault(task_id, {})
        for name in args.controllers:
            rates = [success_rate(task_id, name, args.episodes, s) for s in args.seeds]
            row[name] = {"per_seed": dict(zip(map(str, args.seeds), rates)), "rate": round(float(np.mean(rates)), 4)}
            row["commit"] = commit
            print(f"{task_id:20s} {name:13s} {row[name]['rate']:.3f}  (seeds {args.seeds})", flush=True)
        if "demonstrator" in row and "search" in row:
            row["skill_gap"] = round(row["search"]["rate"] - row["demonstrator"]["rate"], 4)
    pairs = {}
    for name in NAMES:
        old, new = result["tasks"].get(f"contact/{name}", {}), result["tasks"].get(f"contact2/{name}", {})
        shared = [
            c for c in CONTROLLERS if c in old and c in new and old[c]["per_seed"].keys() == new[c]["per_seed"].keys()
        ]
        pairs[name] = {c: round(new[c]["rate"] - old[c]["rate"], 4) for c in shared}
    result["contact2_minus_contact"] = pairs
    result["runs"].append(
        {
            "command": " ".join([Path(sys.executable).name, *sys.argv]),
            "commit": commit,
            "episodes_per_seed": args.episodes,
            "seeds": args.seeds,
            "seconds": round(time.perf_counter() - start, 1),
            "python": platform.python_version(),
            "cores": os.cpu_count(),
        }
    )
    result["seeding"] = "env i's first episode is seeded (seed, i, 0): contact/<name> and contact2/<name> share poses"
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
