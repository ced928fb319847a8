"""Whether a stage's base policy reads demonstrations, and whether the stage records its own: the one rule
that the plan, stage status and the robot checks all read."""

from __future__ import annotations

from stages.workflow import Workflow


def uses_demos(wf: Workflow) -> bool:
    """Whether finetune-base reads demos at all: not for the scripted stand-in reference, and not for a
    checkpoint used as given (base_policy.finetune false) on a robot the simulator's expert cannot
    demonstrate on (any robot.type but accrue_sim), which would otherwise need robot demos it never reads."""
    from accrue.scripted_reference import parse_spec

    bp = wf.base_policy
    if parse_spec(bp.init) is not None:
        return False
    return bp.finetune or wf.robot is None or wf.robot.type == "accrue_sim"


def stage_records_demos(wf: Workflow, k: int) -> bool:
    """Stage k records its task's demos when the workflow gives none for it and the base policy is
    fine-tuned on demos (uses_demos): the one rule plan and status both read."""
    return wf.task(k) not in wf.base_policy.demos and uses_demos(wf)
