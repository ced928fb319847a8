"""stages.plan: which steps a stage runs, how they are wired, what each config holds, and --budget."""

from __future__ import annotations

from pathlib import Path

import pytest

from artifacts.store import Store
from stages.errors import StageError
from stages.plan import apply_budget, plan_stage
from stages.runner_types import FromRef, FromStep
from stages.workflow import load_workflow, parse_workflow

WORKFLOWS = Path(__file__).resolve().parents[1] / "workflows"


def workflow(**over):
    data = {
        "name": "w",
        "tasks": ["nist/rect_peg", "nist/round_peg", "nist/gear"],
        "method": "accrue",
        "seed": 7,
        "budgets": {"env_steps": 1000, "eval_every": 250, "checkpoint_every": 100},
    }
    data.update(over)
    return parse_workflow(data, "test.yaml")


@pytest.fixture
def store(tmp_path):
    return Store.init(tmp_path / "store")[0]


def by_name(plan):
    return {inv.step.name: inv for inv in plan.steps}


def test_stage_one_records_demos_and_skips_the_teacher(store):
    plan = plan_stage(workflow(), 1, store)
    assert plan.names() == [
        "record-demos",
        "finetune-base",
        "cache-teacher",
        "warmup",
        "train",
        "evaluate-all",
        "handoff",
    ]
    steps = by_name(plan)
    assert steps["record-demos"].config["seed"] == 7 and steps["record-demos"].config["task"] == "nist/rect_peg"
    assert steps["finetune-base"].inputs == {"demos-1": FromStep("record-demos", "demos")}
    assert steps["finetune-base"].step.inputs == ("demos-1",)
    assert steps["cache-teacher"].inputs == {}
    assert "handoff" not in steps["train"].inputs and "teacher" not in steps["train"].inputs
    assert steps["train"].inputs["replay"] == FromStep("warmup", "replay")


def test_later_stages_read_earlier_ones_through_refs(store):
    steps = by_name(plan_stage(workflow(), 3, store))
    ft = steps["finetune-base"].inputs
    assert ft["init"] == FromRef("workflow/w/stage/2/finetune-base:base-policy")
    assert ft["demos-1"] == FromRef("workflow/w/stage/1/record-demos:demos")
    assert ft["demos-3"] == FromStep("record-demos", "demos")
    assert steps["cache-teacher"].inputs == {"handoff": FromRef("workflow/w/stage/2/handoff:handoff")}
    assert steps["train"].inputs["teacher"] == FromStep("cache-teacher", "teacher")
    assert steps["train"].config["task_ids"] == ["nist/rect_peg", "nist/round_peg", "nist/gear"]
    assert steps["handoff"].inputs["handoff"] == FromRef("workflow/w/stage/2/handoff:handoff")


def test_methods_without_distillation_take_no_teacher_input(store):
    steps = by_name(plan_stage(workflow(method="er"), 2, store))
    assert steps["cache-teacher"].inputs == {}
    assert "teacher" not in steps["train"].inputs and "handoff" in steps["train"].inputs


def test_given_demos_replace_recording(store):
    steps = by_name(plan_stage(workflow(base_policy={"demos": {"nist/round_peg": "abc123"}}), 2, store))
    assert "record-demos" not in steps  # stage 2's task has given demos
    assert steps["finetune-base"].inputs["demos-2"] == "abc123"
    assert steps["finetune-base"].inputs["demos-1"] == FromRef("workflow/w/stage/1/record-demos:demos")
    steps = by_name(plan_stage(workflow(base_policy={"demos": {"nist/rect_peg": "abc123"}}), 1, store))
    assert "record-demos" not in steps


def test_each_config_holds_only_what_its_step_reads(store):
    a = by_name(plan_stage(workflow(), 1, store))
    b = by_name(
        plan_stage(
            workflow(budgets={"env_steps": 1000, "eval_every": 250, "checkpoint_every": 100, "retained_episodes": 3}),
            1,
            store,
        )
    )
    changed = {name for name in a if a[name].config != b[name].config}
    assert changed == {"handoff"}
    c = by_name(plan_stage(workflow(learner={"lam": 0.5}), 1, store))
    assert {name for name in a if a[name].config != c[name].config} == {"train"}


def test_only_steps_that_render_the_sim_cameras_carry_their_version(store):
    # images rendered before the cameras were posed (every view from the world origin) must not be reused
    state = by_name(plan_stage(workflow(), 1, store))
    image = by_name(plan_stage(workflow(obs_mode="state+image"), 1, store))
    for name in ("record-demos", "warmup", "train", "evaluate-all"):
        assert "sim_cameras" not in state[name].config
        assert image[name].config["sim_cameras"] == "posed"


def test_unknown_task_and_foreign_demos_are_one_line_errors(store):
    with pytest.raises(StageError, match=r"tasks\[1\]: unknown task 'nist/nope'"):
        plan_stage(workflow(tasks=["nist/gear", "nist/nope"]), 1, store)
    with pytest.raises(StageError, match="base_policy.demos: 'plugs/star' is not one of"):
        plan_stage(workflow(base_policy={"demos": {"plugs/star": "x"}}), 1, store)


def test_budget_scales_steps_and_grid():
    wf = workflow()
    small = apply_budget(wf, "0.1")
    assert (small.budgets.env_steps, small.budgets.eval_every, small.budgets.checkpoint_every) == (100, 25, 10)
    assert small.base_policy.finetune_steps == 20 and wf.base_policy.finetune_steps == 200
    fixed = apply_budget(wf, "500")
    assert (fixed.budgets.env_steps, fixed.budgets.eval_every) == (500, 125)
    assert apply_budget(wf, None) is wf
    for bad in ("0", "-1", "x", "12.5"):
        with pytest.raises(StageError, match="--budget"):
            apply_budget(wf, bad)


def test_the_scripted_stand_in_needs_no_demos(store):
    for k in (1, 2):
        steps = by_name(plan_stage(workflow(base_policy={"init": "scripted-reference:0.5"}), k, store))
        assert "record-demos" not in steps
        assert not any(r.startswith("demos-") for r in steps["finetune-base"].inputs)
    with pytest.raises(Exception, match="known bias fraction must be in"):
        plan_stage(workflow(base_policy={"init": "scripted-reference:2"}), 1, store)


@pytest.mark.parametrize(
    "name", ["quickstart", "quickstart-standin", "nist", "plugs-s1", "plugs-s2", "plugs-s3", "plugs-s4"]
)
def test_shipped_workflows_load_and_plan(store, name):
    wf = load_workflow(WORKFLOWS / f"{name}.yaml")
    for k in range(1, wf.num_stages + 1):
        plan_stage(apply_budget(wf, "0.01"), k, store)
    if not name.startswith("quickstart"):
        assert wf.horizon == 16 and wf.budgets.env_steps == 500_000 and wf.budgets.num_envs == 64
        assert wf.budgets.retained_episodes == (100 if name == "nist" else 50)
        assert wf.learner["algo"] == "fastsac"


def test_fresh_distillation_caches_the_current_base_policy_chunks(store):
    steps = by_name(plan_stage(workflow(learner={"distill_inputs": "fresh"}), 2, store))
    teacher = steps["cache-teacher"]
    assert teacher.inputs["base-policy"] == FromStep("finetune-base", "base-policy")
    assert teacher.config["distill_inputs"] == "fresh" and teacher.config["task_ids"] == [
        "nist/rect_peg",
        "nist/round_peg",
    ]
    stored = by_name(plan_stage(workflow(), 2, store))["cache-teacher"]
    assert "base-policy" not in stored.inputs and "distill_inputs" not in stored.config


@pytest.mark.parametrize(
    "method, ablation",
    [
        ("accrue", "none"),
        ("accrue", "no-reference"),
        ("sequential", "none"),
        ("er", "none"),
        ("single-task", "none"),
        ("isolated", "none"),
    ],
)
def test_every_method_sees_the_same_learner_state(store, method, ablation):
    """s = (E(I), q, e(ℓ)) is set by the workflow, never by the method: warmup, train and evaluate-all of
    every method and ablation read the same encoder and task features."""
    wf = workflow(method=method, task_features=32, learner={"ablation": ablation} if ablation != "none" else {})
    steps = by_name(plan_stage(wf, 2, store))
    for name in ("warmup", "train", "evaluate-all"):
        assert steps[name].config["task_features"] == 32 and steps[name].config["encoder"] == "none"
