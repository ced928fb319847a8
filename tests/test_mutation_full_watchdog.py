"""scripts/mutation_full.py's watchdog: a mutant that waits (never reaching mutmut's CPU-time limit) is ended
after its wall-time limit, and nothing is signalled before mutmut starts running mutants."""

from __future__ import annotations

import importlib.util
import io
import os
import signal
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def load_script():
    spec = importlib.util.spec_from_file_location("mutation_full", ROOT / "scripts" / "mutation_full.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# A stand-in for mutmut: a parent that forks one worker and waits for it (the worker prints its pid).
PARENT = """
import subprocess, sys
child = subprocess.Popen([sys.executable, "-c", sys.argv[1]], stdout=subprocess.PIPE, text=True)
print(child.stdout.readline().strip(), flush=True)
rc = child.wait()
sys.exit(-rc if rc < 0 else rc)  # exit with the number of the signal that ended the worker
"""
SLEEPER = "import os, time; print(os.getpid(), flush=True); time.sleep(60)"
STUBBORN = (
    "import os, signal, time; signal.signal(signal.SIGXCPU, signal.SIG_IGN); print(os.getpid(), flush=True); "
    "time.sleep(60)"
)


def start(worker: str):
    parent = subprocess.Popen([sys.executable, "-c", PARENT, worker], stdout=subprocess.PIPE, text=True)
    child_pid = int(parent.stdout.readline())
    return parent, child_pid


def wait_for(pred, timeout=20.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(0.05)
    return False


@contextmanager
def watching(pid: int, armed: bool = True, **limits):
    """A watchdog over `pid`'s workers for the length of the block, stopped (and `pid` killed) after it."""
    dog = load_script().MutantWatchdog(pid, poll=0.05, **limits)
    if armed:
        dog.armed.set()
    dog.start()
    try:
        yield dog
    finally:
        dog.done.set()
        if alive(pid):
            os.kill(pid, signal.SIGKILL)


def test_a_waiting_mutant_gets_sigxcpu_after_its_wall_limit():
    parent, child = start(SLEEPER)
    with watching(parent.pid, limit=0.5, grace=30.0) as dog:
        assert parent.wait(timeout=20) == signal.SIGXCPU  # the worker died of the signal mutmut reads as timeout
        assert dog.ended == [(child, "XCPU")]


def test_a_mutant_that_ignores_sigxcpu_is_killed_after_the_grace():
    parent, child = start(STUBBORN)
    with watching(parent.pid, limit=0.3, grace=0.5) as dog:
        assert parent.wait(timeout=20) == signal.SIGKILL
        assert dog.ended == [(child, "XCPU"), (child, "KILL")]


def test_a_watchdog_scheduled_late_still_sends_sigxcpu_before_the_kill():
    # a busy machine may first run the check after limit + grace have both passed: SIGXCPU must still come
    # first (mutmut reads only that as a timeout), and SIGKILL only `grace` seconds after it
    parent, child = start(STUBBORN)
    dog = load_script().MutantWatchdog(parent.pid, limit=0.1, grace=0.3)
    try:
        time.sleep(0.6)
        dog.check()
        assert dog.ended == [(child, "XCPU")]
        dog.check()
        assert dog.ended == [(child, "XCPU")]
        time.sleep(0.4)
        dog.check()
        assert dog.ended == [(child, "XCPU"), (child, "KILL")]
        assert parent.wait(timeout=20) == signal.SIGKILL
        dog.check()
        assert dog.ended == [(child, "XCPU"), (child, "KILL")]
    finally:
        if alive(parent.pid):
            os.kill(parent.pid, signal.SIGKILL)


def test_nothing_is_signalled_before_the_mutants_start():
    parent, child = start(SLEEPER)
    with watching(parent.pid, armed=False, limit=0.1, grace=30.0) as dog:
        time.sleep(0.6)
        assert parent.poll() is None and dog.ended == []
        dog.armed.set()
        assert wait_for(lambda: parent.poll() is not None)
        assert dog.ended[0] == (child, "XCPU")


def test_mutmuts_output_passes_through_and_arms_the_watchdog_on_its_line(capfd):
    mf = load_script()
    dog = mf.MutantWatchdog(0, limit=1.0)
    # the marker split across two reads, as a pipe may deliver it
    mf.forward_output(io.BufferedReader(io.BytesIO(b"Running stats\n   done\nRunning mutat")), dog)
    assert not dog.armed.is_set()
    mf.forward_output(io.BufferedReader(io.BytesIO(b"Running mutation testing\n1/10")), dog)
    assert dog.armed.is_set()
    assert capfd.readouterr().out.endswith("Running mutation testing\n1/10")


# A stand-in for the mutmut executable: one worker in its process group, both sleeping; it writes the pids.
FAKE_MUTMUT = """#!{python}
import subprocess, sys, time, pathlib
worker = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
pathlib.Path({pids!r}).write_text(f"{{__import__('os').getpid()}} {{worker.pid}}")
time.sleep(60)
"""

SWEEP = """
import sys, importlib.util
spec = importlib.util.spec_from_file_location("mutation_full", {script!r})
mf = importlib.util.module_from_spec(spec); spec.loader.exec_module(mf)
mf.MUTMUT = {fake!r}
print("rc", mf.run_sweep(__import__("pathlib").Path({tree!r}), 1, None, [], 180.0), flush=True)
"""


def alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split()[2] != "Z"
    except FileNotFoundError:
        return False


def test_sigterm_to_the_script_stops_mutmut_and_its_workers(tmp_path):
    pids = tmp_path / "pids"
    fake = tmp_path / "mutmut"
    fake.write_text(FAKE_MUTMUT.format(python=sys.executable, pids=str(pids)))
    fake.chmod(0o755)
    code = SWEEP.format(script=str(ROOT / "scripts" / "mutation_full.py"), fake=str(fake), tree=str(tmp_path))
    sweep = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert wait_for(lambda: pids.exists() and len(pids.read_text().split()) == 2)
        mutmut_pid, worker_pid = map(int, pids.read_text().split())
        sweep.send_signal(signal.SIGTERM)
        out, _ = sweep.communicate(timeout=40)
        assert "stopped (resume with the same command)" in out and "rc 0" in out
        assert wait_for(lambda: not alive(mutmut_pid) and not alive(worker_pid), timeout=10)
    finally:
        sweep.kill()


# mutmut with its fork server: mutmut -> server (lives for the whole sweep) -> one worker per mutant
SERVER = """
import subprocess, sys, time
worker = subprocess.Popen([sys.executable, "-c", sys.argv[1]], stdout=subprocess.PIPE, text=True)
print(worker.stdout.readline().strip(), flush=True)
time.sleep(60)
"""
MUTMUT_WITH_SERVER = """
import subprocess, sys
server = subprocess.Popen([sys.executable, "-c", sys.argv[1], sys.argv[2]], stdout=subprocess.PIPE, text=True)
print(server.pid, server.stdout.readline().strip(), flush=True)
server.wait()
"""


def test_with_a_fork_server_only_its_workers_are_signalled_never_the_server():
    top = subprocess.Popen(
        [sys.executable, "-c", MUTMUT_WITH_SERVER, SERVER, SLEEPER], stdout=subprocess.PIPE, text=True
    )
    server, worker = map(int, top.stdout.readline().split())
    try:
        with watching(top.pid, limit=0.3, grace=30.0, depth=2) as dog:
            assert wait_for(lambda: not alive(worker))
            time.sleep(0.5)
            assert dog.ended == [(worker, "XCPU")]
            assert alive(server)
    finally:
        os.kill(server, signal.SIGKILL)


def test_the_isolation_mode_is_read_from_the_trees_mutmut_config(tmp_path):
    mf = load_script()
    (tmp_path / "pyproject.toml").write_text('[tool.mutmut]\nprocess_isolation = "forkserver"\n')
    assert mf.isolation(tmp_path) == "forkserver"
    (tmp_path / "pyproject.toml").write_text("[tool.mutmut]\n")
    assert mf.isolation(tmp_path) == "fork"
