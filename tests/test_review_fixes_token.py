"""Review fix: the documented two-host token step works on a fresh store: `accrue robot token` makes the
store's link token (the function the learner and actor use) and a 0600 copy, never printing it unless
--show."""

from __future__ import annotations

import pytest
from test_robot_link_auth import cli

pytestmark = pytest.mark.timeout(300)


def test_robot_token_makes_the_store_token_and_a_private_copy_without_printing_it(tmp_path):
    from accrue.robot.link_auth import read_token_file

    assert cli("init", "--store", str(tmp_path / "store")).returncode == 0
    assert not (tmp_path / "store" / "robot" / "link-token").exists()  # a fresh store has none
    made = cli("robot", "token", "--store", str(tmp_path / "store"), "--out", str(tmp_path / "lab-token"))
    assert made.returncode == 0, made.stderr
    token = read_token_file(tmp_path / "store" / "robot" / "link-token")
    assert (tmp_path / "lab-token").stat().st_mode & 0o777 == 0o600
    assert read_token_file(tmp_path / "lab-token") == token
    assert token not in made.stdout + made.stderr and "made now" in made.stdout

    again = cli("robot", "token", "--store", str(tmp_path / "store"), "--show")
    assert again.returncode == 0 and again.stdout.strip().splitlines()[-1] == token
    assert "made now" not in again.stdout

    (tmp_path / "other").write_text("something else\n")
    clash = cli("robot", "token", "--store", str(tmp_path / "store"), "--out", str(tmp_path / "other"))
    assert clash.returncode != 0 and len(clash.stderr.strip().splitlines()) == 1
    assert "exists and is not this token" in clash.stderr
    assert (tmp_path / "other").read_text() == "something else\n"
