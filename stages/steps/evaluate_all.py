"""`evaluate-all`: row k of the success matrix, π_base^k + θ^k on tasks 1..k (M episodes each), the base
policy alone on the same episodes (for the report), and MCAP logs of a few episodes per task. With
budgets.report_episodes the episodes are the disjoint report set (never the selection set that train's
curves choose checkpoints on)."""

from __future__ import annotations

from stages.runner_context import StepContext
from stages.runner_types import StepDef
from stages.steps import train as train_step
from stages.steps.common import deterministic, load_base_policy, make_env, per_task_features, reference_fn, write_json

EVAL_FILE = "eval.json"  # the `eval` output: row k of the success matrix and the base policy alone


def run(ctx: StepContext) -> None:
    from accrue import rl_loop
    from accrue.learner import load_learner
    from accrue.logs.mcap_episodes import EpisodeRecorder
    from accrue.sim import STATE_NAMES, get_task

    c = ctx.config
    k, tasks, horizon, seed = c["stage"], c["task_ids"], c["horizon"], c["seed"]
    deterministic(seed)
    policy = load_base_policy(ctx.input_path("base-policy"), seed)
    references = {t: reference_fn(policy, t, horizon) for t in tasks}
    features = per_task_features(c, tasks)
    checkpoint = ctx.input_path("checkpoint")
    current = load_learner(checkpoint / train_step.LEARNER_DIR, device="cpu")
    # Isolated keeps one learner per task: task i is evaluated with checkpoint i
    per_task = checkpoint / train_step.PER_TASK_DIR
    learners = {
        t: (load_learner(per_task / str(i), device="cpu") if (per_task / str(i)).is_dir() else current)
        for i, t in enumerate(tasks, 1)
    }
    episode_set, episodes = ("report", c["report_episodes"]) if c.get("report_episodes") else ("eval", c["episodes"])
    evaluator = rl_loop.Evaluator(
        lambda t, n: make_env(t, n, rl_loop.env_seed(seed, k, episode_set, tasks.index(t)), c["obs_mode"]),
        references,
        features,
        episodes,
        c["num_envs"],
        horizon,
        c["gamma"],
    )
    success, base_success = {}, {}
    for t in tasks:
        success[t] = evaluator.success_rate(t, rl_loop.actor_act(learners[t]))
        base_success[t] = evaluator.success_rate(t)
        ctx.console.print(
            f"evaluate-all: {t}: actor {success[t]:.2f}  base policy alone {base_success[t]:.2f} "
            f"({episodes} {episode_set} episodes)"
        )
    evaluator.close()
    write_json(
        ctx.new_output("eval", "eval") / EVAL_FILE,
        {
            "stage": k,
            "task_ids": tasks,
            "success": success,
            "base_success": base_success,
            "episodes": episodes,
            **({"episode_set": episode_set} if episode_set == "report" else {}),
            "method": c["method"],
            "seed": seed,
            "per_task_checkpoint": sorted(t for t in tasks if learners[t] is not current),
        },
    )

    logs = ctx.new_output("episodes", "episodes")
    for i, t in enumerate(tasks):
        if c["record_episodes"] < 1:
            break
        env = make_env(t, c["record_episodes"], rl_loop.env_seed(seed, k, episode_set, i), c["obs_mode"])
        recorder = EpisodeRecorder(
            logs / t.replace("/", "__"), control_hz=get_task(t).control_hz, state_names=list(STATE_NAMES)
        )
        rl_loop.record_episodes(
            env,
            references[t],
            features[t],
            rl_loop.actor_act(learners[t]),
            recorder,
            horizon,
            {"task_id": t, "stage": k, "seed": seed, "policy": "base+actor"},
        )
        env.close()
    ctx.log_event("evaluation", stage=k, success=success, base_success=base_success)


STEP = StepDef(
    name="evaluate-all",
    code_version="evaluate-all-1",
    run=run,
    inputs=("base-policy", "checkpoint"),
    outputs={"eval": "eval", "episodes": "episodes"},
    description="success of base policy + actor on tasks 1..k (row k of the success matrix)",
)
