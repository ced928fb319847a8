"""Review fix: bad TLS files on the learner are named as a bad certificate/key pair before gRPC sees them
(gRPC reports them only as an address it cannot listen on)."""

from __future__ import annotations

import pytest
from test_review_fixes_refused import make_pairs
from test_robot_learner_link import TOKEN
from test_robot_link_auth import cli

from accrue.errors import AccrueError

pytestmark = pytest.mark.timeout(300)


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    return make_pairs(tmp_path_factory.mktemp("certs"))


def test_a_bad_tls_pair_on_the_learner_is_named_as_such(tmp_path, pair):
    from accrue.robot.transport import serve

    text = tmp_path / "hostname"
    text.write_text("gpu-box\n")
    cases = [
        (text, text, "is not a PEM certificate (it is not PEM"),
        (pair / "a" / "learner.crt", pair / "b" / "learner.key", "(the key is not the certificate's)"),
        (pair / "a" / "learner.key", pair / "a" / "learner.crt", "is not a PEM certificate (it holds PRIVATE KEY"),
    ]
    for cert, key, says in cases:
        with pytest.raises(AccrueError) as err:
            serve({}, "127.0.0.1:0", token=TOKEN, tls_cert=cert, tls_key=key)
        line = str(err.value)
        assert line.startswith(f"learner link: --tls-cert {cert} and --tls-key {key} are not a usable PEM pair")
        assert says in line and "cannot listen" not in line

    (tmp_path / "store").mkdir()
    assert cli("init", "--store", str(tmp_path / "store")).returncode == 0
    run = cli("robot", "learner", "--store", str(tmp_path / "store"), "--tls-cert", str(text), "--tls-key", str(text))
    assert run.returncode != 0 and len(run.stderr.strip().splitlines()) == 1
    assert "are not a usable PEM pair" in run.stderr and "cannot listen" not in run.stderr
