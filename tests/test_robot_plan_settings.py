"""The robot section's unkeyed settings reach the session (stages.steps.robot_plan.session_settings): the
takeover (robot.intervention) and the workflow's tracking: section, which the actor's and the learner's
TensorBoard runs read. Without them a workflow's takeover would silently be off and its tracking the
defaults."""

from __future__ import annotations

import json

from test_robot_hold import hold_workflow

from stages.steps.robot_plan import session_settings
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


def test_the_terminal_operator_of_a_session_audits_every_key(monkeypatch):
    """make_operator gives the terminal operator the session's audit (it had none: terminal actions
    never reached the audit log, only the page's did)."""
    import io
    import os
    import pty
    import sys

    from rich.console import Console

    from stages.steps.robot_session import SessionSettings, make_operator

    master, slave = pty.openpty()
    tty_in = os.fdopen(slave, "r")
    monkeypatch.setattr(sys, "stdin", tty_in)
    audited: list[tuple[str, dict]] = []
    op = make_operator(
        SessionSettings(operator="terminal", operator_name="ann"),
        None,
        Console(file=io.StringIO()),
        audit=lambda event, fields: audited.append((event, fields)),
    )
    try:
        os.write(master, b"r")
        assert op.wait_reset(1, "nist/rect_peg", 0).go
    finally:
        op.close()
        tty_in.close()
        os.close(master)
    assert [(e, f["action"], f["via"], f["operator"]) for e, f in audited] == [
        ("robot-operator-action", "reset", "terminal", "ann")
    ]
