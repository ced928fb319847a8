"""Review fix: `accrue robot learner`'s messages name the command that exists (not `accrue learner`), and
`accrue robot certs --host ""` is refused in one line instead of writing a certificate for an empty name."""

from __future__ import annotations

import pytest
from test_robot_link_auth import cli

pytestmark = pytest.mark.timeout(300)


def test_learner_errors_name_the_real_command(tmp_path):
    run = cli("robot", "learner", "--listen", "127.0.0.1:0", timeout=60)
    assert run.returncode != 0 and run.stderr.startswith("error: accrue robot learner: no link token")
    run = cli("robot", "learner", "--token-file", str(tmp_path / "none"), timeout=60)
    assert run.returncode != 0 and "error: accrue robot learner --token-file: cannot read" in run.stderr


def test_the_spawned_learners_messages_name_the_real_command_too():
    from accrue.errors import AccrueError
    from accrue.robot.learner_service import check_listen, main

    with pytest.raises(AccrueError, match=r"^accrue robot learner: give --tls-cert and --tls-key together"):
        main(["--tls-cert", "x"])
    with pytest.raises(AccrueError, match=r"^accrue robot learner: listening on 0.0.0.0:1 without TLS"):
        check_listen("0.0.0.0:1", tls=False, insecure=False)


@pytest.mark.parametrize("host", ["", " ", "a b"])
def test_certs_refuses_an_empty_or_spaced_host(tmp_path, host):
    made = cli("robot", "certs", str(tmp_path / "certs"), "--host", host)
    assert made.returncode != 0 and len(made.stderr.strip().splitlines()) == 1
    assert f"accrue robot certs --host: {host!r} is not a host name or IP address" in made.stderr
    assert not (tmp_path / "certs").exists()
