"""`accrue add DIR --kind demos --workflow WF`: a lerobot-record dataset is checked against WF's robot mapping."""
from __future__ import annotations

from pathlib import Path


def check_demos_for_workflow(path: Path, kind: str, workflow: Path) -> dict:
    from stages.errors import StageError
    from stages.workflow import load_workflow

    if kind != "demos":
        raise StageError(f"--workflow checks demonstrations: it goes with --kind demos (got --kind {kind})")
    wf = load_workflow(workflow)
    if wf.robot is None:
        raise StageError(f"--workflow {workflow}: has no robot section to check the dataset against")
    from accrue.robot.demos import check_robot_dataset
    from accrue.robot.mapping import RobotMapping

    return check_robot_dataset(path, RobotMapping.from_dict(wf.robot.model_dump()), wf.robot.type)
