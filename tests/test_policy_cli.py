"""`accrue policy ...`: user mistakes are one `error:` line and exit code 2, never a traceback."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _accrue(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1", "TRANSFORMERS_OFFLINE": "1"}
    return subprocess.run(
        [sys.executable, "-m", "cli.main", *args], cwd=ROOT, env=env, capture_output=True, text=True, timeout=120
    )


def test_policy_group_lists_its_commands():
    result = _accrue("policy", "--help")
    assert result.returncode == 0
    for name in ("finetune", "chunk", "eval"):
        assert name in result.stdout


def test_missing_checkpoint_is_one_error_line(tmp_path):
    result = _accrue("policy", "chunk", str(tmp_path / "nope"), "--instruction", "x", "--state", "0,0")
    assert result.returncode == 2
    assert result.stderr.strip() == f"error: policy checkpoint {tmp_path / 'nope'} does not exist or is not a directory"
    assert "Traceback" not in result.stderr


def test_finetune_with_bad_retention_and_missing_demos(tmp_path):
    result = _accrue("policy", "finetune", "--demos", str(tmp_path), "--out", str(tmp_path / "o"), "--retention", "1.5")
    assert result.returncode == 2 and result.stderr.strip() == "error: demo retention must be in (0, 1], got 1.5"
    result = _accrue("policy", "finetune", "--demos", str(tmp_path / "none"), "--out", str(tmp_path / "o"))
    assert result.returncode == 2
    assert (
        result.stderr.strip().splitlines()[-1]
        == f"error: {tmp_path / 'none'} is not a LeRobotDataset (missing meta/info.json)"
    )
