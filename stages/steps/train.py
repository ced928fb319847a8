"""`train`: one stage of off-policy RL on action chunks (paper Algorithm 1, lines 1-10).

Inputs: `base-policy` (π_base^k), `replay` (B^k's warmup shard), and from stage 2 on `handoff`
(θ^{k-1}, ψ^{k-1}, B^{<k}) and `teacher` (Eq. 3 targets). Outputs: `checkpoint` (θ^k, ψ^k and the
whole learner state), `replay` (every shard of B^k) and `curve` (success on tasks 1..k every E env
steps, curve.json). Intra-step checkpoints (learner + the replay shards appended since the last one
+ loop counters) are saved at fixed env-step points, so `--continue` after a kill repeats nothing
that was saved and ends with the same bytes as a run that never stopped.
"""
from __future__ import annotations

from pathlib import Path

from stages.errors import StageError
from stages.runner_context import StepContext
from stages.runner_types import StepDef
from stages.steps.cache_teacher import load_targets
from stages.steps.common import (copy_tree, deterministic, load_base_policy, make_env, per_task_features, read_json,
                                 reference_fn, write_json)

LOOP_FILE = "loop.json"


def per_task_learners(handoff: Path | None) -> dict[int, Path]:
    """Isolated: stage index i -> the learner kept for task i (handoff/per_task/<i>/)."""
    if handoff is None or not (handoff / "per_task").is_dir():
        return {}
    return {int(p.name): p for p in sorted((handoff / "per_task").iterdir())}


def fisher_batch(memory, task_index: int, samples: int):
    """EWC: the previous task's last `samples` retained transitions."""
    import torch

    rows = torch.nonzero(memory.column("task") == task_index).flatten()[-samples:]
    if rows.numel() == 0:
        raise StageError("method ewc needs retained transitions of the previous task for its Fisher: "
                         "set budgets.retained_episodes > 0")
    return memory.gather(rows)


def run(ctx: StepContext) -> None:
    import time

    from accrue import rl_loop
    from accrue.learner import ReplayBuffer, begin_stage, end_stage, load_learner
    from accrue.learner.continual import stage_plan
    from stages.steps.common import learner_config

    c = ctx.config
    k, tasks, horizon, seed = c["stage"], c["task_ids"], c["horizon"], c["seed"]
    task = tasks[-1]
    deterministic(seed)
    import torch

    settings = dict(c["learner"])
    if "device" not in settings:    # not pinned by the workflow: the GPU when there is one
        settings["device"] = "cuda" if torch.cuda.is_available() else "cpu"
    cfg = learner_config(settings)
    dev = cfg.device
    plan = stage_plan(cfg.method, cfg.ablation)

    # π_base^k, held fixed during the stage, proposes ã for every task (fresh references, Sec. IV-C)
    policy = load_base_policy(ctx.input_path("base-policy"), seed)
    references = {t: reference_fn(policy, t, horizon) for t in tasks}
    features = per_task_features(c, tasks)

    # what the stage inherits: (θ^{k-1}, ψ^{k-1}, B^{<k}) and the cached Eq. 3 targets
    handoff = ctx.input_path("handoff") if ctx.has_input("handoff") else None
    prev = load_learner(handoff / "learner", device=dev) if handoff else None
    prior = ReplayBuffer.load(handoff / "memory") if handoff else None
    teacher = load_targets(ctx.input_path("teacher")) if ctx.has_input("teacher") else None
    kept = per_task_learners(handoff) if plan.checkpoint_per_task else {}
    frozen = {tasks[i - 1]: rl_loop.actor_act(load_learner(p, device=dev)) for i, p in kept.items()}

    warm = read_json(ctx.input_path("replay") / "warmup.json")
    resume = ctx.last_checkpoint()
    if resume is None:
        buffer = ReplayBuffer.load(ctx.input_path("replay"))                          # B^k from warmup
        fisher = fisher_batch(prior, k - 2, cfg.ewc_samples) if plan.needs_fisher and prev else None
        learner = begin_stage(prev, cfg, buffer.state_dim, horizon, fisher_batch=fisher)   # line 1
        state = rl_loop.LoopState(next_episode=warm["next_episode"])
    else:
        ck, progress = resume
        buffer = ReplayBuffer.load(ck / "replay")
        learner = load_learner(ck / "learner", device=dev)
        state = rl_loop.LoopState.from_json(read_json(ck / LOOP_FILE))
        ctx.console.print(f"train: resumed at env step {state.env_steps} ({state.updates} updates)")

    env = make_env(task, c["num_envs"], rl_loop.env_seed(seed, k, "train"), c["obs_mode"])
    collector = rl_loop.ChunkCollector(env, references[task], features[task], buffer, task_index=k - 1,
                                       gamma=cfg.gamma, next_episode=state.next_episode)
    if resume is None:
        collector.restart()
    else:
        rl_loop.restore_collector(collector, state)
    evaluator = rl_loop.Evaluator(
        lambda t, n: make_env(t, n, rl_loop.env_seed(seed, k, "eval", tasks.index(t)), c["obs_mode"]),
        references, features, c["eval_episodes"], c["num_envs"], horizon, cfg.gamma)
    from accrue.sim import get_task

    episode_span = c["num_envs"] * get_task(task).max_steps    # env steps for every env to run one episode
    loop = rl_loop.LoopSettings(tasks, c["env_steps"], c["eval_every"], c["checkpoint_every"],
                                min_checkpoint_gap=2 * episode_span)

    staging = ctx.scratch_dir("checkpoint")

    def save_checkpoint(st: rl_loop.LoopState) -> None:
        learner.save(staging / "learner")
        buffer.save_new_shards(staging / "replay")      # only the shards appended since the last one
        write_json(staging / LOOP_FILE, st.to_json())
        ctx.save_checkpoint(staging, {"env_steps": st.env_steps, "updates": st.updates})

    clock = {"t": time.monotonic(), "updates": state.updates}

    def show(st: rl_loop.LoopState, info: dict) -> None:
        now = time.monotonic()
        rate = (st.updates - clock["updates"]) / max(now - clock["t"], 1e-9)
        clock.update(t=now, updates=st.updates)
        line = (f"train: env steps {st.env_steps}/{loop.env_steps}  updates {st.updates} ({rate:.0f}/s)  "
                f"episodes {st.episodes} (success {st.successes / max(st.episodes, 1):.2f})")
        if "eval" in info:
            line += "  eval " + " ".join(f"{t}={r:.2f}" for t, r in info["eval"].items())
        ctx.console.print(line, soft_wrap=True)

    state = rl_loop.train_loop(learner, collector, evaluator, loop, prior=prior, teacher=teacher,
                               state=state, frozen_acts=frozen, on_checkpoint=save_checkpoint, on_progress=show)
    end_stage(learner)                       # RETAIN merges here; the others hand over as they are
    env.close()
    evaluator.close()

    out = ctx.new_output("checkpoint", "checkpoint")
    learner.save(out / "learner")
    for i, p in kept.items():
        copy_tree(p, out / "per_task" / str(i))
    write_json(out / "checkpoint.json", {"stage": k, "task_ids": tasks, "method": cfg.method,
                                         "per_task": sorted(kept), "env_steps": state.env_steps,
                                         "updates": state.updates})
    buffer.save_new_shards(ctx.new_output("replay", "replay"))
    write_json(ctx.new_output("curve", "eval") / "curve.json", {
        "stage": k, "task_ids": tasks, "grid": sorted(state.grid_done),
        "success": {t: state.curve[t] for t in tasks}, "episodes_per_point": c["eval_episodes"],
        "method": cfg.method, "ablation": cfg.ablation, "seed": seed, "env_steps": state.env_steps,
        "updates": state.updates, "train_episodes": state.episodes, "train_successes": state.successes})


STEP = StepDef(name="train", code_version="train-2", run=run, inputs=("base-policy", "replay"),
               optional_inputs=("handoff", "teacher"),
               outputs={"checkpoint": "checkpoint", "replay": "replay", "curve": "eval"},
               description="off-policy RL on chunks with an evaluation grid and resumable checkpoints")
