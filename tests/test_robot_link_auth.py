"""Nobody but the actor drives the learner: a call without the link token, or with another, is refused
before its handler runs (Hello reveals no run id, Shutdown and Episode change nothing), counted, printed
and written to the store's audit log without the token; TLS with a pair from `accrue robot certs` carries
a whole actor-learner round trip, and the actor hears of the refusals; a bad --listen, a non-loopback
address without TLS or a port in use is one line and a non-zero exit."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from test_robot_learner_link import TOKEN, episode, init_payload, start_learner, wait_for

from accrue.errors import AccrueError
from accrue.robot.link_auth import LinkAuth, parse_address, store_token
from accrue.robot.transport import PROTOCOL, LinkRefused, Peer, PeerDown, serve

pytestmark = pytest.mark.timeout(300)
ROOT = Path(__file__).resolve().parents[1]


def cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env.pop("ACCRUE_LINK_TOKEN", None)
    return subprocess.run(
        [sys.executable, "-m", "cli.main", *args], cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout
    )


def test_calls_without_the_token_are_refused_logged_and_audited(tmp_path, capsys):
    from artifacts.auditlog import iter_events
    from artifacts.store import Store
    from cli.robot_cmds import store_audit

    store, _ = Store.init(tmp_path / "store")
    service, server, port = start_learner(audit=store_audit(store.root))
    service.run_id = "the-run-id"
    try:
        address = f"127.0.0.1:{port}"
        with pytest.raises(LinkRefused, match="UNAUTHENTICATED"):
            Peer(address).call("Hello", {"protocol": PROTOCOL})
        with pytest.raises(LinkRefused):
            Peer(address, "not-the-token").call("Shutdown", {})
        with pytest.raises(LinkRefused):
            Peer(address).call("Episode", {"run_id": "the-run-id", "index": 0}, episode(0))
        assert not service.stop.is_set() and service.episodes == {}
        assert service.refused == 3

        hello, _ = Peer(address, TOKEN).call("Hello", {"protocol": PROTOCOL})  # the token opens it
        assert hello["run_id"] == "the-run-id"
    finally:
        server.stop(grace=0)
        service.stop.set()
    refused = [e for e in iter_events(store) if e["event"] == "robot-link-refused"]
    assert [e["method"] for e in refused] == ["Hello", "Shutdown", "Episode"]
    assert all(e["peer"].startswith("ipv4:127.0.0.1:") and e["at"] for e in refused)
    printed = capsys.readouterr().out
    assert printed.count("accrue robot learner: refused ") == 3 and "refused Shutdown from ipv4:127.0.0.1:" in printed
    assert "the-run-id" not in printed
    for text in (printed, store.log_path.read_text()):
        assert TOKEN not in text and "not-the-token" not in text


def test_the_store_token_is_made_once_private_and_never_shown(tmp_path):
    token = store_token(tmp_path)
    assert store_token(tmp_path) == token and len(token) >= 40
    assert (tmp_path / "robot" / "link-token").stat().st_mode & 0o777 == 0o600
    assert token not in repr(LinkAuth(token))


def test_tls_round_trip_with_a_pair_from_accrue_robot_certs(tmp_path, one_torch_thread):
    from accrue.robot.learner_client import LearnerLink

    made = cli("robot", "certs", str(tmp_path / "certs"), "--host", "127.0.0.1")
    assert made.returncode == 0, made.stderr
    cert, key = tmp_path / "certs" / "learner.crt", tmp_path / "certs" / "learner.key"
    assert key.stat().st_mode & 0o777 == 0o600
    service, server, port = start_learner(tls_cert=cert, tls_key=key)
    reports: list[tuple[str, dict]] = []
    snapshots: list[int] = []
    link = LearnerLink(
        lambda: init_payload(tmp_path),
        lambda: [],
        lambda h, d: snapshots.append(h["version"]),
        lambda line, fields: reports.append((line, dict(fields))),
        address=f"127.0.0.1:{port}",
        heartbeat_s=0.1,
        dead_after_s=5.0,
        auth=LinkAuth(TOKEN, tls_ca=cert),
    )
    try:
        # a caller without TLS gets nothing; one with TLS but not the token is refused
        with pytest.raises(PeerDown, match="UNAVAILABLE"):
            Peer(f"127.0.0.1:{port}", TOKEN).call("Hello", {"protocol": PROTOCOL}, timeout=3)
        with pytest.raises(LinkRefused):
            Peer(f"127.0.0.1:{port}", tls_ca=cert).call("Shutdown", {})
        link.start()
        link.push({"index": 0, "relabel": False}, episode(0))
        wait_for(lambda: snapshots and service.updates >= 5, 120, "weights over TLS")
        assert sorted(service.episodes) == [0] and link.healthy() and link.weights_received_at is not None
        wait_for(lambda: any(f.get("event") == "robot-link-refused" for _, f in reports), 30, "the refusal")
        assert not service.stop.is_set()  # the refused Shutdown did nothing
    finally:
        link.close()
        server.stop(grace=0)
        service.stop.set()
    refused = [(line, f) for line, f in reports if f.get("event") == "robot-link-refused"]
    assert len(refused) == 1 and refused[0][1]["method"] == "Shutdown" and "refused Shutdown" in refused[0][0]
    assert all(TOKEN not in line and TOKEN not in str(f) for line, f in reports)


@pytest.mark.parametrize(
    "listen, says",
    [
        ("0.0.0.0:99999", "'0.0.0.0:99999' is not HOST:PORT"),
        ("127.0.0.1:-5", "'127.0.0.1:-5' is not HOST:PORT"),
        ("not an address", "'not an address' is not HOST:PORT"),
        ("0.0.0.0:50051", "without TLS"),
    ],
)
def test_a_bad_listen_address_is_one_line_and_a_non_zero_exit(listen, says):
    run = cli("robot", "learner", "--listen", listen, timeout=60)
    assert run.returncode != 0 and says in run.stderr
    assert len(run.stderr.strip().splitlines()) == 1 and run.stderr.startswith("error: ")


def test_parse_address_takes_only_host_and_port():
    assert parse_address("gpu-box:50051", "x") == ("gpu-box", 50051)
    assert parse_address("[::1]:7", "x") == ("[::1]", 7)
    for bad in ("gpu-box", ":50051", "h:0", "h:65536", "h:5a", "::1:5", "h:٣"):
        with pytest.raises(AccrueError, match="robot.learner_address"):
            parse_address(bad, "robot.learner_address")
    assert parse_address("h:0", "x", allow_zero=True) == ("h", 0)


def test_a_port_in_use_is_refused(tmp_path):
    server, port = serve({}, "127.0.0.1:0", token=TOKEN)
    try:
        with pytest.raises(AccrueError, match="cannot listen on '127.0.0.1:.*' \\(the port is in use"):
            serve({}, f"127.0.0.1:{port}", token=TOKEN)
        token_file = tmp_path / "token"
        token_file.write_text(TOKEN)
        token_file.chmod(0o600)
        run = cli("robot", "learner", "--listen", f"127.0.0.1:{port}", "--token-file", str(token_file), timeout=60)
        assert run.returncode != 0 and "the port is in use" in run.stderr
        assert len(run.stderr.strip().splitlines()) == 1
    finally:
        server.stop(grace=0)


def test_a_learner_whose_actor_is_gone_says_its_last_line_without_a_traceback():
    """kill -9 of the actor closes the pipe the spawned learner prints to: its goodbye must not end in a
    BrokenPipeError traceback (issue 21)."""
    import os
    import subprocess
    import sys

    read_end, write_end = os.pipe()
    os.close(read_end)  # the actor is gone: nobody reads the learner's stdout
    code = "from accrue.robot.learner_service import say; say('the actor is gone'); say('exiting')"
    out = subprocess.run([sys.executable, "-c", code], stdout=write_end, stderr=subprocess.PIPE, text=True)
    os.close(write_end)
    assert out.returncode == 0, out.stderr
    assert "Traceback" not in out.stderr and "BrokenPipe" not in out.stderr
