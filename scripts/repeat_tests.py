"""Run one pytest selection N times in a row, each in a fresh process, to catch flakes and races.

    python scripts/repeat_tests.py --runs 20 [--keep-going] [--out benchmarks/results/test_repeats.json] \
        -- tests/test_runner_steps.py tests/test_remote_cas.py ...

It stops at the first failing run unless --keep-going. For every run it records the exit code, the
duration, the failed/errored test ids (from pytest's short summary), the load average before and after
and the busiest other processes at the start (the machine state the figures were taken under). The JSON
is rewritten after every run, so a stopped or interrupted series still leaves what it measured.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shlex
import subprocess
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = ROOT / "benchmarks" / "results" / "test_repeats.json"
# pytest's short test summary (-ra is in pyproject's addopts): "FAILED tests/x.py::t - why"
SUMMARY = re.compile(r"^(FAILED|ERROR) (\S+)")


def now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def load() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


def busiest(limit: int = 6) -> list[str]:
    """The processes using the most CPU right now, other than this series (who else is loading the machine)."""
    try:
        out = subprocess.run(
            ["ps", "-eo", "pcpu,pid,ppid,args", "--sort=-pcpu", "--no-headers"],
            capture_output=True,
            text=True,
            timeout=10,
        ).stdout
    except (OSError, subprocess.SubprocessError):
        return []
    mine = {str(os.getpid())}
    rows = []
    for line in out.splitlines():
        parts = line.split(None, 3)
        if len(parts) < 4 or parts[1] in mine or parts[2] in mine:
            continue
        rows.append(f"{parts[0]}% {parts[3][:160]}")
        if len(rows) == limit:
            break
    return rows


def git_state() -> dict:
    def git(*args: str) -> str:
        proc = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True)
        return proc.stdout.strip()

    return {"commit": git("rev-parse", "HEAD"), "dirty_paths": len(git("status", "--porcelain").splitlines())}


def failed_ids(output: str) -> list[str]:
    return [f"{m.group(1)} {m.group(2)}" for m in map(SUMMARY.match, output.splitlines()) if m]


def one_run(index: int, pytest_cmd: list[str]) -> tuple[dict, str]:
    before, started_at, start = load(), now(), time.monotonic()
    proc = subprocess.run(pytest_cmd, cwd=ROOT, capture_output=True, text=True)
    output = proc.stdout + proc.stderr
    lines = [line for line in proc.stdout.splitlines() if line.strip()]
    run = {
        "run": index,
        "started": started_at,
        "rc": proc.returncode,
        "duration_s": round(time.monotonic() - start, 1),
        "summary": lines[-1] if lines else "",
        "failed": failed_ids(output),
        "load_before": before,
        "load_after": load(),
    }
    return run, output


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", "-n", type=int, default=20, help="how many runs in a row (default 20)")
    parser.add_argument("--keep-going", action="store_true", help="go on after a failing run")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="the JSON to write")
    parser.add_argument("--note", default="", help="what else ran on the machine (stored as is)")
    parser.add_argument("pytest_args", nargs="+", help="the pytest selection (after --)")
    args = parser.parse_args(argv)
    if args.runs < 1:
        parser.error("--runs must be at least 1")
    pytest_cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *args.pytest_args]
    result = {
        "command": " ".join(shlex.quote(a) for a in [sys.executable, *sys.argv]),
        "pytest": " ".join(shlex.quote(a) for a in pytest_cmd),
        # the test files (or node ids) the series covers, as given; options such as -m are in "pytest"
        "selection": [a for a in args.pytest_args if not a.startswith("-") and (ROOT / a.split("::")[0]).exists()],
        "niceness": os.nice(0),
        "note": args.note,
        "machine": {
            "host": platform.node(),
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "load_at_start": load(),
            "busiest_at_start": busiest(),
        },
        "git": git_state(),
        "started": now(),
        "runs_requested": args.runs,
        "runs": [],
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)

    def write() -> None:
        runs = result["runs"]
        durations = [r["duration_s"] for r in runs]
        result["passed_in_a_row"] = next((i for i, r in enumerate(runs) if r["rc"] != 0), len(runs))
        result["failed_runs"] = sum(r["rc"] != 0 for r in runs)
        if durations:
            result["duration_s"] = {"min": min(durations), "max": max(durations), "total": round(sum(durations), 1)}
            result["load_1min"] = {
                "min": min(r["load_before"][0] for r in runs),
                "max": max(r["load_before"][0] for r in runs),
            }
        tmp = args.out.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(result, indent=2) + "\n")
        tmp.replace(args.out)

    for index in range(1, args.runs + 1):
        run, output = one_run(index, pytest_cmd)
        if index == 1 or run["rc"] != 0:
            run["busiest"] = busiest()
        if run["rc"] != 0:
            run["output_tail"] = output[-6000:]
        result["runs"].append(run)
        result["finished"] = now()
        write()
        failed = ", ".join(run["failed"]) or run["summary"]
        print(
            f"run {index:2d}/{args.runs}: rc {run['rc']} in {run['duration_s']:7.1f} s, load {run['load_before']}"
            + ("" if run["rc"] == 0 else f" - {failed}"),
            flush=True,
        )
        if run["rc"] != 0 and not args.keep_going:
            break
    print(f"{result['passed_in_a_row']} of {args.runs} passed in a row; written to {args.out}")
    return 0 if result["failed_runs"] == 0 and len(result["runs"]) == args.runs else 1


if __name__ == "__main__":
    sys.exit(main())
