"""One paper-scale RL stage, timed, with where the time goes: 500k env steps, 64 envs, H = 16 and the
paper's learner (LearnerConfig.paper(): FastSAC sizes, batch 8192, UTD 8, bf16 and torch.compile on CUDA).

    .venv/bin/python benchmarks/paper_stage.py --out benchmarks/results/paper_stage_gpu.json      # a GPU machine
    .venv/bin/python benchmarks/paper_stage.py --device cpu --env-steps 4096 --num-envs 8 --batch 256 --small

The reference ã is the scripted demonstrator that never searches (accrue.sim's expert, search=False), held
as one H-step chunk, so the stage needs no base-policy weights; its cost is reported as `reference` and a
real π_base adds its own inference time. The stage runs accrue.rl_loop exactly as the train step does
(warmup, then act / step / store / update, an evaluation every --eval-every env steps on the current
task). Each part of the loop is timed by wrapping the call that does it:

    physics      env.step_chunk (MuJoCo on CPU: one process, the envs one after another)
    reference    π_base's chunk for every env that needs one
    act          the actor's chunk (with exploration) for every env
    store        replay insertion
    update       learner.train_step: UTD gradient updates (critic, actor, target)
    evaluate     the evaluation grid (its own physics and acting inside)

MuJoCo Warp (GPU physics) would replace `physics`; benchmarks/gpu_path.py measures which contact tasks it
can step (their mesh collisions) and says where it cannot.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


class Timers:
    """Seconds spent per part; `wrap(obj, name, part)` times every call of obj.name, `timed(fn, part)` of fn."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self._depth = 0  # parts nested in another (evaluate's physics) count only for the outer one

    def timed(self, inner, part: str):
        """`inner`, with its wall time added to `part`."""

        def call(*args, **kw):
            if self._depth:
                return inner(*args, **kw)
            self._depth += 1
            start = time.perf_counter()
            try:
                return inner(*args, **kw)
            finally:
                self.seconds[part] += time.perf_counter() - start
                self.calls[part] += 1
                self._depth -= 1

        return call

    def wrap(self, obj, name: str, part: str) -> None:
        setattr(obj, name, self.timed(getattr(obj, name), part))


def demonstrator_reference(task_id: str, horizon: int):
    """The demonstrator that never searches, its action held for the whole chunk (stateless per call)."""
    import numpy as np

    from accrue.sim import make_expert

    def reference(obs: dict) -> np.ndarray:
        a = make_expert(task_id, quality=1.0, seed=0, search=False).act(obs["state"])
        return np.repeat(a[:, None, :], horizon, axis=1).astype(np.float32)

    return reference


def run(args) -> dict:
    import torch

    from accrue import rl_loop
    from accrue.learner import LearnerConfig, ReplayBuffer, make_learner
    from accrue.learner_inputs import state_features
    from accrue.sim import make_vec_env

    torch.manual_seed(args.seed)
    if args.device == "cpu":
        torch.set_num_threads(args.threads)
    overrides = {"device": args.device, "seed": args.seed}
    if args.device == "cpu":  # bf16 autocast and compile are the GPU path's; CPU measures plain eager
        overrides.update(amp=False, compile=False)
    if args.batch:
        overrides["batch_size"] = args.batch
    if args.small:  # the CPU smoke size: the paper's structure, small networks
        overrides.update(actor_hidden=[64, 64], critic_hidden=[64, 64], projector_dim=32, utd=2)
    cfg = LearnerConfig.paper(**overrides)
    timers = Timers()
    horizon, task = args.horizon, args.task

    env = make_vec_env(task, args.num_envs, seed=rl_loop.env_seed(args.seed, 1, "train"))
    timers.wrap(env, "step_chunk", "physics")
    reference = timers.timed(demonstrator_reference(task, horizon), "reference")
    buffer = ReplayBuffer(state_features(env.reset()).shape[1], horizon, device=args.buffer_device)
    timers.wrap(buffer, "add", "store")
    learner = make_learner(cfg, buffer.state_dim, horizon)
    timers.wrap(learner, "act", "act")
    timers.wrap(learner, "train_step", "update")
    collector = rl_loop.ChunkCollector(env, reference, state_features, buffer, task_index=0, gamma=cfg.gamma)
    collector.restart()

    started = time.perf_counter()
    warm = rl_loop.warmup(collector, args.warmup_episodes)
    warmup_s = time.perf_counter() - started
    evaluator = rl_loop.Evaluator(
        lambda t, n: make_vec_env(t, n, seed=rl_loop.env_seed(args.seed, 1, "eval", 0)),
        {task: reference},
        state_features,
        args.eval_episodes,
        args.num_envs,
        horizon,
        cfg.gamma,
    )
    timers.wrap(evaluator, "success_rate", "evaluate")
    settings = rl_loop.LoopSettings([task], args.env_steps, args.eval_every, 0)
    last = {"t": time.perf_counter()}

    def show(st, info):
        if time.perf_counter() - last["t"] > 10 or "eval" in info:
            last["t"] = time.perf_counter()
            done = time.perf_counter() - started
            line = f"env steps {st.env_steps}/{args.env_steps}  updates {st.updates}  {done:.0f} s"
            if st.env_steps:
                line += f", ~{done / st.env_steps * (args.env_steps - st.env_steps):.0f} s left"
            if "eval" in info:
                line += f"  eval {info['eval'][task]:.2f}"
            print(line, flush=True)

    state = rl_loop.train_loop(learner, collector, evaluator, settings, on_progress=show)
    total = time.perf_counter() - started
    env.close()
    evaluator.close()
    parts = {k: round(v, 2) for k, v in sorted(timers.seconds.items())}
    parts["other"] = round(total - sum(timers.seconds.values()), 2)
    return {
        "command": "python " + " ".join(sys.argv),
        "task": task,
        "env_steps": state.env_steps,
        "num_envs": args.num_envs,
        "horizon": horizon,
        "updates": state.updates,
        "learner": {k: getattr(cfg, k) for k in ("algo", "batch_size", "utd", "actor_hidden", "critic_hidden")}
        | {"device": args.device, "amp": cfg.amp, "compile": cfg.compile},
        "warmup": {"episodes": warm.episodes, "seconds": round(warmup_s, 2)},
        "total_s": round(total, 2),
        "seconds": parts,
        "share": {k: round(v / total, 3) for k, v in parts.items()},
        "env_steps_per_s": round(state.env_steps / total, 1),
        "updates_per_s": round(state.updates / max(timers.seconds["update"], 1e-9), 1),
        "eval_curve": state.curve[task],
        "machine": {
            "cpu_count": os.cpu_count(),
            "load_avg_1min_after": round(os.getloadavg()[0], 2),
            "platform": platform.platform(),
            "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        },
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", default="contact/keyed_peg")
    p.add_argument("--env-steps", type=int, default=500_000)
    p.add_argument("--num-envs", type=int, default=64)
    p.add_argument("--horizon", type=int, default=16)
    p.add_argument("--eval-every", type=int, default=50_000)
    p.add_argument("--eval-episodes", type=int, default=64)
    p.add_argument("--warmup-episodes", type=int, default=64)
    p.add_argument("--device", default="cuda")
    p.add_argument("--buffer-device", default="cpu")
    p.add_argument("--batch", type=int, default=0, help="batch size (default: the paper's 8192)")
    p.add_argument("--threads", type=int, default=1, help="torch threads on CPU")
    p.add_argument("--small", action="store_true", help="small networks (a CPU smoke run)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path)
    args = p.parse_args()
    result = run(args)
    print(json.dumps({k: result[k] for k in ("total_s", "seconds", "share", "env_steps_per_s")}, indent=1))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
