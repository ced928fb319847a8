"""Where an evaluation's control step goes: MuJoCo physics vs the Python/numpy around it (issue 19).

    .venv/bin/python benchmarks/bench_env_step.py [--episodes 24] [--tasks contact/round_peg ...] [--json]

Runs rl_loop.Evaluator.success_rate as a stage's evaluation does (workflows/contact-quickstart.yaml's
num_envs 8, horizon 4, history 4 and geometry descriptor, torch at the stages' one thread, the env's
default mujoco.batch thread count) with a fresh fasttd3 actor (256x256) refining the scripted reference's
chunks (the stand-in base policy: the workflows' embedded-mlp needs a fine-tune), and splits the wall time
by wrapping the calls:

    physics      VecAssemblyEnv.batch.step (the substeps, on mujoco.batch's C thread pool)
    reset        batch.reset + batch.forward at episode starts
    env python   the rest of step_chunk and reset: actions, noise draws, history, success checks, observe
    policy       features(obs), reference(obs), the actor's forward (act)
    evaluator    the rest of success_rate's loop

then replays every control step's recorded controls from the same episode starts on one MjData per
episode with a plain `mujoco.mj_step(model, data, nstep=substeps)` loop (that env's randomised model),
single-threaded: the bare-physics cost of the same steps. `--json` writes the figures to
benchmarks/results/env_step.json (a row per label, `--label`; perf_report.py's rows are its own commands).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "env_step.json"
TASKS = ["contact/round_peg", "contact/keyed_peg", "contact/gear_mesh", "nist/rect_peg"]
FEATURES = {"encoder": "none", "task_features": 0, "history": 4, "task_descriptor": "geometry"}  # contact-quickstart
LEARNER = {"algo": "fasttd3", "actor_hidden": [256, 256], "critic_hidden": [256, 256], "projector_dim": 64}


class Clock:
    """Accumulated seconds per part, and a wrapper that charges a callable's time to one."""

    def __init__(self) -> None:
        self.s: dict[str, float] = {}

    def wrap(self, part: str, fn):
        def timed(*args, **kw):
            t = time.perf_counter()
            try:
                return fn(*args, **kw)
            finally:
                self.s[part] = self.s.get(part, 0.0) + time.perf_counter() - t

        return timed


class Recorder:
    """Every env's episodes as (model, qpos, qvel, [ctrl per control step]), for the bare replay."""

    def __init__(self, env) -> None:
        self.env, self.episodes, self.open = env, [], {}

    def started(self, ids) -> None:
        for i in ids:
            i = int(i)
            if self.open.get(i, (None, None, None, []))[3]:
                self.episodes.append(self.open[i])
            self.open[i] = (self.env.batch.get_model(i), self.env._qpos[i].copy(), self.env._qvel[i].copy(), [])

    def stepped(self, ids) -> None:
        for i in ids:
            self.open[int(i)][3].append(self.env._ctrl[int(i)].copy())

    def all(self) -> list:
        return self.episodes + [e for e in self.open.values() if e[3]]


def instrument(env, clock: Clock, recorders: dict) -> None:
    """Charge env's batch calls to physics/reset and its step_chunk/reset to env totals; record controls."""
    batch, rec = env.batch, Recorder(env)
    recorders[env.task.task_id] = rec
    step, breset, forward = batch.step, batch.reset, batch.forward
    timed_step = clock.wrap("physics", step)

    def batch_step(ids=None, nstep=1, **kw):
        rec.stepped(np.arange(env.num_envs) if ids is None else ids)
        return timed_step(ids, nstep, **kw)

    batch.step = batch_step
    batch.reset = clock.wrap("reset", breset)
    timed_forward = clock.wrap("reset", forward)

    def batch_forward(ids=None, **kw):
        out = timed_forward(ids, **kw)
        rec.started(np.arange(env.num_envs) if ids is None else ids)
        return out

    batch.forward = batch_forward
    env.step_chunk = clock.wrap("env_step_total", env.step_chunk)
    env.reset = clock.wrap("env_reset_total", env.reset)


def replay_seconds(task, episodes: list) -> tuple[float, int]:
    """A bare single-thread mj_step loop over the recorded episodes: (seconds, control steps)."""
    import mujoco

    sub, n = task.substeps, 0
    datas = [mujoco.MjData(m) for m, *_ in episodes]
    t0 = time.perf_counter()
    for (model, qpos, qvel, ctrls), data in zip(episodes, datas):
        data.qpos[:], data.qvel[:] = qpos, qvel
        mujoco.mj_forward(model, data)
        for c in ctrls:
            data.ctrl[:] = c
            mujoco.mj_step(model, data, nstep=sub)
            n += 1
    return time.perf_counter() - t0, n


def measure(tasks: list[str], episodes: int, num_envs: int, horizon: int, seed: int) -> dict:
    from accrue import rl_loop
    from accrue.learner import LearnerConfig, make_learner
    from accrue.scripted_reference import ScriptedReference
    from accrue.sim import get_task
    from stages.steps.common import deterministic, make_env, per_task_features, reference_fn

    deterministic(seed)  # the stages' torch threads (1) and seeds
    features = per_task_features(FEATURES, tasks)
    references = {t: reference_fn(ScriptedReference(0.75), t, horizon) for t in tasks}
    probe = make_env(tasks[0], 1, 0, "state")
    state_dim = features[tasks[0]](probe.reset()).shape[1]
    probe.close()
    learner = make_learner(LearnerConfig.from_dict({**LEARNER, "seed": seed}), state_dim, horizon)
    clock, recorders = Clock(), {}

    def make(t, n):
        env = make_env(t, n, rl_loop.env_seed(seed, 1, "eval", tasks.index(t)), "state")
        instrument(env, clock, recorders)
        return env

    timed_features = {t: clock.wrap("policy", f) for t, f in features.items()}
    timed_refs = {t: clock.wrap("policy", r) for t, r in references.items()}
    evaluator = rl_loop.Evaluator(make, timed_refs, timed_features, episodes, num_envs, horizon, 0.99)
    act = clock.wrap("policy", rl_loop.actor_act(learner))
    rows = {}
    for t in tasks:
        evaluator.success_rate(t, act)  # warm: env built, caches filled
        clock.s.clear()
        recorders[t].episodes.clear()
        recorders[t].open.clear()
        wall = time.perf_counter()
        success = evaluator.success_rate(t, act)
        wall = time.perf_counter() - wall
        s = dict(clock.s)
        env_python = s["env_step_total"] + s["env_reset_total"] - s["physics"] - s["reset"]
        parts = {
            "physics": s["physics"],
            "reset": s["reset"],
            "env_python": env_python,
            "policy": s["policy"],
            "evaluator": wall - s["env_step_total"] - s["env_reset_total"] - s["policy"],
        }
        bare, steps = replay_seconds(get_task(t), recorders[t].all())
        rows[t] = {
            "success": success,
            "control_steps": steps,
            "wall_s": round(wall, 3),
            "ms_per_control_step": {k: round(1e3 * v / steps, 4) for k, v in parts.items()},
            "share": {k: round(v / wall, 3) for k, v in parts.items()},
            "bare_mj_step_ms_per_control_step": round(1e3 * bare / steps, 4),
            "substeps": get_task(t).substeps,
        }
    evaluator.close()
    return rows


def load_avg() -> float:
    return round(os.getloadavg()[0], 2)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", nargs="+", default=TASKS)
    ap.add_argument("--episodes", type=int, default=24, help="evaluation episodes per task")
    ap.add_argument("--num-envs", type=int, default=8)
    ap.add_argument("--horizon", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true", help=f"store the figures in {OUT.relative_to(ROOT)}")
    ap.add_argument("--label", default="current", help="the row's name in the JSON file")
    args = ap.parse_args()
    before = load_avg()
    rows = measure(args.tasks, args.episodes, args.num_envs, args.horizon, args.seed)
    after = load_avg()
    print(f"load average (1 min): {before} before, {after} after; {os.cpu_count()} cores")
    head = f"{'task':20s} {'steps':>6s} {'wall s':>7s} " + " ".join(
        f"{k:>10s}" for k in ["physics", "reset", "env_python", "policy", "evaluator"]
    )
    print("ms per control step (share of the evaluation's wall time); bare = single-thread mj_step replay")
    print(head + f" {'bare':>7s}")
    for t, r in rows.items():
        cells = " ".join(
            f"{r['ms_per_control_step'][k]:6.3f}({100 * r['share'][k]:2.0f}%)"[:10].rjust(10)
            for k in r["ms_per_control_step"]
        )
        print(
            f"{t:20s} {r['control_steps']:6d} {r['wall_s']:7.2f} {cells} {r['bare_mj_step_ms_per_control_step']:7.3f}"
        )
    if args.json:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
        results = json.loads(OUT.read_text()) if OUT.is_file() else {}
        results[args.label] = {
            "command": "python benchmarks/bench_env_step.py " + " ".join(os.sys.argv[1:]),
            "date": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "commit": commit.stdout.strip() or None,
            "machine": {"cores": os.cpu_count(), "load_avg_1min_before": before, "load_avg_1min_after": after},
            "episodes_per_task": args.episodes,
            "num_envs": args.num_envs,
            "tasks": rows,
        }
        OUT.write_text(json.dumps(results, indent=2) + "\n")
        print(f"wrote {OUT.relative_to(ROOT)} [{args.label}]")


if __name__ == "__main__":
    main()
