"""The CI subset of the fault harness (issue 13): three kill -9 trials of the tiny two-stage workflow,
each at a random moment of a random step, then `--continue`. Every trial must leave a store that
verifies with no lock held, and end with the same artifacts as an uninterrupted run.
(`scripts/fault_harness.py --trials 100` is the on-demand version; this one uses the scripted
reference base policy, so no lerobot fine-tuning subprocess, to stay short.)"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_three_random_kills_then_continue_lose_nothing(tmp_path):
    out = tmp_path / "faults.json"
    proc = subprocess.run(
        [
            sys.executable,
            str(ROOT / "scripts" / "fault_harness.py"),
            "--trials",
            "3",
            "--seed",
            "7",
            "--base",
            "scripted-reference:0.5",
            "--out",
            str(out),
            "--workdir",
            str(tmp_path / "w"),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=1200,
    )
    report = json.loads(out.read_text())
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert report["summary"]["passed"] == report["summary"]["trials"] == 3
    for r in report["results"]:
        assert r["ok"] and r["after_kill_problems"] == [] and r["final_locks"] == [] and r["differing_steps"] == []
    steps = {r["aimed_at"] for r in report["results"]}
    assert len(steps) >= 2, steps  # the kills are spread over the workflow's steps
    assert "--trials 3" in report["command"]
