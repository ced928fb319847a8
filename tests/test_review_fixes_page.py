"""Review fix: the operator page is plain HTTP and carries the link token, so a non-loopback
`robot.operator_page.listen` is refused when the workflow loads unless `operator_page.insecure: true`
(as the learner refuses a non-loopback address without TLS unless --insecure)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from robot_workflow import write_hw_workflow

from stages.errors import StageError


def robot_workflow(tmp_path: Path, **robot) -> Path:
    """tests/robot_workflow's workflow with extra robot.* keys."""
    wf = write_hw_workflow(tmp_path / "hw.yaml", tmp_path / "calib")
    lines = "".join(f"  {k}: {json.dumps(v)}\n" for k, v in robot.items())
    wf.write_text(wf.read_text().replace("  publish_every: 10\n", "  publish_every: 10\n" + lines))
    return wf


def test_an_operator_page_off_loopback_needs_insecure(tmp_path):
    from stages.workflow import load_workflow

    with pytest.raises(StageError) as err:
        load_workflow(robot_workflow(tmp_path, operator_page={"listen": "0.0.0.0:18799"}))
    line = str(err.value)
    assert "\n" not in line and "robot.operator_page.listen: 0.0.0.0:18799 is not loopback" in line
    assert "operator_page.insecure: true" in line

    ok = load_workflow(robot_workflow(tmp_path, operator_page={"listen": "0.0.0.0:18799", "insecure": True}))
    assert ok.robot.operator_page == {"listen": "0.0.0.0:18799", "insecure": True}
    for listen in ("127.0.0.1:0", "localhost:8765", "[::1]:8765"):
        load_workflow(robot_workflow(tmp_path, operator_page={"listen": listen}))
    with pytest.raises(StageError, match=r"robot.operator_page.insecure: expected true or false, got 'yes'"):
        load_workflow(robot_workflow(tmp_path, operator_page={"listen": "0.0.0.0:1", "insecure": "yes"}))
