"""`cache-teacher`: Eq. 3, â_j = π̄_{θ^{k-1}}(s_j, ã_j) for every transition j of the retained memory B^{<k}.

Computed once before the stage's RL from the previous stage's actor (the handoff) and kept fixed.
At stage 1, and for methods that do not distil, the artifact says it was skipped and why.
"""
from __future__ import annotations

from stages.runner_context import StepContext
from stages.runner_types import StepDef
from stages.steps.common import deterministic, write_json

TARGETS_FILE = "teacher.safetensors"
INFO_FILE = "teacher.json"


def skip_reason(stage: int, method: str, ablation: str) -> str | None:
    from accrue.learner.continual import stage_plan

    if stage == 1:
        return "stage 1 has no previous actor and no retained memory"
    if not stage_plan(method, ablation).distill:
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
    import torch
    from safetensors.torch import save_file

    from accrue.learner import ReplayBuffer, compute_teacher_targets, load_learner

    deterministic(c["seed"])
    handoff = ctx.input_path("handoff")
    teacher = load_learner(handoff / "learner", device="cpu")              # θ^{k-1}: a frozen copy, discarded after
    memory = ReplayBuffer.load(handoff / "memory")           # B^{<k}
    targets = compute_teacher_targets(teacher, memory.column("state"), memory.column("ref"))
    save_file({"targets": targets.contiguous()}, str(out / TARGETS_FILE))
    write_json(out / INFO_FILE, {"stage": c["stage"], "skipped": False, "rows": int(targets.shape[0]),
                                 "shape": list(targets.shape)})
    ctx.console.print(f"cache-teacher: cached {targets.shape[0]} teacher targets (Eq. 3)")


def load_targets(path) -> "torch.Tensor | None":
    """The cached targets of a teacher-targets artifact, or None when it records a skip."""
    from safetensors.torch import load_file

    from stages.steps.common import read_json

    info = read_json(path / INFO_FILE)
    if info["skipped"]:
        return None
    return load_file(str(path / TARGETS_FILE))["targets"]


STEP = StepDef(name="cache-teacher", code_version="cache-teacher-1", run=run, optional_inputs=("handoff",),
               outputs={"teacher": "teacher-targets"},
               description="Eq. 3 targets of the previous actor on the retained memory")
