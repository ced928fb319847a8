"""`train`: one stage of off-policy RL on action chunks (paper Algorithm 1, lines 1 and 4-10).

Inputs: `base-policy` (π_base^k), `replay` (B^k's warmup shard), and from stage 2 on `handoff`
(θ^{k-1}, ψ^{k-1}, B^{<k}) and `teacher` (Eq. 3 targets). Outputs: `checkpoint` (θ^k, ψ^k and the
whole learner state), `replay` (every shard of B^k) and `curve` (success on tasks 1..k every E env
steps). Intra-step checkpoints (learner + the replay shards appended since the last one + loop
counters) are saved at fixed env-step points, so `--continue` after a kill repeats nothing that was
saved and ends with the same bytes as a run that never stopped.
"""

from __future__ import annotations

from stages.runner_context import StepContext
from stages.runner_types import StepDef
from stages.steps import handoff as handoff_step
from stages.steps import warmup as warmup_step
from stages.steps.cache_teacher import load_teacher
from stages.steps.checkpoint_layout import CHECKPOINT_FILE, LEARNER_DIR, PER_TASK_DIR  # noqa: F401 - train_step.X
from stages.steps.common import (
    copy_tree,
    deterministic,
    learner_config,
    load_base_policy,
    make_env,
    per_task_features,
    read_json,
    reference_fn,
    write_json,
)

REPLAY_DIR, LOOP_FILE = "replay", "loop.json"  # intra-step checkpoints only
CURVE_FILE = "curve.json"  # the `curve` output


def bind_tracking(steps, spec, workflow: str, root: str | None = None) -> tuple:
    """The stage's step invocations with the train step's tracking bound (outside its cache key):
    spec is the workflow's tracking section, root where runs go (default <store>/log/tracking)."""
    import dataclasses
    import functools

    bound = {"spec": spec.model_dump() if hasattr(spec, "model_dump") else spec, "workflow": workflow, "root": root}
    return tuple(
        dataclasses.replace(inv, step=dataclasses.replace(inv.step, run=functools.partial(run, tracking=bound)))
        if inv.step.name == STEP.name and getattr(inv.step.run, "func", inv.step.run) is run  # rebinds a bound one
        else inv
        for inv in steps
    )


def open_step_tracker(ctx: StepContext, tracking: dict | None, stage: int, fallback_workflow: str):
    """The step's tracker (accrue.tracking) at <root>/<workflow>/stage-<k>/<step>/, root by default
    <store>/log/tracking.

    `tracking` is bound by bind_tracking: {"spec": the workflow's tracking section, "workflow": its name,
    "root": None or a directory}. Unbound, the defaults apply (TensorBoard on) under `fallback_workflow`."""
    from pathlib import Path

    from accrue.tracking import open_tracker, run_name, tracking_dir

    tracking = tracking or {}
    name = run_name(tracking.get("workflow") or fallback_workflow, stage, ctx.step)
    root = tracking.get("root")
    return open_tracker(
        tracking.get("spec"),
        Path(root) / name if root else tracking_dir(ctx.store.root, name),
        name,
        warn=lambda line: ctx.console.print(f"warning: {line}", style="yellow", markup=False, soft_wrap=True),
    )


def loss_tracking(tracker, start_updates: int):
    """on_update for rl_loop: the learner's losses and Q, and the running train success, once per
    `tracking.every` updates, against env steps."""
    mark = {"bucket": start_updates // tracker.every}

    def on_update(st, info: dict) -> None:
        bucket = st.updates // tracker.every
        if not tracker.enabled or bucket <= mark["bucket"]:
            return
        mark["bucket"] = bucket
        values = {f"train/{key}": value for key, value in info.items()}
        values.update(
            {
                "train/updates": st.updates,
                "train/episodes": st.episodes,
                "train/success_rate": st.successes / max(st.episodes, 1),
            }
        )
        tracker.scalars(values, st.env_steps)

    return on_update


def run(ctx: StepContext, tracking: dict | None = None) -> None:
    import time

    import torch

    from accrue import rl_loop, stage_rl
    from accrue.learner import ReplayBuffer, load_learner, save_learner
    from accrue.sim import get_task

    c = ctx.config
    k, tasks, horizon, seed = c["stage"], c["task_ids"], c["horizon"], c["seed"]
    task = tasks[-1]
    deterministic(seed)
    settings = dict(c["learner"])
    if "device" not in settings:  # not pinned by the workflow: the GPU when there is one
        settings["device"] = "cuda" if torch.cuda.is_available() else "cpu"
    cfg = learner_config(settings)
    dev = cfg.device

    # π_base^k, held fixed during the stage, proposes ã for every task (fresh references, Sec. IV-C)
    policy = load_base_policy(ctx.input_path("base-policy"), seed)
    references = {t: reference_fn(policy, t, horizon) for t in tasks}
    features = per_task_features(c, tasks)

    # what the stage inherits: (θ^{k-1}, ψ^{k-1}, B^{<k}) and the cached Eq. 3 targets
    handoff = ctx.input_path("handoff") if ctx.has_input("handoff") else None
    previous = load_learner(handoff / handoff_step.LEARNER_DIR, device=dev) if handoff else None
    memory = ReplayBuffer.load(handoff / handoff_step.MEMORY_DIR) if handoff else None
    teacher = load_teacher(ctx.input_path("teacher")) if ctx.has_input("teacher") else None
    kept = handoff_step.per_task_learners(handoff) if cfg.rules.checkpoint_per_task else {}
    frozen = {tasks[i - 1]: rl_loop.actor_act(load_learner(p, device=dev)) for i, p in kept.items()}

    checkpoint = ctx.last_checkpoint()
    if checkpoint is None:
        buffer = ReplayBuffer.load(ctx.input_path("replay"))  # B^k from warmup
        next_episode = read_json(ctx.input_path("replay") / warmup_step.INFO_FILE)["next_episode"]
        resume = None
    else:
        ck, _ = checkpoint
        buffer = ReplayBuffer.load(ck / REPLAY_DIR)
        loop_state = rl_loop.LoopState.from_json(read_json(ck / LOOP_FILE))
        resume = (load_learner(ck / LEARNER_DIR, device=dev), loop_state)
        next_episode = loop_state.next_episode
        ctx.console.print(f"train: resumed at env step {loop_state.env_steps} ({loop_state.updates} updates)")

    env = make_env(task, c["num_envs"], rl_loop.env_seed(seed, k, "train"), c["obs_mode"])
    collector = rl_loop.ChunkCollector(
        env, references[task], features[task], buffer, task_index=k - 1, gamma=cfg.gamma, next_episode=next_episode
    )

    def evaluator_on(episode_set: str, episodes: int, report=None) -> rl_loop.Evaluator:
        return rl_loop.Evaluator(
            lambda t, n: make_env(t, n, rl_loop.env_seed(seed, k, episode_set, tasks.index(t)), c["obs_mode"]),
            references,
            features,
            episodes,
            c["num_envs"],
            horizon,
            cfg.gamma,
            report=report,
        )

    # the best checkpoint is chosen on the "eval" episodes and, with report_episodes, reported on disjoint ones
    report_set = evaluator_on("report", c["report_episodes"]) if c.get("report_episodes") else None
    evaluator = evaluator_on("eval", c["eval_episodes"], report_set)
    episode_span = c["num_envs"] * get_task(task).max_steps  # env steps for every env to run one episode
    loop = rl_loop.LoopSettings(
        tasks, c["env_steps"], c["eval_every"], c["checkpoint_every"], min_checkpoint_gap=2 * episode_span
    )

    staging = ctx.scratch_dir("checkpoint")

    def save_checkpoint(learner, st: rl_loop.LoopState) -> None:
        save_learner(learner, staging / LEARNER_DIR)
        buffer.save_new_shards(staging / REPLAY_DIR)  # only the shards appended since the last one
        write_json(staging / LOOP_FILE, st.to_json())
        ctx.save_checkpoint(staging, {"env_steps": st.env_steps, "updates": st.updates})

    clock = {"t": time.monotonic(), "updates": resume[1].updates if resume else 0}

    def show(st: rl_loop.LoopState, info: dict) -> None:
        now = time.monotonic()
        rate = (st.updates - clock["updates"]) / max(now - clock["t"], 1e-9)
        clock.update(t=now, updates=st.updates)
        line = (
            f"train: env steps {st.env_steps}/{loop.env_steps}  updates {st.updates} ({rate:.0f}/s)  "
            f"episodes {st.episodes} (success {st.successes / max(st.episodes, 1):.2f})"
        )
        if "eval" in info:
            line += "  eval " + " ".join(f"{t}={r:.2f}" for t, r in info["eval"].items())
        ctx.console.print(line, soft_wrap=True)
        if "eval" in info and st.grid_done:  # success on tasks 1..k at this grid point
            values = {f"eval/success/{t}": r for t, r in info["eval"].items()}
            values.update({f"eval/report_success/{t}": curve[-1] for t, curve in st.report_curve.items() if curve})
            tracker.scalars(values, st.grid_done[-1])

    # event files beside the store's audit log, never in an artifact (docs/TRACKING.md)
    with open_step_tracker(ctx, tracking, k, f"{cfg.method}-seed{seed}") as tracker:
        learner, state = stage_rl.train_stage(
            cfg,
            previous,
            memory,
            teacher,
            collector,
            evaluator,
            loop,
            frozen_acts=frozen,
            resume=resume,
            on_checkpoint=save_checkpoint,
            on_progress=show,
            on_update=loss_tracking(tracker, clock["updates"]),
        )
    env.close()
    evaluator.close()

    out = ctx.new_output("checkpoint", "checkpoint")
    save_learner(learner, out / LEARNER_DIR)
    for i, p in kept.items():
        copy_tree(p, out / PER_TASK_DIR / str(i))
    write_json(
        out / CHECKPOINT_FILE,
        {
            "stage": k,
            "task_ids": tasks,
            "method": cfg.method,
            "per_task": sorted(kept),
            "env_steps": state.env_steps,
            "updates": state.updates,
        },
    )
    buffer.save_new_shards(ctx.new_output("replay", "replay"))
    write_json(
        ctx.new_output("curve", "eval") / CURVE_FILE,
        {
            "stage": k,
            "task_ids": tasks,
            "grid": sorted(state.grid_done),
            "success": {t: state.curve[t] for t in tasks},
            "episodes_per_point": c["eval_episodes"],
            **(
                {"report_success": {t: state.report_curve[t] for t in tasks}, "report_episodes": c["report_episodes"]}
                if report_set is not None
                else {}
            ),
            "method": cfg.method,
            "ablation": cfg.ablation,
            "seed": seed,
            "env_steps": state.env_steps,
            "updates": state.updates,
            "train_episodes": state.episodes,
            "train_successes": state.successes,
        },
    )


STEP = StepDef(
    name="train",
    code_version="train-3",
    run=run,
    inputs=("base-policy", "replay"),
    optional_inputs=("handoff", "teacher"),
    outputs={"checkpoint": "checkpoint", "replay": "replay", "curve": "eval"},
    description="off-policy RL on chunks with an evaluation grid and resumable checkpoints",
)
