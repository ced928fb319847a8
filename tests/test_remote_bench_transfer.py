"""benchmarks/bench_transfer.py runs end to end on a tiny set (issue 51): both sides move the files, the
pulled store verifies, a no-op push sends nothing, and the JSON keeps the command, commit and load."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow  # a moto server and a dozen accrue processes: ~20 s on the shared 2-core machine
def test_the_transfer_benchmark_runs_and_records_what_made_its_figures(tmp_path):
    out = tmp_path / "transfer.json"
    args = ["--small", "5", "--big", "1", "--big-mb", "17", "--rounds", "1", "--json", str(out), "--note", "ci"]
    env = {k: v for k, v in os.environ.items() if not k.startswith("AWS_")}
    done = subprocess.run(
        [sys.executable, "benchmarks/bench_transfer.py", *args, "--dir", str(tmp_path)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    figures = json.loads(out.read_text())
    assert figures["command"].startswith("python benchmarks/bench_transfer.py --small 5 --big 1")
    assert figures["machine"]["note"] == "ci" and len(figures["machine"]["load_before"]) == 3
    assert figures["noop_push_objects_sent"] == 0
    for key in ("push_s", "pull_s", "boto3_upload_s", "boto3_download_s", "push_in_process_s", "pull_in_process_s"):
        assert len(figures["rounds_s"][key]) == 1 and figures["median_s"][key] > 0
    assert figures["push_vs_boto3"] > 0 and figures["pull_vs_boto3"] > 0
    assert list(tmp_path.glob("bench-transfer-*")) == []  # its work directory is gone
