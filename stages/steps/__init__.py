"""The step bodies of a stage (paper Algorithm 1), one module each, plus `record-demos`.

STEPS maps a step name to its StepDef; stages.plan wires them into a stage's plan.
"""

from stages.steps import cache_teacher, evaluate_all, finetune_base, handoff, record_demos, train, warmup

STEPS = {
    m.STEP.name: m.STEP for m in (record_demos, finetune_base, cache_teacher, warmup, train, evaluate_all, handoff)
}

__all__ = ["STEPS"]
