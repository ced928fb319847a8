"""`cache-teacher`: Algorithm 1 line 2, Eq. 3: â_j = π̄_{θ^{k-1}}(s_j, ã_j) for every transition j of the
retained memory B^{<k}, computed once before the stage's RL from the previous stage's actor (the handoff)
and kept fixed. With `learner.distill_inputs` fresh/both it also caches π_base^k's chunk ã'_j at each
retained state (an input: `base-policy`). At stage 1, and for methods that do not distil, the artifact
says it was skipped and why.
"""

from __future__ import annotations

from stages.runner_context import StepContext
from stages.runner_types import StepDef
from stages.steps.common import deterministic, read_json, write_json

TARGETS_FILE = "teacher.safetensors"  # tensors "targets" (N, H, d) and, when cached, "fresh_ref" (N, H, d)
INFO_FILE = "teacher.json"


def skip_reason(stage: int, method: str, ablation: str) -> str | None:
    from accrue.methods import rules

    if stage == 1:
        return "stage 1 has no previous actor and no retained memory"
    if not rules(method, ablation).distill:
        return f"method {method} does not distil toward a previous actor"
    return None


def run(ctx: StepContext) -> None:
    c = ctx.config
    out = ctx.new_output("teacher", "teacher-targets")
    reason = skip_reason(c["stage"], c["method"], c["ablation"])
    if reason is not None:
        write_json(out / INFO_FILE, {"stage": c["stage"], "skipped": True, "reason": reason})
        ctx.console.print(f"cache-teacher: skipped ({reason})")
        return
    from safetensors.torch import save_file

    from accrue.learner import ReplayBuffer, load_learner
    from accrue.stage_rl import cache_teacher
    from stages.steps import handoff as handoff_step

    deterministic(c["seed"])
    handoff = ctx.input_path("handoff")
    teacher = load_learner(handoff / handoff_step.LEARNER_DIR, device="cpu")  # θ^{k-1}: a frozen copy
    memory = ReplayBuffer.load(handoff / handoff_step.MEMORY_DIR)  # B^{<k}
    cache = cache_teacher(teacher, memory, _fresh_reference(ctx) if ctx.has_input("base-policy") else None)
    tensors = {"targets": cache.targets.contiguous()}
    if cache.fresh_ref is not None:
        tensors["fresh_ref"] = cache.fresh_ref.contiguous()
    save_file(tensors, str(out / TARGETS_FILE))
    write_json(
        out / INFO_FILE,
        {
            "stage": c["stage"],
            "skipped": False,
            "rows": int(cache.targets.shape[0]),
            "shape": list(cache.targets.shape),
            "fresh_ref": cache.fresh_ref is not None,
        },
    )
    ctx.console.print(
        f"cache-teacher: cached {cache.targets.shape[0]} teacher targets (Eq. 3)"
        + (" and the current base policy's chunks at the same states" if cache.fresh_ref is not None else "")
    )


def _fresh_reference(ctx: StepContext):
    """(retained states, task index) -> π_base^k's chunks there, with the task's instruction."""
    from accrue.learner_inputs import observation_from_state
    from stages.steps.common import load_base_policy, reference_fn

    c = ctx.config
    policy = load_base_policy(ctx.input_path("base-policy"), c["seed"])
    references = [reference_fn(policy, t, c["horizon"]) for t in c["task_ids"]]
    return lambda states, task: references[task](observation_from_state(states, c["encoder"]))


def load_teacher(path):
    """The TeacherCache of a teacher-targets artifact, or None when it records a skip."""
    from safetensors.torch import load_file

    from accrue.stage_rl import TeacherCache

    if read_json(path / INFO_FILE)["skipped"]:
        return None
    tensors = load_file(str(path / TARGETS_FILE))
    return TeacherCache(tensors["targets"], tensors.get("fresh_ref"))


STEP = StepDef(
    name="cache-teacher",
    code_version="cache-teacher-2",
    run=run,
    optional_inputs=("handoff", "base-policy"),
    outputs={"teacher": "teacher-targets"},
    description="Eq. 3 targets of the previous actor on the retained memory",
)
