"""Review fix: a workflow's `tracking:` defaults and W&B modes come from accrue.tracking (one place), so
stages.workflow's TrackingSpec/WandbSpec and accrue.tracking.settings_of cannot drift apart."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_workflow_models_take_their_tracking_defaults_from_accrue_tracking():
    """In a fresh interpreter, accrue.tracking's constants are changed before stages.workflow is imported:
    the workflow's models must follow (they copied 20, 'accrue', 'offline' before)."""
    code = """
import json
import accrue.tracking as t
t.DEFAULT_EVERY, t.DEFAULT_TENSORBOARD = 7, False
t.WANDB_MODES = ("offline", "online", "disabled")
t.WANDB_DEFAULTS = {"project": "elsewhere", "mode": "disabled", "entity": "lab"}
from stages.workflow import TrackingSpec, WandbSpec
print(json.dumps([TrackingSpec().model_dump(), WandbSpec().model_dump(), WandbSpec(mode="online").mode]))
"""
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    tracking, wandb, online = json.loads(out.stdout)
    assert tracking == {"tensorboard": False, "wandb": None, "every": 7}
    assert wandb == {"project": "elsewhere", "mode": "disabled", "entity": "lab"} and online == "online"


def test_settings_of_and_the_validated_section_agree():
    from accrue.tracking import settings_of
    from stages.workflow import TrackingSpec

    for section in ({}, {"wandb": {}}, {"wandb": {"mode": "online"}, "every": 5}, {"tensorboard": False}):
        assert settings_of(section) == settings_of(TrackingSpec.model_validate(section))
