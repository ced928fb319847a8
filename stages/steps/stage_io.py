"""What warmup, train and evaluate-all read, and what their environment hands back (paper Algorithm 1).

One code path for each input: π_base^k's reference chunks and the learner state s for the stage's tasks,
the warmup shard of B^k, what the stage inherits (θ^{k-1}, ψ^{k-1}, B^{<k}, the cached Eq. 3 targets,
the per-task learners Isolated keeps) and the checkpoint evaluate-all deploys. The environment
(stages.steps.sim_env or stages.steps.robot_env) loads what it uses from here; nothing else reads them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from stages.runner_context import StepContext
from stages.steps import handoff as handoff_step
from stages.steps.checkpoint_layout import LEARNER_DIR, PER_TASK_DIR
from stages.steps.common import deterministic, load_base_policy, per_task_features, read_json, reference_fn

WARMUP_INFO_FILE = "warmup.json"  # in warmup's `replay` output, beside the shards: counts and the next episode id


@dataclass
class BaseInputs:
    """Per task, the reference chunks ã of π_base^k (held fixed during the stage) and s(obs)."""

    references: dict
    features: dict


def base_inputs(ctx: StepContext, tasks: list[str]) -> BaseInputs:
    """Seeds the step (deterministic), loads `base-policy` and builds references and s for `tasks`."""
    c = ctx.config
    deterministic(c["seed"])
    policy = load_base_policy(ctx.input_path("base-policy"), c["seed"])
    references = {t: reference_fn(policy, t, c["horizon"]) for t in tasks}
    return BaseInputs(references, per_task_features(c, tasks))


@dataclass
class Warmup:
    """warmup's `replay` output: the first shard of B^k and its warmup.json."""

    dir: Path
    info: dict

    def buffer(self):
        from accrue.learner import ReplayBuffer

        return ReplayBuffer.load(self.dir)


def warmup_shard(ctx: StepContext) -> Warmup:
    d = ctx.input_path("replay")
    return Warmup(d, read_json(d / WARMUP_INFO_FILE))


@dataclass
class Inherited:
    """What stage k inherits from stage k-1's handoff and cache-teacher (None on stage 1)."""

    handoff: Path | None
    teacher_dir: Path | None
    per_task: dict  # task position (1-based) -> a kept learner's directory (Isolated)

    @property
    def memory_dir(self) -> Path | None:
        return self.handoff / handoff_step.MEMORY_DIR if self.handoff else None

    @property
    def teacher_file(self) -> Path | None:
        f = self.teacher_dir / "teacher.safetensors" if self.teacher_dir else None
        return f if f is not None and f.is_file() else None

    def previous(self, device: str):
        """θ^{k-1}, ψ^{k-1} (the whole learner state), or None."""
        from accrue.learner import load_learner

        return load_learner(self.handoff / handoff_step.LEARNER_DIR, device=device) if self.handoff else None

    def memory(self):
        """B^{<k}, or None."""
        from accrue.learner import ReplayBuffer

        return ReplayBuffer.load(self.memory_dir) if self.handoff else None

    def teacher(self):
        """The cached Eq. 3 targets, or None."""
        from stages.steps.cache_teacher import load_teacher

        return load_teacher(self.teacher_dir) if self.teacher_dir else None


def inherited(ctx: StepContext, cfg) -> Inherited:
    """The `handoff` and `teacher` inputs of train; per-task learners only where cfg's rules keep them."""
    handoff = ctx.input_path("handoff") if ctx.has_input("handoff") else None
    teacher = ctx.input_path("teacher") if ctx.has_input("teacher") else None
    kept = handoff_step.per_task_learners(handoff) if cfg.rules.checkpoint_per_task else {}
    return Inherited(handoff, teacher, kept)


@dataclass
class Deployed:
    """evaluate-all's `checkpoint`: π_base^k + θ^k's learner, and per task the learner that task is
    evaluated with (Isolated keeps one per task; every other method deploys the current one)."""

    current: object
    learners: dict

    def per_task_checkpoint(self) -> list[str]:
        return sorted(t for t, learner in self.learners.items() if learner is not self.current)


def deployed(ctx: StepContext, tasks: list[str]) -> Deployed:
    from accrue.learner import load_learner

    checkpoint = ctx.input_path("checkpoint")
    current = load_learner(checkpoint / LEARNER_DIR, device="cpu")
    per_task = checkpoint / PER_TASK_DIR
    learners = {
        t: (load_learner(per_task / str(i), device="cpu") if (per_task / str(i)).is_dir() else current)
        for i, t in enumerate(tasks, 1)
    }
    return Deployed(current, learners)


def tracking_run(ctx: StepContext, tracking: dict | None, stage: int, fallback_workflow: str) -> tuple:
    """(the tracking section, the run's name, its directory) of the step: the run
    <workflow>/stage-<k>/<step> under <root>, by default <store>/log/tracking (docs/TRACKING.md).

    `tracking` is bound by stages.steps.train.bind_tracking: {"spec": the workflow's tracking section,
    "workflow": its name, "root": None or a directory}. Unbound, the defaults apply (TensorBoard on) under
    `fallback_workflow`."""
    from accrue.tracking import run_name, tracking_dir

    tracking = tracking or {}
    name = run_name(tracking.get("workflow") or fallback_workflow, stage, ctx.step)
    root = tracking.get("root")
    return tracking.get("spec"), name, (Path(root) / name if root else tracking_dir(ctx.store.root, name))


# ---------------------------------------------------------------- what an environment hands back


@dataclass
class WarmupResult:
    """π_base^k's episodes: B^k's first shard and what warmup.json says of them (`extra`: the
    environment's own fields)."""

    buffer: object
    episodes: int
    successes: int
    env_steps: int
    next_episode: int
    extra: dict
    line: str  # the one line printed at the end


@dataclass
class TrainResult:
    """The stage's learner and B^k; checkpoint.json's and curve.json's environment fields."""

    learner: object
    buffer: object
    per_task: dict  # task position -> kept learner directory, copied into the checkpoint
    checkpoint: dict
    curve: dict


@dataclass
class EvaluateResult:
    """Row k of the success matrix and eval.json's environment fields."""

    success: dict
    base_success: dict
    episodes: int
    extra: dict
