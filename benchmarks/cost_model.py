"""A bench cell's and a whole grid's wall time, projected from measured coefficients (issue 48, item 4).

    .venv/bin/python benchmarks/cost_model.py --measure              # re-measure the coefficients (~2-3 min)
    .venv/bin/python benchmarks/cost_model.py                        # project from the committed coefficients
    .venv/bin/python benchmarks/cost_model.py --markdown             # ... and print the docs' table
    .venv/bin/python benchmarks/perf_report.py --row model           # the grid's row of perf.json, from them

Coefficients, each measured by this script on one core (torch and MuJoCo one thread each) and stored with
the machine's 1-min load average at the time (on a shared machine a figure only ever gets slower: a
projection from loaded coefficients is an upper bound on an idle machine's):

    physics      per task, control steps/s of the evaluation setting: a vec env of num_envs envs, H-step
                 chunks, the learner state computed every chunk, env resets; MuJoCo's seconds per control step
                 and the episode lengths from the limited demonstrator (make_expert(search=False)) acting every
                 control step, as the base policy that imitates it does (held for H steps it never reaches the
                 contact a policy that inserts makes: MuJoCo 3-7x cheaper, success 0: both are stored), the env's
                 Python per control step and per step_chunk call from both runs
    learner      per distinct learner setting of the specs' cells: seconds per gradient update of
                 learner.train_step on a synthetic replay, at stage 1 and, where the method samples B^{<k} or
                 anchors to θ^{k-1}, at a later stage (interleaved rounds, the median); one actor call
    base_policy  π_base's chunk on num_envs envs (embedded-mlp), and record-demos' fixed cost (write_demos)
    finetune     finetune-base seconds a stage: benchmarks/results/perf.json's finetune row (training set
                 built), else --finetune-s
    overhead     a step that does nothing (perf.json's cell row: cache-teacher, handoff); one env build

A cell is planned stage by stage as `accrue bench` runs it (stages.bench.spec.load_spec, stages.plan.plan_stage)
and each step's work is counted from its config, then priced:

    record-demos   demos / the demonstrator's success (benchmarks/results/contact_experts.json) attempts
    finetune-base  the finetune coefficient (x steps / the measured row's steps)
    warmup         π_base^k's episodes (at least warmup_episodes, every env running)
    train          env_steps of physics, a π_base and an actor chunk per chunk step, utd updates per chunk step
                   once B^k holds learning_starts rows, and the evaluation grid under the OLD protocol (every
                   task at every point, selection + report sets) or the NEW one (the current task at every point
                   on both sets, earlier tasks once, at the chosen checkpoint, on the report set, else selection)
    evaluate-all   every task 1..k, the actor and the base policy alone, on the report set (else selection)
    cache-teacher, handoff   the fixed step overhead

Grid hours: cells one core each, `cores` at a time; a step that cells share through the step cache (same
content key: record-demos, finetune-base and warmup of one ordering prefix and seed; the ablations' `accrue`
row is the headline's cells) is paid once: wall = max(unique work / cores, the longest cell). Validation
compares the model with perf.json's cell row and with committed steps in bench logs (runs/bench/*/logs).
"""

from __future__ import annotations

import argparse
import hashlib
import itertools
import json
import math
import re
import shlex
import statistics
import sys
import time
from functools import lru_cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
import perf_report  # noqa: E402
from perf_report import GRID_SPECS, machine, software  # noqa: E402

SPECS = (*GRID_SPECS, "contact-learner")
OUT = ROOT / "benchmarks" / "results" / "cost_model.json"
PERF = ROOT / "benchmarks" / "results" / "perf.json"
EXPERTS = ROOT / "benchmarks" / "results" / "contact_experts.json"
QUICKSTART = ROOT / "workflows" / "quickstart.yaml"  # perf.json's cell row ran it: the validation workflow
LOGS = ROOT / "runs" / "bench"  # `accrue bench` cell logs (not committed): finished stages to validate against
PROTOCOLS = ("old", "new")
CORES = (2, 16)
SHARED = "machine shared with other engineers' bench cells and tests: every coefficient is an upper bound"
# learner settings that change what is learned, not what an update computes
NOT_SPEED = {"seed", "beta", "lam", "actor_lr", "critic_lr", "learning_starts", "ref_dropout", "std_max", "utd"}
NOT_SPEED |= {"exploration", "delta_bound", "noise_steps", "obs_norm_fixed_tail", "gamma"}
FEATURE_KEYS = ("encoder", "task_features", "history", "task_descriptor", "obs_mode")


def load() -> float:
    return machine()["load_avg_1min"]


# --------------------------------------------------------------------------- what a cell runs
def cell_plans(wf) -> list:
    from stages.plan import plan_stage

    return [plan_stage(wf, k, None) for k in range(1, len(wf.tasks) + 1)]


def step_keys(plans: list) -> dict[tuple[int, str], str]:
    """(stage, step) -> a content key: the step's name, config and its inputs' keys, as the step cache keys
    steps (the workflow's name is in no key), so cells that share a step share its key."""
    from stages.runner_types import FromRef, FromStep

    keys: dict[tuple[int, str], str] = {}
    for plan in plans:
        for inv in plan.steps:
            inputs = {}
            for role, src in sorted(inv.inputs.items()):
                if isinstance(src, FromStep):
                    inputs[role] = f"{keys[(plan.stage, src.step)]}:{src.role}"
                elif isinstance(src, FromRef):
                    m = re.fullmatch(r"workflow/[^/]+/stage/(\d+)/([^:]+):(.+)", src.ref)
                    inputs[role] = f"{keys[(int(m[1]), m[2])]}:{m[3]}" if m else src.ref
                else:
                    inputs[role] = str(src)
            blob = json.dumps([inv.step.name, inv.step.code_version, inv.config, inputs], sort_keys=True, default=str)
            keys[(plan.stage, inv.step.name)] = hashlib.sha256(blob.encode()).hexdigest()[:16]
    return keys


def learner_key(train_config: dict) -> str:
    """The learner coefficient a train step reads: its learner's speed-relevant settings, inputs and H."""
    settings = {k: v for k, v in train_config["learner"].items() if k not in NOT_SPEED}
    features = {k: train_config.get(k) for k in FEATURE_KEYS}
    blob = json.dumps([settings, features, train_config["horizon"]], sort_keys=True)
    label = settings["method"] + ("" if settings.get("ablation", "none") == "none" else f"/{settings['ablation']}")
    return f"{label} {hashlib.sha256(blob.encode()).hexdigest()[:8]}"


def physics_key(task: str, config: dict) -> str:
    return f"{task} n{config['num_envs']} H{config['horizon']}"


def later_phase(learner: dict, stage: int) -> bool:
    """Whether stage's updates cost more than stage 1's: B^{<k} sampled, or EWC's anchor."""
    from accrue.methods import rules

    r = rules(learner["method"], learner.get("ablation", "none"))
    return stage > 1 and (r.uses_prior_memory or r.ewc_penalty)


# --------------------------------------------------------------------------- episode counting (exact)
def grid_points(env_steps: int, eval_every: int) -> int:
    from accrue.rl_loop import LoopSettings

    return len(LoopSettings([], env_steps, eval_every, 0).grid())


def train_eval_calls(config: dict, protocol: str) -> list[tuple[str, int, int]]:
    """(task, calls, episodes per call) of one train step's evaluation grid: OLD scores every task at every
    grid point on the selection and report sets; NEW the current task so, earlier tasks once, at the chosen
    checkpoint, on the report set (the selection set when there is none), as rl_loop.train_loop does."""
    tasks, sel, rep = config["task_ids"], config["eval_episodes"], config.get("report_episodes", 0)
    points = grid_points(config["env_steps"], config["eval_every"])
    calls = []
    for t in tasks:
        if protocol == "old" or t == tasks[-1]:
            calls += [(t, points, n) for n in (sel, rep) if n]
        else:
            calls.append((t, 1, rep or sel))
    return calls


def evaluate_all_calls(config: dict) -> list[tuple[str, int, bool]]:
    """(task, episodes, with the actor) of evaluate-all: every task, the actor and the base policy alone."""
    per = config.get("report_episodes") or config["episodes"]
    return [(t, per, actor) for t in config["task_ids"] for actor in (True, False)]


def episode_counts(wf) -> dict[str, int]:
    """A cell's episodes: train's evaluation grid under both protocols, evaluate-all's, warmup's (at least)."""
    counts = {"train_eval_old": 0, "train_eval_new": 0, "evaluate_all": 0, "warmup_at_least": 0}
    for plan in cell_plans(wf):
        for inv in plan.steps:
            if inv.step.name == "train":
                for p in PROTOCOLS:
                    counts[f"train_eval_{p}"] += sum(n * e for _, n, e in train_eval_calls(inv.config, p))
            elif inv.step.name == "evaluate-all":
                counts["evaluate_all"] += sum(e for _, e, _ in evaluate_all_calls(inv.config))
            elif inv.step.name == "warmup":
                counts["warmup_at_least"] += inv.config["episodes"]
    return counts


# --------------------------------------------------------------------------- schedules
@lru_cache(maxsize=None)
def eval_chunks(episodes: int, num_envs: int, chunks: tuple[int, ...]) -> int:
    """Chunk steps of rl_loop.Evaluator.success_rate: min(num_envs, episodes) envs, an env that ends starts
    the next episode while fewer than `episodes` have started; episode lengths (in chunks) cycle `chunks`."""
    n, lengths = min(num_envs, episodes), itertools.cycle(chunks)
    left = [next(lengths) for _ in range(n)]
    started, finished, steps = n, 0, 0
    while finished < episodes:
        steps += 1
        for i in range(n):
            if left[i] > 0:
                left[i] -= 1
                if left[i] == 0:
                    finished += 1
                    if started < episodes:
                        left[i], started = next(lengths), started + 1
    return steps


@lru_cache(maxsize=None)
def warmup_chunks(episodes: int, num_envs: int, chunks: tuple[int, ...]) -> int:
    """Chunk steps of rl_loop.warmup: every env restarts as it ends, until `episodes` have ended."""
    lengths = itertools.cycle(chunks)
    left = [next(lengths) for _ in range(num_envs)]
    finished, steps = 0, 0
    while finished < episodes or steps == 0:
        steps += 1
        for i in range(num_envs):
            left[i] -= 1
            if left[i] == 0:
                finished, left[i] = finished + 1, next(lengths)
    return steps


# --------------------------------------------------------------------------- pricing a step
def physics_of(coef: dict, task: str, config: dict) -> tuple[str, dict]:
    """The physics coefficient of task at the step's num_envs and H (else any measured for the task)."""
    key = physics_key(task, config) if "horizon" in config else ""
    if key not in coef["physics"]:
        key = next((k for k in coef["physics"] if k.split(" ")[0] == task), key)
    if key not in coef["physics"]:
        raise SystemExit(f"error: no physics coefficient for {task}: run with --measure")
    return key, coef["physics"][key]


def step_work(inv, plan, coef: dict, protocol: str) -> dict:
    """What one step runs: control steps per physics coefficient, π_base chunks, actor chunks per learner
    coefficient, gradient updates per learner coefficient and phase, fixed seconds, env builds, one step."""
    c, name = inv.config, inv.step.name
    w: dict = {"control_steps": {}, "actor_chunks": {}, "updates": {}, "reference_chunks": 0, "fixed_s": {}}
    w.update(env_builds=0, steps=1)

    def add(part: str, key: str, n: float) -> None:
        w[part][key] = w[part].get(key, 0) + n

    def episodes(task: str, n: int, actor: str | None) -> None:
        key, p = physics_of(coef, task, c)
        add("control_steps", key, n * p["mean_episode_steps"])
        chunks = eval_chunks(n, c["num_envs"], tuple(p["episode_chunks"]))
        w["reference_chunks"] += chunks
        if actor:
            add("actor_chunks", actor, chunks)

    if name == "record-demos":  # successful demos only: demos / success attempts (at most 10x demos)
        key, p = physics_of(coef, c["task"], c)
        success = coef["demo_success"].get(c["task"], p["demo_success"])
        attempts = min(10 * c["episodes"], math.ceil(c["episodes"] / max(success, 1e-3)))
        add("control_steps", key, attempts * p["mean_episode_steps"])
        add("fixed_s", "record-demos", coef["base_policy"]["record_demos_fixed_s"])
        w["env_builds"] = 1
    elif name == "finetune-base":
        ft = coef["finetune"]
        add("fixed_s", "finetune", ft["seconds_per_stage"] * c["steps"] / ft["steps"])
    elif name == "warmup":
        key, p = physics_of(coef, c["task"], c)
        chunks = warmup_chunks(c["episodes"], c["num_envs"], tuple(p["episode_chunks"]))
        add("control_steps", key, chunks * c["num_envs"] * p["steps_per_env_chunk"])
        w["reference_chunks"], w["env_builds"] = chunks, 1
    elif name == "train":
        task, lk, learner = c["task_ids"][-1], learner_key(c), c["learner"]
        key, p = physics_of(coef, task, c)
        chunk_steps = math.ceil(c["env_steps"] / (c["num_envs"] * p["steps_per_env_chunk"]))
        warm = next(s.config for s in plan.steps if s.step.name == "warmup")
        warm_rows = c["num_envs"] * warmup_chunks(warm["episodes"], c["num_envs"], tuple(p["episode_chunks"]))
        first = max(1, math.ceil((learner.get("learning_starts", 0) - warm_rows) / c["num_envs"]))
        phase = "later" if later_phase(learner, c["stage"]) else "first"
        add("updates", f"{lk}|{phase}", learner.get("utd", 1) * max(0, chunk_steps - first + 1))
        add("control_steps", key, c["env_steps"])
        add("actor_chunks", lk, chunk_steps)
        w["reference_chunks"] += chunk_steps
        calls = train_eval_calls(c, protocol)
        for t, n, per in calls:
            for _ in range(n):
                episodes(t, per, lk)
        w["env_builds"] = 1 + len(calls)
    elif name == "evaluate-all":
        for t, per, actor in evaluate_all_calls(c):
            episodes(t, per, "evaluate-all" if actor else None)
        w["env_builds"] = len(c["task_ids"])
    return w


def learner_coefficient(coef: dict, key: str) -> dict:
    """A learner's coefficient; a setting measured for no cell yet (a spec changed since) borrows the first
    measured one of the same method and ablation (project() lists which)."""
    learners = coef["learner"]
    if key in learners:
        return learners[key]
    same = [v for k, v in learners.items() if k.split(" ")[0] == key.split(" ")[0]]
    if not same:
        raise SystemExit(f"error: no learner coefficient for {key}: run with --measure")
    return same[0]


def price(w: dict, coef: dict) -> dict[str, float]:
    """Seconds of a step's work, by part."""
    phys, over = coef["physics"], coef["overhead"]
    mean_act = statistics.mean(v["act_s"] for v in coef["learner"].values())
    act = lambda k: learner_coefficient(coef, k)["act_s"] if " " in k else mean_act  # noqa: E731
    update = lambda k: learner_coefficient(coef, k.split("|")[0])[f"{k.split('|')[1]}_update_s"]  # noqa: E731
    return {
        "physics": sum(n / phys[k]["control_steps_per_s"] for k, n in w["control_steps"].items()),
        "policy": w["reference_chunks"] * coef["base_policy"]["reference_s"]
        + sum(n * act(k) for k, n in w["actor_chunks"].items()),
        "updates": sum(n * update(k) for k, n in w["updates"].items()),
        "finetune": w["fixed_s"].get("finetune", 0.0),
        "overhead": w["steps"] * over["step_s"]
        + w["env_builds"] * over["env_build_s"]
        + w["fixed_s"].get("record-demos", 0.0),
    }


# --------------------------------------------------------------------------- cells, specs, grids
def cell_steps(wf, coef: dict) -> list[dict]:
    """Every step of a cell from scratch: its stage, name, content key and seconds by part per protocol."""
    plans = cell_plans(wf)
    keys = step_keys(plans)
    return [
        {
            "stage": plan.stage,
            "step": inv.step.name,
            "key": keys[(plan.stage, inv.step.name)],
            "learner": learner_key(inv.config) if inv.step.name == "train" else None,
            "parts": {p: price(step_work(inv, plan, coef, p), coef) for p in PROTOCOLS},
        }
        for plan in plans
        for inv in plan.steps
    ]


def project(cells: list, coef: dict, cores: tuple[int, ...] = CORES, memo: dict | None = None) -> dict:
    """Cell minutes (from scratch), core-hours, and the grid's wall hours on `cores` cores, per protocol.
    memo: cell name -> its cell_steps, shared between calls on the same coefficients."""
    totals: dict[str, list[float]] = {p: [] for p in PROTOCOLS}
    unique: dict[str, dict[str, float]] = {}
    parts = {p: dict.fromkeys(("physics", "policy", "updates", "finetune", "overhead"), 0.0) for p in PROTOCOLS}
    memo = {} if memo is None else memo
    borrowed = {s["learner"] for c in cells for s in memo.get(c.name, [])}
    for cell in cells:
        if cell.name not in memo:
            memo[cell.name] = cell_steps(cell.workflow, coef)
        steps = memo[cell.name]
        borrowed |= {s["learner"] for s in steps if s.get("learner") and s["learner"] not in coef["learner"]}
        for p in PROTOCOLS:
            totals[p].append(sum(sum(s["parts"][p].values()) for s in steps))
            for s in steps:
                for k, v in s["parts"][p].items():
                    parts[p][k] += v
        for s in steps:
            unique.setdefault(s["key"], {p: sum(s["parts"][p].values()) for p in PROTOCOLS})
    out = {
        "cells": len(cells),
        "learner_settings_not_measured": sorted(k for k in borrowed if k and k not in coef["learner"]),
        "cell_min": {
            p: {"mean": round(statistics.mean(t) / 60, 1), "min": round(min(t) / 60, 1), "max": round(max(t) / 60, 1)}
            for p, t in totals.items()
        },
        "share": {p: {k: round(v / sum(parts[p].values()), 3) for k, v in parts[p].items()} for p in PROTOCOLS},
        "core_h": {p: round(sum(t) / 3600, 1) for p, t in totals.items()},
        "core_h_cache_shared": {p: round(sum(u[p] for u in unique.values()) / 3600, 1) for p in PROTOCOLS},
        "grid_h": {
            str(n): {p: round(max(sum(u[p] for u in unique.values()) / n, max(totals[p])) / 3600, 1) for p in PROTOCOLS}
            for n in cores
        },
    }
    return out


def spec_cells(name: str) -> list:
    from stages.bench.spec import load_spec

    return load_spec(ROOT / "workflows" / "bench" / f"{name}.yaml").cells


def projections(specs: list[str], coef: dict) -> dict:
    """Per spec, and for the full grid (issue 18's specs among `specs`, sharing the step cache)."""
    out, memo, cells = {}, {}, {name: spec_cells(name) for name in specs}
    for name in specs:
        first = cells[name][0].workflow
        out[name] = {
            "stages": len(first.tasks),
            "episodes_per_cell": episode_counts(first),
            **project(cells[name], coef, memo=memo),
        }
    grid = [s for s in GRID_SPECS if s in specs]
    if len(grid) > 1:
        out["full grid"] = {"specs": grid, **project([c for s in grid for c in cells[s]], coef, memo=memo)}
    return out


# --------------------------------------------------------------------------- measuring
def needs(workflows: list) -> tuple[dict, dict]:
    """The physics and learner coefficients these workflows read: key -> a train step's config using it."""
    physics, learners = {}, {}
    for wf in workflows:
        for plan in cell_plans(wf):
            for inv in plan.steps:
                if inv.step.name == "train":
                    learners.setdefault(learner_key(inv.config), inv.config)
                    for t in inv.config["task_ids"]:
                        physics.setdefault(physics_key(t, inv.config), {**inv.config, "task": t})
    return physics, learners


def features_for(config: dict, task: str):
    from stages.steps.common import per_task_features

    return per_task_features(config, [task])[task]


def demonstrator_loop(config: dict, episodes: int, horizon: int) -> dict:
    """Seconds of MuJoCo (batch.step), of env.step_chunk, of env.reset and of the learner state, on num_envs
    envs (one MuJoCo thread) run by the limited demonstrator: acting every control step (horizon 1) or held
    for `horizon` steps."""
    import numpy as np

    from accrue import rl_loop
    from accrue.sim import make_expert, make_vec_env

    task, n = config["task"], config["num_envs"]
    t0 = time.perf_counter()
    env = make_vec_env(task, n, seed=rl_loop.env_seed(0, 1, "eval", 0), nthread=1)
    obs = env.reset()
    out = {"build_s": time.perf_counter() - t0, "mujoco_s": 0.0, "step_s": 0.0, "reset_s": 0.0, "features_s": 0.0}
    step = env.batch.step

    def timed_step(*a, **kw):
        t = time.perf_counter()
        try:
            return step(*a, **kw)
        finally:
            out["mujoco_s"] += time.perf_counter() - t

    env.batch.step = timed_step
    features, expert = features_for(config, task), make_expert(task, search=False, bias_known=0.75)
    # every env's first `per_env` episodes (the first `episodes` to end would favour the short ones)
    per_env, ended = math.ceil(episodes / n), [[] for _ in range(n)]
    calls, running = 0, np.zeros(n, int)
    while min(map(len, ended)) < per_env:
        t = time.perf_counter()
        features(obs)  # the learner state, as the Evaluator computes it every chunk
        out["features_s"] += time.perf_counter() - t
        chunk = np.repeat(np.asarray(expert.act(obs["state"]), np.float32)[:, None], horizon, axis=1)
        t = time.perf_counter()
        res = env.step_chunk(chunk, 0.99)
        out["step_s"] += time.perf_counter() - t
        calls, running = calls + 1, running + res.steps
        done = res.terminated | res.truncated
        for i in np.flatnonzero(done):
            ended[i].append((int(running[i]), bool(res.success[i])))
        running[done] = 0
        t = time.perf_counter()
        obs = env.reset(done) if done.any() else res.obs
        out["reset_s"] += time.perf_counter() - t
    env.close()
    kept = [e for runs in ended for e in runs[:per_env]]
    steps = sum(x for runs in ended for x, _ in runs) + int(running.sum())
    lengths = [x for x, _ in kept]
    return {**out, "calls": calls, "steps": steps, "lengths": lengths, "success": sum(ok for _, ok in kept) / len(kept)}


def measure_physics(config: dict, episodes: int) -> dict:
    """Control steps/s of the evaluation setting on one core, from two runs of the limited demonstrator.

    Held for H steps (the chunked setting) the demonstrator never reaches the contact its own per-step
    actions make (success 0, MuJoCo 3-7x cheaper than with a policy that inserts), so MuJoCo's seconds per
    control step and the episode lengths come from the demonstrator acting every control step, as the base
    policy that imitates it does; the env's Python around MuJoCo (per control step, per step_chunk call)
    from both runs; resets per episode and the learner state per call as measured."""
    horizon, before = config["horizon"], load()
    t0 = time.perf_counter()
    contact = demonstrator_loop(config, episodes, 1)
    held = demonstrator_loop(config, max(config["num_envs"], episodes // 2), horizon)
    # the env's Python: per_call * calls + per_step * steps, in both runs
    (c1, s1, o1), (c2, s2, o2) = [(r["calls"], r["steps"], r["step_s"] - r["mujoco_s"]) for r in (contact, held)]
    det = c1 * s2 - c2 * s1
    per_call = max(0.0, (o1 * s2 - o2 * s1) / det) if det else 0.0
    per_step = max(0.0, (o2 - per_call * c2) / s2)
    lengths = contact["lengths"]
    chunks = [math.ceil(x / horizon) for x in lengths]
    mean_len = statistics.mean(lengths)
    per_control_step = (
        contact["mujoco_s"] / contact["steps"]
        + per_step
        + (per_call + held["features_s"] / held["calls"]) * statistics.mean(chunks) / mean_len
        + contact["reset_s"] / len(lengths) / mean_len
    )
    return {
        "num_envs": config["num_envs"],
        "horizon": horizon,
        "control_steps_per_s": round(1 / per_control_step, 1),
        "mujoco_steps_per_s": round(contact["steps"] / contact["mujoco_s"], 1),
        "held_chunk_mujoco_steps_per_s": round(held["steps"] / held["mujoco_s"], 1),
        "env_python_s": {"per_step": round(per_step, 7), "per_call": round(per_call, 7)},
        "mean_episode_steps": round(mean_len, 2),
        "steps_per_env_chunk": round(sum(lengths) / sum(chunks), 3),
        "episode_chunks": chunks,
        "demo_success": round(contact["success"], 3),
        "held_chunk_success": round(held["success"], 3),
        "env_build_s": round(contact["build_s"], 3),
        "episodes": len(lengths),
        "seconds": round(time.perf_counter() - t0, 2),
        "load_avg_1min": before,
    }


def synthetic_replay(state_dim: int, horizon: int, rows: int, task: int, seed: int, envs: int = 32):
    """A replay of `rows` random chunk transitions, in episodes of 20 chunks per env."""
    import numpy as np

    from accrue.learner import ReplayBuffer

    rng, buffer = np.random.default_rng(seed), ReplayBuffer(state_dim, horizon)
    for i in range(math.ceil(rows / envs)):
        ended = np.full(envs, i % 20 == 19)
        chunk = lambda: rng.uniform(-1, 1, (envs, horizon, 6)).astype(np.float32)  # noqa: E731
        buffer.add(
            rng.standard_normal((envs, state_dim)).astype(np.float32),
            chunk(),
            chunk(),
            (rng.random(envs) > 0.8).astype(np.float32),
            rng.standard_normal((envs, state_dim)).astype(np.float32),
            chunk(),
            ended & (rng.random(envs) > 0.5),
            task,
            np.arange(envs) + envs * (i // 20),
            ended=ended,
        )
    return buffer


def prepare_learner(config: dict) -> tuple[dict, dict]:
    """A learner at this train step's settings on a synthetic replay: its row (state dim, one actor call on
    num_envs rows) and one train_step per phase (stage 1; a later stage where the method samples B^{<k} or
    anchors to θ^{k-1}: its previous learner, retained memory, Eq. 3 targets or Fisher as begin_stage gets them)."""
    import numpy as np
    import torch

    from accrue.learner import begin_stage, compute_teacher_targets, end_stage
    from accrue.sim import make_vec_env
    from accrue.stage_rl import fisher_batch
    from stages.steps.common import learner_config

    torch.set_num_threads(1)
    task, horizon, n = config["task_ids"][-1], config["horizon"], config["num_envs"]
    env = make_vec_env(task, 1, seed=0, nthread=1)
    d = features_for(config, task)(env.reset()).shape[1]
    env.close()
    cfg = learner_config({**config["learner"], "device": "cpu"})
    buffer = synthetic_replay(d, horizon, max(2048, cfg.learning_starts + 64), task=1, seed=0)
    first = begin_stage(None, cfg, d, horizon)
    row = {"label": learner_key(config).split(" ")[0], "state_dim": d, "utd": cfg.utd, "settings": config["learner"]}
    rng = np.random.default_rng(0)
    s, ref = rng.standard_normal((n, d)).astype(np.float32), rng.uniform(-1, 1, (n, horizon, 6)).astype(np.float32)
    t = time.perf_counter()
    for _ in range(20):
        first.act(s, ref, explore=True, reset_mask=np.zeros(n, bool))
        first.act_with(first.deployed_actor(), s, ref)
    row["act_s"] = round((time.perf_counter() - t) / 40, 6)
    steps = {"first": lambda: first.train_step(buffer)}
    if later_phase(config["learner"], 2):
        memory = synthetic_replay(d, horizon, 1024, task=0, seed=1)
        teacher = None
        if cfg.rules.distill:
            teacher = compute_teacher_targets(first, memory.column("state"), memory.column("ref"))
        fresh = teacher.clone() if teacher is not None and cfg.distill_inputs != "stored" else None
        fisher = fisher_batch(memory, 0, cfg.ewc_samples) if cfg.rules.ewc_penalty else None
        later = begin_stage(end_stage(first), cfg, d, horizon, fisher_batch=fisher)
        steps["later"] = lambda: later.train_step(buffer, memory, teacher, fresh)
    for step in steps.values():
        step()  # warm-up
    return row, steps


def measure_learners(needed: dict, updates: int, rounds: int = 5) -> dict:
    """Seconds per gradient update of every learner setting, timed in interleaved rounds (a busy machine
    slows them alike), the median round kept; stage 1 and, where it costs more, a later stage."""
    rows, steps = {}, {}
    for key, config in needed.items():
        rows[key], phases = prepare_learner(config)
        steps.update({(key, phase): fn for phase, fn in phases.items()})
    times: dict[tuple[str, str], list[float]] = {k: [] for k in steps}
    before = load()
    for _ in range(rounds):
        for (key, phase), fn in steps.items():
            utd = rows[key]["utd"]
            calls = max(1, math.ceil(updates / rounds / utd))
            t = time.perf_counter()
            for _ in range(calls):
                fn()
            times[(key, phase)].append((time.perf_counter() - t) / (calls * utd))
    after = load()
    for key, row in rows.items():
        for phase in ("first", "later"):
            rounds_s = times.get((key, phase), times[(key, "first")])
            row[f"{phase}_update_s"] = round(statistics.median(rounds_s), 5)
            row[f"{phase}_update_s_best_round"] = round(min(rounds_s), 5)
        row.update(load_avg_1min=before, load_avg_1min_after=after)
    return rows


def measure_base_policy(physics_needs: dict) -> dict:
    """π_base's chunk for num_envs envs (an embedded-mlp fine-tuned for 2 steps on 2 demos: the same network
    and processors as the workflows'), and record-demos' cost besides physics (imports, the lerobot dataset),
    from writing those 2 demos."""
    import tempfile

    from accrue.policy import EMBEDDED_DEFAULT, FinetuneSettings, finetune
    from accrue.sim import make_vec_env
    from accrue.sim.demos import write_demos
    from stages.steps.common import load_base_policy, reference_fn

    before = load()
    horizon = max(c["horizon"] for c in physics_needs.values())
    with tempfile.TemporaryDirectory(prefix="cost-model-") as tmp:
        demos, t = Path(tmp) / "demos", time.perf_counter()
        write_demos("nist/rect_peg", 2, demos, seed=0, num_envs=2, progress=False)
        record_s = time.perf_counter() - t
        settings = FinetuneSettings(steps=2, batch_size=8, lr=1e-3, chunk_size=horizon)
        policy = load_base_policy(finetune(EMBEDDED_DEFAULT, [demos], Path(tmp) / "policy", settings), 0)
        seconds = []
        for c in physics_needs.values():
            env = make_vec_env(c["task"], c["num_envs"], seed=0, nthread=1)
            obs, reference = env.reset(), reference_fn(policy, c["task"], c["horizon"])
            reference(obs)
            t = time.perf_counter()
            for _ in range(30):
                reference(obs)
            seconds.append((time.perf_counter() - t) / 30)
            env.close()
    return {
        "reference_s": round(statistics.mean(seconds), 6),
        "record_demos_fixed_s": round(record_s, 2),
        "what": "reference_s: BasePolicy.reference_chunk on num_envs envs' observations (embedded-mlp), mean over "
        "the tasks; record_demos_fixed_s: write_demos of 2 searching-expert demos of nist/rect_peg in a fresh "
        "process's first call (imports and the lerobot dataset; its physics is a few hundred control steps)",
        "load_avg_1min": before,
    }


def finetune_coefficient(seconds: float | None) -> dict:
    if seconds is not None:
        return {"seconds_per_stage": seconds, "steps": 800, "source": "--finetune-s", "load_avg_1min": load()}
    row = json.loads(PERF.read_text()).get("finetune") if PERF.is_file() else None
    if row is None:
        raise SystemExit("error: no finetune row in perf.json: run perf_report.py --row finetune or give --finetune-s")
    steps = int(re.search(r"(\d+) steps of", row["what"])[1])
    return {
        "seconds_per_stage": row["in_process_training_set_built_s"],
        "steps": steps,
        "source": f"benchmarks/results/perf.json finetune row (`{row['command']}`, {row['date']}): in-process, "
        "training set built",
        "load_avg_1min": row["machine_before"]["load_avg_1min"],
    }


def overhead_coefficient(physics: dict) -> dict:
    """A step that does nothing (perf.json's cell row: cache-teacher and handoff) and one env build."""
    row = json.loads(PERF.read_text()).get("cell", {}) if PERF.is_file() else {}
    idle = [s for name, s in row.get("step_seconds", []) if name in ("cache-teacher", "handoff")]
    return {
        "step_s": round(statistics.median(idle), 2) if idle else 0.0,
        "env_build_s": round(statistics.mean(p["env_build_s"] for p in physics.values()), 3),
        "source": "step_s: median committed cache-teacher/handoff seconds of perf.json's cell row; env_build_s: "
        "the physics measurements' make_vec_env + reset",
        "load_avg_1min": row.get("machine_before", {}).get("load_avg_1min"),
    }


def demo_success() -> dict:
    """record-demos' success per task: contact_experts.json's limited demonstrator (it records with it)."""
    if not EXPERTS.is_file():
        return {}
    return {t: r["no_search"] for t, r in json.loads(EXPERTS.read_text())["tasks"].items()}


def measure(workflows: list, episodes: int, updates: int, finetune_s: float | None) -> dict:
    physics_needs, learner_needs = needs(workflows)
    physics = {}
    for key, config in physics_needs.items():
        physics[key] = measure_physics(config, episodes)
        p = physics[key]
        print(
            f"physics {key}: {p['control_steps_per_s']} control steps/s, {p['mean_episode_steps']} steps an "
            f"episode ({p['seconds']} s, load {p['load_avg_1min']})",
            flush=True,
        )
    learners = measure_learners(learner_needs, updates)
    for key, r in learners.items():
        print(
            f"learner {key}: {r['first_update_s'] * 1e3:.1f} / {r['later_update_s'] * 1e3:.1f} ms an update "
            f"(stage 1 / later), load {r['load_avg_1min']}",
            flush=True,
        )
    base = measure_base_policy(physics_needs)
    print(
        f"base policy: {base['reference_s'] * 1e3:.2f} ms a chunk; record-demos fixed {base['record_demos_fixed_s']} s"
    )
    return {
        "physics": physics,
        "learner": learners,
        "base_policy": base,
        "finetune": finetune_coefficient(finetune_s),
        "overhead": overhead_coefficient(physics),
        "demo_success": demo_success(),
    }


# --------------------------------------------------------------------------- validation
PROTOCOL_CHANGE = "90cc40a"  # train: earlier tasks scored once, at the chosen checkpoint


def protocol_at(commit: str | None = None, mtime: float | None = None) -> str:
    """The evaluation protocol a measurement ran under: from its commit, else its time, against the change."""
    import subprocess

    git = lambda *a: subprocess.run(["git", *a], cwd=ROOT, capture_output=True, text=True)  # noqa: E731
    if commit:
        return "old" if git("merge-base", "--is-ancestor", commit, f"{PROTOCOL_CHANGE}~1").returncode == 0 else "new"
    changed = float(git("log", "-1", "--format=%ct", PROTOCOL_CHANGE).stdout.strip() or 0)
    return "new" if (mtime or 0) > changed else "old"


def compare(measured: list[tuple[int, str, float]], steps: list[dict], protocol: str) -> list[dict]:
    model = {(s["stage"], s["step"]): sum(s["parts"][protocol].values()) for s in steps}
    return [
        {
            "stage": k,
            "step": name,
            "measured_s": round(m, 1),
            "model_s": round(model[(k, name)], 1),
            "measured_over_model": round(m / max(model[(k, name)], 1e-9), 2),
        }
        for k, name, m in measured
        if (k, name) in model and name not in ("cache-teacher", "handoff")
    ]


def validate_perf_cell(coef: dict) -> dict | None:
    """perf.json's cell row: the quickstart's first cell, every step run (none cached)."""
    from stages.workflow import load_workflow

    row = json.loads(PERF.read_text()).get("cell") if PERF.is_file() else None
    if not row:
        return None
    steps = cell_steps(load_workflow(QUICKSTART), coef)
    first = row["step_seconds"][: len(steps)]
    if [name for name, _ in first] != [s["step"] for s in steps]:
        return {"skipped": "perf.json's cell row does not list the quickstart's steps in order"}
    protocol = protocol_at(commit=row["software"]["commit"])
    rows = compare([(s["stage"], s["step"], sec) for s, (_, sec) in zip(steps, first)], steps, protocol)
    total_m = sum(sec for _, sec in first)
    total_p = sum(sum(s["parts"][protocol].values()) for s in steps)
    return {
        "what": f"perf.json's cell row ({row['date']}, commit {row['software']['commit']}): workflows/quickstart.yaml "
        f"from scratch, under the {protocol} protocol; 1-min load {row['machine_before']['load_avg_1min']} -> "
        f"{row['machine_after']['load_avg_1min']} while it ran ({row.get('note', '')})",
        "protocol": protocol,
        "steps": rows,
        "cell_measured_s": round(total_m, 1),
        "cell_model_s": round(total_p, 1),
        "cell_measured_over_model": round(total_m / total_p, 2),
    }


LINE = re.compile(r"^step ([\w-]+): (?:cached|committed record \S+ in ([\d.]+) s)")


def validate_logs(coef: dict, root: Path = LOGS) -> list[dict]:
    """Committed steps in `accrue bench` cell logs (runs/bench/<spec>/logs/<cell>.log), against the model."""
    from stages.bench.spec import load_spec

    specs, out = {}, []
    for log in sorted(root.glob("*/logs/*.log")):
        name = log.stem
        spec_file = ROOT / "workflows" / "bench" / f"{name.split('.')[0]}.yaml"
        if not spec_file.is_file():
            continue
        spec = specs.setdefault(spec_file, load_spec(spec_file))
        cell = next((c for c in spec.cells if c.name == name), None)
        if cell is None:  # the spec changed since: its cells have other names
            continue
        seen: dict[str, int] = {}
        measured = []
        for line in log.read_text(errors="replace").splitlines():
            m = LINE.match(line)
            if m:
                seen[m[1]] = seen.get(m[1], 0) + 1
                if m[2]:
                    measured.append((seen[m[1]], m[1], float(m[2])))
        rows = compare(measured, cell_steps(cell.workflow, coef), protocol_at(mtime=log.stat().st_mtime))
        out += [{"cell": name, **r} for r in rows]
    return out


# --------------------------------------------------------------------------- output
def arrow(d: dict, fmt: str = "{:.1f}") -> str:
    return f"{fmt.format(d['old'])} → {fmt.format(d['new'])}"


def markdown(result: dict) -> str:
    coef, proj = result["coefficients"], result["projections"]
    loads = [v["load_avg_1min"] for part in ("physics", "learner") for v in coef[part].values()]
    lines = [
        "| spec | cells | cell min (old → new protocol) | core-h | grid h, 2 cores | grid h, 16 cores |",
        "|---|---|---|---|---|---|",
    ]
    for name, p in proj.items():
        label = f"**{name}** ({' + '.join(p['specs'])})" if "specs" in p else f"`{name}`"
        mean = {q: p["cell_min"][q]["mean"] for q in PROTOCOLS}
        lines.append(
            f"| {label} | {p['cells']} | {arrow(mean)} | {arrow(p['core_h_cache_shared'])} | {arrow(p['grid_h']['2'])} "
            f"| {arrow(p['grid_h']['16'])} |"
        )
    val = result.get("validation", {})
    checks = []
    if (cell := val.get("perf_cell")) and "cell_measured_over_model" in cell:
        checks.append(f"the quickstart cell of perf.json measured {cell['cell_measured_over_model']}× the model")
    trains = [r["measured_over_model"] for r in val.get("logs", []) if r["step"] == "train"]
    if trains:
        checks.append(f"{len(trains)} train steps in bench logs measured {min(trains)}–{max(trains)}× the model")
    lines += [
        "",
        f"Projected by `{result['command']}` from coefficients measured {result['coefficients_date']} at commit "
        f"{result['coefficients_software']['commit']} on a {result['machine_before']['cores']}-core machine "
        f"**shared with other jobs** (1-min load {min(loads)}–{max(loads)} while measuring): an upper bound on an "
        "idle machine's. A cell runs on one core, `cores` cells at a time; steps that cells share through the "
        "step cache are paid once (core-h and grid h count them once; cell minutes count every step of the "
        "cell). Old protocol: every task at every grid point; new: earlier tasks once, at the chosen checkpoint."
        + (f" Validation: {'; '.join(checks)}." if checks else ""),
    ]
    return "\n".join(lines)


def committed(path: Path = OUT) -> tuple[dict, dict]:
    """The coefficients a cost_model.json holds, and when and on what they were measured."""
    previous = json.loads(path.read_text()) if path.is_file() else {}
    if "coefficients" not in previous:
        raise SystemExit(f"error: no coefficients in {path}: run benchmarks/cost_model.py --measure")
    return previous["coefficients"], {k: previous[k] for k in ("coefficients_date", "coefficients_software")}


def _measuring_args(argv: list[str]) -> list[str]:
    """argv without what changes no figure (perf_report's rule: --out FILE, --note TEXT; and --markdown)."""
    return [a for a in perf_report._measuring_args(argv) if a != "--markdown"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--measure", action="store_true", help="measure the coefficients (else: read them from --out)")
    ap.add_argument("--specs", nargs="+", default=list(SPECS), help="bench specs (workflows/bench/NAME.yaml)")
    ap.add_argument("--episodes", type=int, default=32, help="measure: demonstrator episodes per task")
    ap.add_argument("--updates", type=int, default=60, help="measure: timed gradient updates per learner setting")
    ap.add_argument("--finetune-s", type=float, help="finetune-base seconds a stage (800 steps), not perf.json's")
    ap.add_argument("--no-validation", action="store_true", help="skip the comparison with measured stages")
    ap.add_argument("--markdown", action="store_true", help="print the projection as a markdown table")
    ap.add_argument("--note", default=SHARED)
    ap.add_argument("--coefficients", type=Path, help="without --measure: read them from this JSON (default: --out)")
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args()
    source = args.coefficients or args.out
    before, started = machine(), time.perf_counter()
    if args.measure:
        from stages.workflow import load_workflow

        workflows = [c.workflow for s in args.specs for c in spec_cells(s)]
        workflows += [] if args.no_validation else [load_workflow(QUICKSTART)]
        coef = measure(workflows, args.episodes, args.updates, args.finetune_s)
        dated = {
            "coefficients_date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "coefficients_software": software(),
        }
    else:
        coef, dated = committed(source)
    result = {
        "what": "bench cells and grids projected from measured coefficients (benchmarks/cost_model.py's docstring)",
        "command": shlex.join(["python", "benchmarks/cost_model.py", *_measuring_args(sys.argv[1:])]),
        **dated,
        "note": args.note,
        "coefficients": coef,
        "projections": projections(args.specs, coef),
        "validation": {}
        if args.no_validation
        else {"perf_cell": validate_perf_cell(coef), "logs": validate_logs(coef)},
        "machine_before": before,
        "machine_after": machine(),
        "software": software(),
        "wall_s": round(time.perf_counter() - started, 1),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(markdown(result) if args.markdown else json.dumps(result["projections"], indent=1))


if __name__ == "__main__":
    main()
