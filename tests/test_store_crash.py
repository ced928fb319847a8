"""Atomic publish under kill -9: a writer process (ingest, refs, log, step runs with checkpoints)
is killed at random moments; afterwards `verify --full` passes and no lock is left held."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

from filelock import FileLock

from artifacts.records import list_attempts
from artifacts.store import Store
from artifacts.verify import verify_store

SUPPORT = Path(__file__).resolve().parent / "test_runner_support.py"
TRIALS = 24


def _log_size(store: Store) -> int:
    return store.log_path.stat().st_size if store.log_path.exists() else 0


def _wait_for_log(store: Store, proc: subprocess.Popen, before: int, timeout: float = 60) -> None:
    """Wait until this writer has logged something, so the kill lands in its work, not its start-up."""
    start = time.monotonic()
    while _log_size(store) <= before:
        assert proc.poll() is None, proc.stderr.read().decode()
        assert time.monotonic() - start < timeout
        time.sleep(0.01)


def test_kill_9_at_random_points_leaves_a_verifiable_store(tmp_path):
    store = Store.init(tmp_path / "store")[0]
    rng = random.Random(1234)
    for trial in range(TRIALS):
        before = _log_size(store)
        proc = subprocess.Popen(
            [sys.executable, str(SUPPORT), "writer", str(store.root), str(trial)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
        )
        _wait_for_log(store, proc, before)
        time.sleep(rng.uniform(0.0, 0.6))
        assert proc.poll() is None, proc.stderr.read().decode()
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        report = verify_store(store, full=True)
        assert report.ok, f"trial {trial}: {report.problems}"
        for lock_file in store.locks_dir.glob("*.lock"):
            lock = FileLock(str(lock_file))
            lock.acquire(timeout=0)  # raises Timeout if a dead writer still held it
            lock.release()
    # the dead writers' attempts are reaped as abandoned on the next look, and the store works on
    proc = subprocess.run(
        [sys.executable, str(SUPPORT), "count", str(store.root), "normal", "4", "0"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    from stages.runner import reap_abandoned

    for key in {a["cache_key"] for a in list_attempts(store)}:
        reap_abandoned(store, key)
    states = {a["state"] for a in list_attempts(store)}
    assert "running" not in states and "committed" in states
    assert verify_store(store, full=True).ok
