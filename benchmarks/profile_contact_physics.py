"""What MuJoCo's step costs on the contact tasks, and why (issue 48 item 2): colliders, narrow-phase pairs,
contacts, solver work and the timer split per control step, for the contact family, its successor contact2
and two nist tasks to compare with.

    .venv/bin/python benchmarks/profile_contact_physics.py [--tasks ...] [--envs 16] [--repeats 3] [--json]

Per task: the parts (colliders per part, by kind: meshes with their vertex counts, boxes, cylinders),
the candidate collision pairs (plug colliders x socket colliders, the table included) and the physics
settings (timestep, substeps per control step, solver, iterations, tolerance, cone, noslip, multiccd).
Per controller (`demonstrator`: the scripted expert that never searches; `search`: the searching expert),
`envs` episodes (env i's first, seeded (0, i, 0)) run in the env on one thread with their controls recorded,
then are replayed single-threaded on one MjData each with plain `mujoco.mj_step`, substep by substep:

    pairs        geom pairs that reach the narrow phase per substep, counted by a contact-filter callback that
                 decides as MuJoCo's default does (it is called only for pairs past the broad and mid phase)
    ncon / nefc  contacts and constraint rows per substep; niter: the solver's iterations per substep
    us_per_ctl   CPU microseconds per control step of the replay (process time, best of `repeats`)
    split        shares of MuJoCo's own timers (mjtTimer, best of `repeats` per stage): the collision's
                 broad and narrow phase, the constraint solver, the rest (kinematics, inertia, actuation,
                 integration, sensors); given when libgomp's omp_get_wtime can serve as MuJoCo's C clock

`--json` writes the figures to benchmarks/results/contact_physics_profile.json with the command, the
machine's load and the commit. CPU time is the per-core cost; on a shared machine it still moves a little
with the load (caches), so compare tasks within one run.
"""

from __future__ import annotations

import argparse
import ctypes
import ctypes.util
import json
import os
import platform
import subprocess
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "contact_physics_profile.json"
TASKS = [
    "contact/round_peg",
    "contact/keyed_peg",
    "contact/gear_mesh",
    "contact/rect_peg",
    "contact2/round_peg",
    "contact2/keyed_peg",
    "contact2/gear_mesh",
    "contact2/rect_peg",
    "nist/round_peg",
    "nist/rect_peg",
]
CONTROLLERS = {"demonstrator": {"search": False}, "search": {}}


def _c_clock():
    """omp_get_wtime (seconds, a C function MuJoCo can call as mjcb_time), or None."""
    name = ctypes.util.find_library("gomp") or "libgomp.so.1"
    try:
        fn = ctypes.CDLL(name).omp_get_wtime
    except (OSError, AttributeError):
        return None
    fn.restype, fn.argtypes = ctypes.c_double, []
    return fn


def colliders(model) -> dict:
    """Colliding geoms of the held part and of the fixture: kinds, mesh vertex counts, candidate pairs."""
    import mujoco

    kinds = {int(mujoco.mjtGeom.mjGEOM_MESH): "mesh", int(mujoco.mjtGeom.mjGEOM_BOX): "box"}
    kinds |= {int(mujoco.mjtGeom.mjGEOM_CYLINDER): "cylinder", int(mujoco.mjtGeom.mjGEOM_PLANE): "plane"}
    parts: dict[str, dict] = {"plug": {}, "socket": {}}
    verts: dict[str, list] = {"plug": [], "socket": []}
    for i in range(model.ngeom):
        role = "plug" if model.geom_contype[i] else "socket" if model.geom_conaffinity[i] else None
        if role is None:
            continue
        kind = kinds.get(int(model.geom_type[i]), str(int(model.geom_type[i])))
        parts[role][kind] = parts[role].get(kind, 0) + 1
        if kind == "mesh":
            verts[role].append(int(model.mesh_vertnum[model.geom_dataid[i]]))
    n_plug, n_socket = (sum(parts[r].values()) for r in ("plug", "socket"))
    return {
        "plug": parts["plug"],
        "socket": parts["socket"],  # the table plane included
        "mesh_vertices": {r: sorted(set(v)) for r, v in verts.items()},
        "candidate_pairs": n_plug * n_socket,
    }


def settings(task, model) -> dict:
    import mujoco

    opt = model.opt
    return {
        "timestep_ms": task.physics_dt * 1e3,
        "substeps_per_control_step": task.substeps,
        "solver": mujoco.mjtSolver(opt.solver).name,
        "iterations": int(opt.iterations),
        "tolerance": float(opt.tolerance),
        "cone": mujoco.mjtCone(opt.cone).name,
        "impratio": float(opt.impratio),
        "noslip_iterations": int(opt.noslip_iterations),
        "multiccd": not opt.disableflags & mujoco.mjtDisableBit.mjDSBL_MULTICCD,
    }


def record(task_id: str, envs: int, controller: dict) -> list:
    """Every env's first episode as (its randomised model, qpos, qvel, [ctrl per control step])."""
    from accrue.sim import make_expert, make_vec_env

    env = make_vec_env(task_id, num_envs=envs, seed=0, nthread=1)
    expert = make_expert(task_id, **controller)
    obs = env.reset()
    episodes = [(env.batch.get_model(i), env._qpos[i].copy(), env._qvel[i].copy(), []) for i in range(envs)]
    while not env.done.all():
        active = np.flatnonzero(~env.done)
        res = env.step(expert.act(obs["state"]))
        for i in active:
            episodes[i][3].append(env._ctrl[i].copy())
        obs = res.obs
    env.close()
    return episodes


def _start(model, qpos, qvel):
    import mujoco

    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:] = qpos, qvel
    mujoco.mj_forward(model, data)
    return data


def counts(episodes: list, substeps: int) -> dict:
    """Per substep: narrow-phase pairs, contacts, constraint rows, solver iterations (mean and 90th pct)."""
    import mujoco

    pairs = [0]

    def contact_filter(m, d, g1, g2):  # MuJoCo's default decision for these models, counting what passes
        passes = (m.geom_contype[g1] & m.geom_conaffinity[g2]) or (m.geom_contype[g2] & m.geom_conaffinity[g1])
        pairs[0] += bool(passes)
        return 0 if passes else 1

    rows = {"pairs": [], "ncon": [], "nefc": [], "niter": []}
    mujoco.set_mjcb_contactfilter(contact_filter)
    try:
        for model, qpos, qvel, ctrls in episodes:
            data = _start(model, qpos, qvel)
            for ctrl in ctrls:
                data.ctrl[:] = ctrl
                for _ in range(substeps):
                    pairs[0] = 0
                    mujoco.mj_step(model, data)
                    rows["pairs"].append(pairs[0])
                    rows["ncon"].append(data.ncon)
                    rows["nefc"].append(data.nefc)
                    rows["niter"].append(int(data.solver_niter[0]))
    finally:
        mujoco.set_mjcb_contactfilter(None)
    return {k: {"mean": round(float(np.mean(v)), 2), "p90": float(np.percentile(v, 90))} for k, v in rows.items()}


def timed(episodes: list, substeps: int, repeats: int, clock) -> dict:
    """CPU us per control step of a plain replay (best of repeats) and MuJoCo's timer split."""
    import mujoco

    timer = mujoco.mjtTimer
    stages = {
        "collision_narrow": timer.mjTIMER_COL_NARROW,
        "collision_broad": timer.mjTIMER_COL_BROAD,
        "constraint_solver": timer.mjTIMER_CONSTRAINT,
    }
    best_cpu, best = np.inf, None
    steps = sum(len(e[3]) for e in episodes)
    for _ in range(repeats):
        totals = np.zeros(len(timer.__members__) if hasattr(timer, "__members__") else 16)
        if clock is not None:
            mujoco.set_mjcb_time(clock)
        try:
            start = time.process_time()
            for model, qpos, qvel, ctrls in episodes:
                data = _start(model, qpos, qvel)
                for t in data.timer:
                    t.duration = 0.0
                for ctrl in ctrls:
                    data.ctrl[:] = ctrl
                    mujoco.mj_step(model, data, nstep=substeps)
                for k in stages.values():
                    totals[int(k)] += data.timer[int(k)].duration
                totals[int(timer.mjTIMER_STEP)] += data.timer[int(timer.mjTIMER_STEP)].duration
            best_cpu = min(best_cpu, time.process_time() - start)
        finally:
            mujoco.set_mjcb_time(None)
        best = totals if best is None else np.minimum(best, totals)
    out = {"us_per_ctl": round(1e6 * best_cpu / steps, 1), "control_steps_per_s": round(steps / best_cpu, 1)}
    step = best[int(timer.mjTIMER_STEP)]
    if clock is not None and step > 0:
        split = {name: round(float(best[int(k)] / step), 3) for name, k in stages.items()}
        split["rest"] = round(1.0 - sum(split.values()), 3)
        out["split"] = split
    return out


def profile(task_id: str, envs: int, repeats: int, clock) -> dict:
    from accrue.sim import get_task
    from accrue.sim.model import build_model

    task = get_task(task_id)
    model = build_model(task)
    row = {"family": task.family, "colliders": colliders(model), "physics": settings(task, model), "controllers": {}}
    for name, kw in CONTROLLERS.items():
        episodes = record(task_id, envs, kw)
        steps = sum(len(e[3]) for e in episodes)
        row["controllers"][name] = {
            "control_steps": steps,
            **timed(episodes, task.substeps, repeats, clock),
            "per_substep": counts(episodes, task.substeps),
        }
    return row


def commit_id() -> str:
    """The checkout's short commit ("unknown" outside git): what a result file was measured on."""
    try:
        return subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", nargs="+", default=TASKS)
    ap.add_argument("--envs", type=int, default=16, help="episodes per controller (one per env)")
    ap.add_argument("--repeats", type=int, default=3, help="timed replays; the best counts")
    ap.add_argument("--json", action="store_true", help=f"write {OUT.relative_to(ROOT)}")
    args = ap.parse_args()
    clock = _c_clock()
    load_before = round(os.getloadavg()[0], 2)
    rows = {}
    head = f"{'task':20s} {'controller':12s} {'us/ctl':>7s} {'steps/s':>8s} {'pairs':>6s} {'ncon':>5s} {'nefc':>5s} {'iter':>5s}"
    print(head + "  split (narrow / broad / solver / rest)")
    for task_id in args.tasks:
        rows[task_id] = row = profile(task_id, args.envs, args.repeats, clock)
        col = row["colliders"]
        print(f"{task_id}: plug {col['plug']} socket {col['socket']} ({col['candidate_pairs']} candidate pairs)")
        for name, c in row["controllers"].items():
            ps = c["per_substep"]
            split = " / ".join(f"{v:.2f}" for v in c.get("split", {}).values())
            print(
                f"{'':20s} {name:12s} {c['us_per_ctl']:7.0f} {c['control_steps_per_s']:8.0f} {ps['pairs']['mean']:6.1f}"
                f" {ps['ncon']['mean']:5.1f} {ps['nefc']['mean']:5.1f} {ps['niter']['mean']:5.1f}  {split}",
                flush=True,
            )
    load_after = round(os.getloadavg()[0], 2)
    print(f"load average (1 min): {load_before} before, {load_after} after; {os.cpu_count()} cores")
    if args.json:
        result = {
            "command": " ".join([Path(sys.executable).name, *sys.argv]),
            "date": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "commit": commit_id(),
            "machine": {
                "cores": os.cpu_count(),
                "load_avg_1min_before": load_before,
                "load_avg_1min_after": load_after,
                "python": platform.python_version(),
            },
            "timer_split": clock is not None,
            "episodes_per_controller": args.envs,
            "repeats": args.repeats,
            "tasks": rows,
        }
        OUT.write_text(json.dumps(result, indent=2) + "\n")
        print(f"wrote {OUT.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
