"""The simulator as the environment of warmup, train and evaluate-all: vector envs seeded per stage and
phase, an env-step budget with an evaluation grid and intra-step checkpoints at fixed env-step points,
and the success of π_base^k + θ^k on M episodes per task.

What the steps read (stages.steps.stage_io) and write (their modules) is the same for the robot
(stages.steps.robot_env); only running the episodes is here.
"""

from __future__ import annotations

import contextlib

from stages.runner_context import StepContext
from stages.steps.checkpoint_layout import LEARNER_DIR
from stages.steps.common import make_env, read_json, write_json
from stages.steps.stage_io import (
    BaseInputs,
    Deployed,
    EvaluateResult,
    Inherited,
    TrainResult,
    Warmup,
    WarmupResult,
    tracking_run,
)

REPLAY_DIR, LOOP_FILE = "replay", "loop.json"  # train's intra-step checkpoints only
CHOSEN_ACTOR_FILE = "chosen_actor.pt"  # the actor deployed at the stage's best point so far (rl_loop.LoopState)
EVAL_RESULT_FILE = "evaluation.json"  # evaluate-all's checkpoint: the success rates, before the episode logs


def open_step_tracker(ctx: StepContext, tracking: dict | None, stage: int, fallback_workflow: str):
    """The step's tracker (accrue.tracking) for the run the plan bound (stage_io.tracking_run)."""
    from accrue.tracking import open_tracker

    spec, name, log_dir = tracking_run(ctx, tracking, stage, fallback_workflow)
    return open_tracker(
        spec,
        log_dir,
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


def load_actor_snapshot(learner, path):
    """A deployed-actor snapshot (LoopState.chosen_actor) saved as a state dict, as a module again."""
    import copy

    import torch

    actor = copy.deepcopy(learner.deployed_actor())
    actor.load_state_dict(torch.load(path, map_location=learner.device, weights_only=True))
    return actor


class SimEnvironment:
    def scope(self, ctx: StepContext):
        return contextlib.nullcontext()

    def learner_device(self) -> str:
        """Not pinned by the workflow: the GPU when there is one."""
        import torch

        return "cuda" if torch.cuda.is_available() else "cpu"

    # ------------------------------------------------------------------ warmup (Algorithm 1 line 3)
    def warmup(self, ctx: StepContext, base: BaseInputs, buffer) -> WarmupResult:
        from accrue import rl_loop

        c = ctx.config
        task = c["task"]
        env = make_env(task, c["num_envs"], rl_loop.env_seed(c["seed"], c["stage"], "warmup"), c["obs_mode"])
        features = base.features[task]
        buffer = buffer(features(env.reset()).shape[1])
        collector = rl_loop.ChunkCollector(
            env, base.references[task], features, buffer, task_index=c["stage"] - 1, gamma=c["gamma"]
        )
        collector.restart()
        stats = rl_loop.warmup(collector, c["episodes"])
        env.close()
        return WarmupResult(
            buffer,
            stats.episodes,
            stats.successes,
            stats.env_steps,
            collector.next_episode,
            {},
            f"warmup: {stats.episodes} base-policy episodes on {task}, "
            f"{stats.successes} succeeded, {len(buffer)} chunk transitions",
        )

    # ------------------------------------------------------------------ train (Algorithm 1 lines 4-10)
    def train(
        self, ctx: StepContext, cfg, base: BaseInputs, warm: Warmup, inherited: Inherited, tracking
    ) -> TrainResult:
        import time

        import torch

        from accrue import rl_loop, stage_rl
        from accrue.learner import ReplayBuffer, load_learner, save_learner
        from accrue.sim import get_task

        c = ctx.config
        k, tasks, horizon, seed = c["stage"], c["task_ids"], c["horizon"], c["seed"]
        task, dev = tasks[-1], cfg.device
        references, features = base.references, base.features
        previous, memory, teacher = inherited.previous(dev), inherited.memory(), inherited.teacher()
        frozen = {tasks[i - 1]: rl_loop.actor_act(load_learner(p, device=dev)) for i, p in inherited.per_task.items()}

        checkpoint = ctx.last_checkpoint()
        if checkpoint is None:
            buffer, next_episode, resume = warm.buffer(), warm.info["next_episode"], None
        else:
            ck, _ = checkpoint
            buffer = ReplayBuffer.load(ck / REPLAY_DIR)
            loop_state = rl_loop.LoopState.from_json(read_json(ck / LOOP_FILE))
            resumed = load_learner(ck / LEARNER_DIR, device=dev)
            if (ck / CHOSEN_ACTOR_FILE).exists():
                loop_state.chosen_actor = load_actor_snapshot(resumed, ck / CHOSEN_ACTOR_FILE)
            resume = (resumed, loop_state)
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
            tasks,
            c["env_steps"],
            c["eval_every"],
            c["checkpoint_every"],
            min_checkpoint_gap=2 * episode_span,
            full_curves=c.get("curves") == "full",
        )

        staging = ctx.scratch_dir("checkpoint")

        def save_checkpoint(learner, st: rl_loop.LoopState) -> None:
            save_learner(learner, staging / LEARNER_DIR)
            buffer.save_new_shards(staging / REPLAY_DIR)  # only the shards appended since the last one
            write_json(staging / LOOP_FILE, st.to_json())
            if st.chosen_actor is not None:
                torch.save(st.chosen_actor.state_dict(), staging / CHOSEN_ACTOR_FILE)
            ctx.save_checkpoint(staging, {"env_steps": st.env_steps, "updates": st.updates})

        clock = {"t": time.monotonic(), "updates": resume[1].updates if resume else 0}
        # the time left, from this attempt's env-step rate so far (a resumed attempt counts from where it started)
        pace = {"t": time.monotonic(), "env_steps": resume[1].env_steps if resume else 0}

        def show(st: rl_loop.LoopState, info: dict) -> None:
            now = time.monotonic()
            rate = (st.updates - clock["updates"]) / max(now - clock["t"], 1e-9)
            clock.update(t=now, updates=st.updates)
            done = st.env_steps - pace["env_steps"]
            left = (loop.env_steps - st.env_steps) * (now - pace["t"]) / done if done > 0 else None
            line = (
                f"train: env steps {st.env_steps}/{loop.env_steps}  updates {st.updates} ({rate:.0f}/s)  "
                f"episodes {st.episodes} (success {st.successes / max(st.episodes, 1):.2f})"
                + (f"  ~{left / 60:.1f} min left" if left is not None else "")
            )
            if "eval" in info:
                line += "  eval " + " ".join(f"{t}={r:.2f}" for t, r in info["eval"].items())
            ctx.console.print(line, soft_wrap=True)
            if "eval" in info and st.grid_done:  # success on tasks 1..k at this grid point
                values = {f"eval/success/{t}": r for t, r in info["eval"].items()}
                values.update(
                    {f"eval/report_success/{t}": c[-1] for t, c in st.report_curve.items() if c and c[-1] is not None}
                )
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
        curve = {
            "grid": sorted(state.grid_done),
            "success": {t: state.curve[t] for t in tasks},
            "episodes_per_point": c["eval_episodes"],
            # earlier tasks are null except at the chosen checkpoint unless budgets.full_curves
            "curves": "full" if loop.full_curves else "chosen",
            "chosen": state.chosen,
            **(
                {"report_success": {t: state.report_curve[t] for t in tasks}, "report_episodes": c["report_episodes"]}
                if report_set is not None
                else {}
            ),
            "ablation": cfg.ablation,
            "env_steps": state.env_steps,
            "updates": state.updates,
            "train_episodes": state.episodes,
            "train_successes": state.successes,
        }
        return TrainResult(
            learner,
            buffer,
            inherited.per_task,
            {"env_steps": state.env_steps, "updates": state.updates},
            curve,
        )

    # ------------------------------------------------------------------ evaluate-all (row k)
    def evaluate(self, ctx: StepContext, base: BaseInputs, deployed: Deployed) -> EvaluateResult:
        """Success of π_base^k + θ^k and of the base policy alone on M episodes per task; with
        budgets.report_episodes the disjoint report set (never the selection set train's curves choose
        checkpoints on). The `episodes` output: MCAP logs of a few episodes per task, written after the
        success rates are sealed in a checkpoint, so `--continue` after a crash in them evaluates nothing
        again."""
        from accrue import rl_loop
        from accrue.logs.mcap_episodes import EpisodeRecorder
        from accrue.sim import STATE_NAMES, get_task

        c = ctx.config
        k, tasks, horizon, seed = c["stage"], c["task_ids"], c["horizon"], c["seed"]
        references, features, learners = base.references, base.features, deployed.learners
        episode_set, episodes = (
            ("report", c["report_episodes"]) if c.get("report_episodes") else ("eval", c["episodes"])
        )
        checkpoint = ctx.last_checkpoint()
        if checkpoint is not None:  # an attempt whose episode logs failed: its success rates are sealed
            done = read_json(checkpoint[0] / EVAL_RESULT_FILE)
            success, base_success = done["success"], done["base_success"]
            ctx.console.print("evaluate-all: resumed with the success rates its checkpoint holds")
        else:
            success, base_success = self._success(ctx, base, deployed, episode_set, episodes)
            if c["record_episodes"] >= 1:  # a crash in the episode logs below must not cost the evaluation
                staging = ctx.scratch_dir("checkpoint")
                write_json(staging / EVAL_RESULT_FILE, {"success": success, "base_success": base_success})
                ctx.save_checkpoint(staging, {"evaluated_tasks": len(tasks)})

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
        return EvaluateResult(
            success, base_success, episodes, {"episode_set": episode_set} if episode_set == "report" else {}
        )

    def _success(self, ctx: StepContext, base: BaseInputs, deployed: Deployed, episode_set: str, episodes: int):
        """Per task, the success of π_base^k + θ^k and of the base policy alone."""
        from accrue import rl_loop

        c = ctx.config
        k, tasks, seed = c["stage"], c["task_ids"], c["seed"]
        evaluator = rl_loop.Evaluator(
            lambda t, n: make_env(t, n, rl_loop.env_seed(seed, k, episode_set, tasks.index(t)), c["obs_mode"]),
            base.references,
            base.features,
            episodes,
            c["num_envs"],
            c["horizon"],
            c["gamma"],
        )
        success, base_success = {}, {}
        for t in tasks:
            success[t] = evaluator.success_rate(t, rl_loop.actor_act(deployed.learners[t]))
            base_success[t] = evaluator.success_rate(t)
            ctx.console.print(
                f"evaluate-all: {t}: actor {success[t]:.2f}  base policy alone {base_success[t]:.2f} "
                f"({episodes} {episode_set} episodes)"
            )
        evaluator.close()
        return success, base_success
