"""Review fix: a wrong token or a bad CA file is said as such, not as a learner that did not come back.

At load, robot.link.tls.{ca,cert,key} must be PEM of their kind (one line naming the file). On the link, a
learner that refuses this actor's token (UNAUTHENTICATED, PERMISSION_DENIED) or whose certificate the CA
does not verify is a LinkRefused (an AccrueError) with a line saying what to fix, reported once, kept in
LearnerLink.refused and raised by LearnerLink.check(); never reported as "learner unreachable"."""

from __future__ import annotations

from pathlib import Path

import pytest
from test_review_fixes_page import robot_workflow
from test_robot_learner_link import TOKEN, start_learner, wait_for

from accrue.errors import AccrueError
from stages.errors import StageError

pytestmark = pytest.mark.timeout(300)


def make_pairs(root: Path) -> Path:
    """Two self-signed pairs, root/a and root/b, from `accrue robot certs` (its function, in this process)."""
    from cli.robot_cmds import certs

    for name in ("a", "b"):
        certs(root / name, host=["127.0.0.1"], days=2)
    return root


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    return make_pairs(tmp_path_factory.mktemp("certs"))


def test_tls_files_that_are_not_pem_are_refused_at_load(tmp_path, pair):
    from accrue.robot.link_auth import validate_link_section
    from stages.workflow import load_workflow

    text = tmp_path / "hostname"
    text.write_text("gpu-box\n")
    with pytest.raises(AccrueError) as err:
        validate_link_section({"tls": {"ca": str(text)}}, "robot.link")
    assert str(err.value) == (
        f"robot.link.tls.ca: {text} is not a PEM certificate (it is not PEM; -----BEGIN CERTIFICATE----- expected)"
    )
    with pytest.raises(AccrueError, match=r"robot.link.tls.ca: .*learner.key is not a PEM certificate \(it holds"):
        validate_link_section({"tls": {"ca": str(pair / "a" / "learner.key")}}, "robot.link")
    with pytest.raises(AccrueError, match=r"robot.link.tls.key: .*learner.crt is not a PEM key"):
        validate_link_section({"tls": {"key": str(pair / "a" / "learner.crt")}}, "robot.link")
    good = {"ca": str(pair / "a" / "learner.crt"), "key": str(pair / "a" / "learner.key")}
    assert validate_link_section({"tls": good}, "robot.link") == {"tls": good}

    wf = robot_workflow(tmp_path, learner_address="127.0.0.1:50051", link={"tls": {"ca": str(text)}})
    with pytest.raises(StageError, match=r"hw.yaml: robot.link.tls.ca: .* is not a PEM certificate"):
        load_workflow(wf)


def refused_link(tmp_path, port: int, auth):
    from accrue.robot.learner_client import LearnerLink

    reports: list[tuple[str, dict]] = []
    link = LearnerLink(
        lambda: pytest.fail("a refused link must not get as far as Init"),
        lambda: [],
        lambda h, d: None,
        lambda line, fields: reports.append((line, dict(fields))),
        address=f"127.0.0.1:{port}",
        heartbeat_s=0.05,
        dead_after_s=0.2,
        auth=auth,
    )
    return link, reports


def test_a_learner_with_another_token_is_reported_as_refusing_not_as_away(tmp_path):
    from accrue.robot.learner_client import LinkRefused
    from accrue.robot.link_auth import link_auth_for

    service, server, port = start_learner()  # it checks TOKEN; this actor has its store's token
    auth = link_auth_for({}, tmp_path / "store")
    link, reports = refused_link(tmp_path, port, auth)
    try:
        link.check()  # nothing refused yet
        link.start()
        wait_for(lambda: link.refused is not None, 60, "the refusal")
        with pytest.raises(LinkRefused) as err:
            link.check()
    finally:
        link.close()
        server.stop(grace=0)
        service.stop.set()
    assert isinstance(err.value, AccrueError) and err.value.reason == "token"
    line = str(err.value)
    assert line.startswith(f"the learner at 127.0.0.1:{port} refused this actor's link token (from ")
    assert str(tmp_path / "store" / "robot" / "link-token") in line and "robot.link.token_file" in line
    assert not link.healthy()
    events = [f["event"] for _, f in reports]
    assert events == ["robot-link-refused-by-learner"]  # once, and never "unreachable"
    assert reports[0][0] == line and auth.token not in line


def test_a_learner_whose_certificate_the_ca_does_not_verify_is_a_tls_refusal(tmp_path, pair):
    from accrue.robot.learner_client import LinkRefused
    from accrue.robot.link_auth import LinkAuth

    service, server, port = start_learner(tls_cert=pair / "a" / "learner.crt", tls_key=pair / "a" / "learner.key")
    link, reports = refused_link(tmp_path, port, LinkAuth(TOKEN, tls_ca=pair / "b" / "learner.crt"))
    try:
        link.start()
        wait_for(lambda: link.refused is not None, 60, "the refusal")
        with pytest.raises(LinkRefused) as err:
            link.check()
    finally:
        link.close()
        server.stop(grace=0)
        service.stop.set()
    assert err.value.reason == "tls"
    assert str(err.value).startswith(f"TLS with the learner at 127.0.0.1:{port} failed (")
    assert f"robot.link.tls.ca {pair / 'b' / 'learner.crt'} must be the learner's --tls-cert" in str(err.value)
    assert [f["event"] for _, f in reports] == ["robot-link-refused-by-learner"]


def test_permission_denied_is_a_refusal_too():
    """A learner behind a proxy that answers PERMISSION_DENIED refuses this actor as UNAUTHENTICATED does."""
    import grpc

    from accrue.robot.transport import LinkRefused, Peer

    class Denied(grpc.RpcError):
        def code(self):
            return grpc.StatusCode.PERMISSION_DENIED

    def unary_unary(name):
        def call(*args, **kwargs):
            raise Denied()

        return call

    peer = Peer("127.0.0.1:1", TOKEN)
    peer.channel.close()
    peer.channel = type("Channel", (), {"unary_unary": staticmethod(unary_unary), "close": lambda self: None})()
    with pytest.raises(LinkRefused, match="Hello to 127.0.0.1:1: PERMISSION_DENIED") as err:
        peer.call("Hello", {})
    assert err.value.reason == "token"
