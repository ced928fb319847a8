"""Small fixes found while writing docs/ROBOT_LINK.md and docs/OPERATOR.md (issue 21):

- a step stopped by SIGTERM is recorded as that, not as "interrupted (Ctrl-C)";
- the actor's link removes its `accrue-actor-*` directory of weight snapshots when it closes, and at exit
  when it never closed, and the next link removes one whose process was killed (58 were left in /tmp on
  the shared machine);
- a learner port in use names a port that is free now, one the user can write into both workflows.
"""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from rich.console import Console

from accrue.errors import AccrueError
from accrue.robot.transport import serve

pytestmark = pytest.mark.timeout(300)
ROOT = Path(__file__).resolve().parents[1]
TOKEN = "docs-fixes-token"


# ---------------------------------------------------------------------------------------------- signals
@pytest.mark.parametrize(
    "sig, recorded",
    [(signal.SIGTERM, "stopped by signal (SIGTERM)"), (signal.SIGINT, "stopped by operator (Ctrl-C)"), (None, None)],
)
def test_an_abandoned_attempt_names_what_stopped_it(tmp_path, sig, recorded):
    from artifacts.auditlog import iter_events
    from artifacts.records import list_attempts
    from artifacts.store import Store
    from stages.runner import Runner
    from stages.runner_types import StepDef, StepInvocation
    from stages.steps.robot_session import StopSignals

    store = Store.init(tmp_path / "store")[0]

    def body(ctx):
        if sig is None:
            raise KeyboardInterrupt  # Python's own SIGINT handler: Ctrl-C
        stops = StopSignals()
        stops.first = sig  # as its handler sets it on the first signal
        raise stops.stop()

    console = Console(record=True, width=200, file=open(os.devnull, "w"))
    with pytest.raises(KeyboardInterrupt):
        Runner(store, console=console).run(StepInvocation(step=StepDef("train", "1", body), config={}))
    want = recorded or "interrupted (Ctrl-C)"
    (attempt,) = list_attempts(store)
    assert attempt["state"] == "abandoned" and attempt["error"] == want
    (event,) = [e for e in iter_events(store) if e["event"] == "step-abandoned"]
    assert event["error"] == want


# ------------------------------------------------------------------------------------ the actor's tmp dir
def closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]  # nothing listens on it once closed


def test_the_link_removes_its_snapshot_directory_at_close():
    from accrue.robot.learner_client import LearnerLink
    from accrue.robot.link_auth import LinkAuth

    reports: list[str] = []
    link = LearnerLink(
        lambda: ({}, b""),
        list,
        lambda h, d: None,
        lambda line, fields: reports.append(line),
        address=f"127.0.0.1:{closed_port()}",
        heartbeat_s=0.05,
        auth=LinkAuth(TOKEN),
    )
    assert link.tmp.name.startswith("accrue-actor-") and link.tmp.is_dir()
    (link.tmp / "v3").mkdir()  # as a weights snapshot lands there
    (link.tmp / "v3" / "learner.json").write_text("{}")
    link.start()
    link.close()
    assert not link.tmp.exists()


def test_a_link_never_closed_leaves_no_directory_at_exit(tmp_path):
    code = (
        "from accrue.robot.learner_client import LearnerLink\n"
        "link = LearnerLink(lambda: ({}, b''), list, lambda h, d: None, lambda l, f: None, address='127.0.0.1:9')\n"
        "(link.tmp / 'v1').mkdir()\n"
        "print(link.tmp)\n"
    )
    run = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    left = Path(run.stdout.strip())
    assert left.name.startswith("accrue-actor-") and not left.exists()


# ----------------------------------------------------------------------------------------- port in use
def free_port_named(message: str) -> int:
    found = re.search(r"port (\d+) is free now: --listen 127\.0\.0\.1:(\d+)", message)
    assert found and found.group(1) == found.group(2), message
    return int(found.group(1))


def test_a_port_in_use_names_a_free_port_that_works():
    server, port = serve({}, "127.0.0.1:0", token=TOKEN)
    try:
        with pytest.raises(AccrueError, match=r"the port is in use") as err:
            serve({}, f"127.0.0.1:{port}", token=TOKEN)
        free = free_port_named(str(err.value))
        assert free != port and f"robot.learner_address: <this host>:{free}" in str(err.value)
        other, bound = serve({}, f"127.0.0.1:{free}", token=TOKEN)  # the advice can be followed as printed
        other.stop(grace=0)
        assert bound == free
    finally:
        server.stop(grace=0)


def test_a_host_that_is_not_this_machines_is_named_as_that():
    with pytest.raises(AccrueError, match=r"192\.0\.2\.7 is not an address of this machine"):
        serve({}, "192.0.2.7:50051", token=TOKEN)  # TEST-NET-1: never a local address


def test_accrue_robot_learner_on_a_port_in_use_is_one_line_with_the_free_port(tmp_path):
    server, port = serve({}, "127.0.0.1:0", token=TOKEN)
    try:
        token_file = tmp_path / "token"
        token_file.write_text(TOKEN)
        token_file.chmod(0o600)
        env = {k: v for k, v in os.environ.items() if k != "ACCRUE_LINK_TOKEN"}
        run = subprocess.run(
            [sys.executable, "-m", "cli.main", "robot", "learner", "--listen", f"127.0.0.1:{port}"]
            + ["--token-file", str(token_file)],
            cwd=ROOT,
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
        )
    finally:
        server.stop(grace=0)
    assert run.returncode != 0 and len(run.stderr.strip().splitlines()) == 1, run.stderr
    assert run.stderr.startswith("error: learner: cannot listen on") and free_port_named(run.stderr) != port


def test_a_killed_actors_directory_is_removed_by_the_next_link(tmp_path, monkeypatch):
    """kill -9 runs no cleanup: the next link on the machine removes dirs whose process is gone."""
    import tempfile

    from accrue.robot import learner_client

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    dead = tmp_path / f"accrue-actor-{gone.pid}-abc"
    (dead / "v2").mkdir(parents=True)
    live = tmp_path / f"accrue-actor-{os.getppid()}-def"  # a running process's (pytest's parent)
    live.mkdir()
    old_style = tmp_path / "accrue-actor-q1w2e3"  # before the pid was in the name: whose, unknown
    old_style.mkdir()
    link = learner_client.LearnerLink(lambda: ({}, b""), list, lambda h, d: None, lambda line, f: None, address="h:1")
    try:
        assert not dead.exists() and live.is_dir() and old_style.is_dir()
        assert link.tmp.parent == tmp_path and link.tmp.name.startswith(f"accrue-actor-{os.getpid()}-")
    finally:
        link.close()


# ---------------------------------------------------------------------------- the learner's temp dir
def test_the_learner_removes_its_directory_and_keeps_no_snapshot_copies(tmp_path, monkeypatch):
    """The learner's `accrue-learner-<pid>-*` dir held a dead copy of the learner per published snapshot
    and was never removed (77 were left in /tmp here); a killed learner's is swept by the next one."""
    import tempfile

    from test_robot_learner_link import init_payload

    from accrue.robot import learner_service

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    dead = tmp_path / f"accrue-learner-{gone.pid}-abc"
    (dead / "snap").mkdir(parents=True)
    service = learner_service.LearnerService()
    assert not dead.exists()
    assert service.tmp.parent == tmp_path and service.tmp.name.startswith(f"accrue-learner-{os.getpid()}-")
    header, blob = init_payload(tmp_path)
    service.init({**header, "run_id": "run-a"}, blob)
    before = set(service.tmp.iterdir())
    for checkpoint in (False, True, False):
        with service.lock:
            service._snapshot(checkpoint)
    assert set(service.tmp.iterdir()) == before  # each snapshot is served from its tar bytes only
    assert service.snapshot[0] == service.version and service.snapshot[3]
    service.remove_tmp()
    assert not service.tmp.exists()
