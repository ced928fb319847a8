"""Run one stage of RL directly (sim + reference + learner, no store) to see whether RL beats its reference.

    .venv/bin/python scripts/rl_stage_probe.py nist/round_peg --base runs/base-policy-checkpoint
    .venv/bin/python scripts/rl_stage_probe.py nist/round_peg --standin 0.0 --env-steps 12000

--base uses a lerobot base-policy checkpoint (what the workflows use). --standin F is a tuning aid for
when no competent base policy is at hand: the scripted expert, acting statelessly (no search), that knows
only the fraction F of its fixture's socket-estimate bias, its action held as one H-step chunk (the
first step moves the target, the rest keep descending) — a reference with a systematic error the
actor can learn to correct. Prints the success of the reference alone and the curve of the actor.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch

from accrue import rl_loop
from accrue.learner import LearnerConfig, ReplayBuffer, make_learner
from accrue.learner_inputs import state_features
from accrue.sim import get_task, make_expert, make_vec_env


def standin_reference(task_id: str, horizon: int, known_bias: float):
    bias = np.asarray(get_task(task_id).estimate_bias)

    def reference(obs: dict) -> np.ndarray:
        expert = make_expert(task_id, quality=1.0, seed=0, correction=-bias * known_bias)  # fresh: stateless
        a = expert.act(obs["state"])
        chunk = np.zeros((len(a), horizon, 6), dtype=np.float32)
        chunk[:, 0] = a
        chunk[:, 1:, 2] = a[:, None, 2]
        return chunk

    return reference


def base_reference(checkpoint: str, task_id: str, horizon: int):
    from accrue.policy import BasePolicy

    policy = BasePolicy.load(checkpoint)
    instruction = get_task(task_id).instruction
    return lambda obs: policy.reference_chunk(obs, instruction, horizon)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("task")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--base", help="lerobot base-policy checkpoint directory")
    src.add_argument("--standin", type=float, metavar="F", help="scripted stand-in knowing fraction F of the bias")
    p.add_argument("--horizon", type=int, default=4)
    p.add_argument("--num-envs", type=int, default=8)
    p.add_argument("--env-steps", type=int, default=12000)
    p.add_argument("--eval-every", type=int, default=3000)
    p.add_argument("--eval-episodes", type=int, default=40)
    p.add_argument("--warmup-episodes", type=int, default=16)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--learner", default="{}", help="LearnerConfig overrides as JSON, e.g. '{\"utd\": 4}'")
    args = p.parse_args()

    torch.set_num_threads(1)
    torch.manual_seed(args.seed)
    H = args.horizon
    reference = (
        standin_reference(args.task, H, args.standin)
        if args.standin is not None
        else base_reference(args.base, args.task, H)
    )
    cfg = LearnerConfig.from_dict({"seed": args.seed, **json.loads(args.learner)})
    env = make_vec_env(args.task, args.num_envs, seed=rl_loop.env_seed(args.seed, 1, "train"))
    features = state_features
    buffer = ReplayBuffer(features(env.reset()).shape[1], H)
    learner = make_learner(cfg, buffer.state_dim, H)
    collector = rl_loop.ChunkCollector(env, reference, features, buffer, task_index=0, gamma=cfg.gamma)
    collector.restart()
    warm = rl_loop.warmup(collector, args.warmup_episodes)
    print(f"warmup: {warm.episodes} episodes, {warm.successes} successes, {len(buffer)} transitions")
    evaluator = rl_loop.Evaluator(
        lambda t, n: make_vec_env(t, n, seed=rl_loop.env_seed(args.seed, 1, "eval", 0)),
        {args.task: reference},
        features,
        args.eval_episodes,
        min(args.num_envs, 10),
        H,
        cfg.gamma,
    )
    print(f"reference alone: {evaluator.success_rate(args.task):.3f}")
    started = time.monotonic()

    def show(st, info):
        if "eval" in info:
            print(
                f"env steps {st.env_steps:6d}  updates {st.updates:5d}  train success "
                f"{st.successes / max(st.episodes, 1):.2f}  eval {info['eval'][args.task]:.3f}  "
                f"({time.monotonic() - started:.0f} s)",
                flush=True,
            )

    settings = rl_loop.LoopSettings([args.task], args.env_steps, args.eval_every, 0)
    rl_loop.train_loop(learner, collector, evaluator, settings, on_progress=show)


if __name__ == "__main__":
    main()
