"""The robot section's unkeyed settings reach the session (stages.steps.hw_plan.session_settings): the
takeover (robot.intervention) and the workflow's tracking: section, which the actor's and the learner's
TensorBoard runs read. Without them a workflow's takeover would silently be off and its tracking the
defaults."""

from __future__ import annotations

import json

from test_robot_hold import hold_workflow

from stages.steps.hw_plan import session_settings
from stages.workflow import load_workflow


def test_intervention_and_tracking_reach_the_session(tmp_path):
    takeover = {"teleop": "accrue_sim_expert", "config": {"calibration_dir": str(tmp_path / "calib")}}
    path = hold_workflow(tmp_path / "hw.yaml", tmp_path / "calib", intervention=takeover)
    path.write_text(path.read_text() + "tracking:\n  every: 7\n  tensorboard: false\n")
    settings = session_settings(load_workflow(path))
    assert settings.intervention is not None
    assert settings.intervention["teleop"] == "accrue_sim_expert"
    assert settings.intervention["config"] == takeover["config"]
    assert settings.tracking["every"] == 7 and settings.tracking["tensorboard"] is False
    json.dumps(settings.tracking)  # plain data: it travels to the learner in Init


def test_no_intervention_is_the_paper(tmp_path):
    settings = session_settings(load_workflow(hold_workflow(tmp_path / "hw.yaml", tmp_path / "calib")))
    assert settings.intervention is None
    assert settings.tracking["tensorboard"] is True  # the default
