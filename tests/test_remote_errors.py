"""Remote mistakes are one line on stderr, exit 2, and change nothing in the local store: wrong
credentials, a missing bucket, an unreachable endpoint, an unmounted disk, bad names and URLs."""

from __future__ import annotations

import json
import re
import socket
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from remote_support import cli, make_store, moto_endpoint, s3_client, s3_env, snapshot  # noqa: E402,F401
from test_cli_store import one_line_error  # noqa: E402


@pytest.fixture
def robot(tmp_path) -> Path:
    path = tmp_path / "robot"
    make_store(path, files=2)
    return path


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("verb", ["push", "pull", "fetch"])
def test_wrong_credentials_missing_bucket_and_unreachable_endpoint(robot, s3_env, monkeypatch, verb):
    from moto.core.authorization import enable_iam_authentication

    s3_client(s3_env).create_bucket(Bucket="lab-store")
    cli(robot, "remote", "add", "origin", "s3://lab-store/accrue")
    cli(robot, "remote", "add", "gone", "s3://no-such-bucket-here/accrue")
    before = snapshot(robot)

    monkeypatch.setenv("AWS_ACCESS_KEY_ID", "AKIAWRONGKEY000000")
    with enable_iam_authentication():
        line = one_line_error(cli(robot, verb, "origin"))
    assert re.fullmatch(
        r"error: remote origin \(s3://lab-store/accrue\): access denied \(InvalidAccessKeyId\); "
        r"check AWS_ACCESS_KEY_ID / AWS_SECRET_ACCESS_KEY or AWS_PROFILE",
        line,
    ), line
    monkeypatch.setenv("AWS_ACCESS_KEY_ID", "testing")

    line = one_line_error(cli(robot, verb, "gone"))
    assert (
        line == "error: remote gone (s3://no-such-bucket-here/accrue): the bucket does not exist "
        "(create it, or fix the URL)"
    )

    endpoint = f"http://127.0.0.1:{_closed_port()}"
    monkeypatch.setenv("AWS_ENDPOINT_URL", endpoint)
    line = one_line_error(cli(robot, verb, "origin"))
    assert f"cannot reach {endpoint} (no answer, or the connection failed)" in line
    assert snapshot(robot) == before


def test_an_unmounted_directory_remote_and_an_empty_one(robot, tmp_path):
    cli(robot, "remote", "add", "usb", str(tmp_path / "media" / "usb" / "accrue"))
    before = snapshot(robot)
    for verb in ("push", "pull"):
        line = one_line_error(cli(robot, verb, "usb"))
        assert "does not exist (is the disk mounted?)" in line, line
    (tmp_path / "media" / "usb" / "accrue").mkdir(parents=True)
    assert "holds no accrue store yet (push to it first)" in one_line_error(cli(robot, "pull", "usb"))
    assert snapshot(robot) == before


@pytest.mark.parametrize(
    "args, pattern",
    [
        (("remote", "add", "bad name", "/tmp/x"), r"bad remote name"),
        (("remote", "add", "web", "https://example.com/x"), r"unsupported scheme"),
        (("remote", "add", "s3", "s3:///prefix"), r"names no bucket"),
        (("remote", "remove", "nowhere"), r"no remote named 'nowhere'"),
        (("push",), r"this store has no remotes; add one with `accrue remote add NAME URL`"),
        (("pull", "--only", "Not A Kind"), r"bad artifact kind|no remotes"),
    ],
)
def test_remote_argument_mistakes(robot, args, pattern):
    line = one_line_error(cli(robot, *args))
    assert re.search(pattern, line), line


def test_remote_add_list_remove_and_choosing_one(robot, tmp_path):
    (tmp_path / "nas").mkdir()
    assert cli(robot, "remote", "add", "nas", str(tmp_path / "nas" / "a"), "--create").returncode == 0
    assert "exists already" in one_line_error(cli(robot, "remote", "add", "nas", str(tmp_path / "b")))
    cli(robot, "remote", "add", "cloud", "s3://bucket-x/lab")
    listed = json.loads(cli(robot, "remote", "list", "--json").stdout)
    assert listed == {
        "cloud": {"kind": "s3", "promisor": False, "url": "s3://bucket-x/lab"},
        "nas": {"kind": "dir", "promisor": False, "url": str(tmp_path / "nas" / "a")},
    }
    # two remotes, none named origin: the name is required; a ref that matches nothing says so
    assert "which remote?" in one_line_error(cli(robot, "push"))
    assert "no ref 'team/nothing' in this store" in one_line_error(cli(robot, "push", "nas", "team/nothing"))
    assert cli(robot, "push", "nas", "team").returncode == 0
    tracking = json.loads(cli(robot, "refs", "remotes/nas/", "--json").stdout)
    assert sorted(tracking) == ["remotes/nas/team/handoff", "remotes/nas/team/replay"]
    removed = cli(robot, "remote", "remove", "nas")
    assert removed.returncode == 0 and "2 remote-tracking refs dropped" in removed.stdout
    assert json.loads(cli(robot, "refs", "remotes/", "--json").stdout) == {}
    assert list(json.loads(cli(robot, "remote", "list", "--json").stdout)) == ["cloud"]
    assert cli(robot, "verify").returncode == 0
