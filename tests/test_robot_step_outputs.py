"""warmup, train and evaluate-all on a robot (stages.steps.robot_env) and in the simulator (sim_env): the
step code versions the caches key on, a stop while a robot step writes its outputs, a crash in the
simulator's optional episode logs, and Isolated's per-task learners on a robot."""

from __future__ import annotations

from pathlib import Path

import pytest

pytestmark = pytest.mark.timeout(600)
ROOT = Path(__file__).resolve().parents[1]


def test_step_code_versions_are_those_the_caches_key_on(tmp_path):
    """The simulator's from each STEP, the robot's from robot_env.CODE_VERSIONS (one place each): a changed
    code version would re-run every cached step."""
    from artifacts.store import Store
    from stages.plan import plan_stage
    from stages.workflow import load_workflow

    store = Store.init(tmp_path / "store")[0]
    versions = {}
    for name in ("quickstart", "hardware-sim"):
        plan = plan_stage(load_workflow(ROOT / "workflows" / f"{name}.yaml"), 1, store)
        versions[name] = {inv.step.name: inv.step.code_version for inv in plan.steps}
    assert {s: versions["quickstart"][s] for s in ("warmup", "train", "evaluate-all")} == {
        "warmup": "warmup-2",
        "train": "train-3",
        "evaluate-all": "evaluate-all-1",
    }
    assert {s: versions["hardware-sim"][s] for s in ("warmup", "train", "evaluate-all")} == {
        "warmup": "hw-warmup-1",
        "train": "hw-train-2",
        "evaluate-all": "hw-evaluate-all-1",
    }
