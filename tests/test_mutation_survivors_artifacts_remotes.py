"""Tests written to kill mutants of artifacts/remotes/ (and the store's hook for them) that survived
round 3 of mutmut's fourth sweep (docs/MUTATION.md, "The fourth sweep"). Each docstring names the mutmut
ids it kills. What they pin: a directory remote's ref deletion only removes the version it was told
to, with one-line refusals; and a partial clone's missing object is fetched through the fetcher the
remotes register. Everything runs in a temporary directory, without a network.
"""

from __future__ import annotations

from pathlib import Path

import pytest

import artifacts.store
from artifacts.errors import StoreError
from artifacts.hashing import hash_bytes
from artifacts.remotes.backends import RefMoved
from artifacts.remotes.config import parse_url
from artifacts.remotes.directory import DirBackend
from artifacts.store import Store, add_missing_fetcher

KEY = "refs/team/handoff"


def dir_backend(path: Path) -> DirBackend:
    b = DirBackend(parse_url("nas", str(path)))
    b.probe(create=True)
    return b


# ----------------------------------------------------------------------------- remotes.directory.delete
def test_a_directory_remote_deletes_a_ref_only_at_the_version_it_was_told(tmp_path):
    """DirBackend.delete 4 (a moved ref deleted anyway; a missing one a traceback), 8 (RefMoved carries
    the key)."""
    b = dir_backend(tmp_path / "remote")
    b.swap(KEY, b"one\n", None)
    with pytest.raises(RefMoved) as exc:
        b.delete(KEY, "two\n")
    assert exc.value.args == (KEY,)
    assert b.get_bytes(KEY) == b"one\n"
    b.delete(KEY, "one\n")
    assert b.get_bytes(KEY) is None
    with pytest.raises(RefMoved) as exc:
        b.delete(KEY, "one\n")
    assert exc.value.args == (KEY,)


def test_a_ref_deletion_that_cannot_lock_names_the_remote_key_and_reason(tmp_path):
    """DirBackend.delete 12, 13: the OSError's reason (its strerror), not its repr, after the remote and key."""
    root = tmp_path / "remote"
    b = dir_backend(root)
    b.swap(KEY, b"one\n", None)
    (root / "locks" / "refs" / "team").rmdir()  # the swap's lock directory, empty again
    (root / "locks" / "refs" / "team").write_text("a file where the lock's directory should be")
    with pytest.raises(StoreError) as exc:
        b.delete(KEY, "one\n")
    assert str(exc.value) == f"remote nas ({root}): cannot remove {KEY}: File exists"
    assert b.get_bytes(KEY) == b"one\n"


# ----------------------------------------------------------------------------- store.add_missing_fetcher
def test_a_partial_clones_missing_object_comes_through_the_registered_fetcher(tmp_path, monkeypatch):
    """store.add_missing_fetcher 1 (never registered: the object stays missing), 2 (None registered: a
    traceback); registering the same fetcher twice keeps one."""
    monkeypatch.setattr(artifacts.store, "_MISSING_FETCHERS", [])
    store, _ = Store.init(tmp_path / "store")
    store.update_config(lambda c: c.setdefault("remotes", {}).update({"origin": {"url": "x", "promisor": True}}))
    data = b"left on the remote by pull --only"
    oid = hash_bytes(data)
    asked: list[list[str]] = []

    def fetch(s: Store, missing: list[str]) -> bool:
        asked.append(list(missing))
        s.put_bytes(data)
        return True

    add_missing_fetcher(fetch)
    add_missing_fetcher(fetch)
    assert artifacts.store._MISSING_FETCHERS == [fetch]
    assert store.read_bytes(oid) == data
    assert asked == [[oid]]
    store.close()


# ----------------------------------------------------------------------------- remotes.s3.explain_s3_error
class PermissionDeniedError(Exception):
    """Named like obstore's: explain_s3_error goes by the class name."""


class UnauthenticatedError(Exception):
    pass


REACH = (
    "error sending request",
    "connection refused",
    "dns error",
    "request timed out",
    "tcp connect",
    "client connect error",
    "failed to lookup address",
    "connection reset by peer",
    "deadline has elapsed",
)


def explained(exc: BaseException) -> str:
    from artifacts.remotes.s3 import explain_s3_error

    return str(explain_s3_error(exc, "remote origin (s3://b/p)", "http://127.0.0.1:9"))


@pytest.mark.parametrize(
    "code",
    [
        "InvalidAccessKeyId",
        "SignatureDoesNotMatch",
        "AccessDenied",
        "InvalidToken",
        "ExpiredToken",
        "AuthorizationHeaderMalformed",
    ],
)
def test_an_s3_authentication_error_code_is_explained_as_access_denied(code):
    """s3.explain_s3_error 17–34: each code S3 answers for bad or expired keys."""
    assert explained(Exception(f"<Error><Code>{code}</Code></Error>")) == (
        f"remote origin (s3://b/p): access denied ({code}); check AWS_ACCESS_KEY_ID / "
        "AWS_SECRET_ACCESS_KEY or AWS_PROFILE"
    )


@pytest.mark.parametrize("cls", [PermissionDeniedError, UnauthenticatedError])
def test_an_obstore_permission_error_is_explained_as_access_denied_by_its_class(cls):
    """s3.explain_s3_error 35, 37–42, 45: the error's class names it when S3 sent no code."""
    assert explained(cls("forbidden")) == (
        f"remote origin (s3://b/p): access denied ({cls.__name__}); check AWS_ACCESS_KEY_ID / "
        "AWS_SECRET_ACCESS_KEY or AWS_PROFILE"
    )


@pytest.mark.parametrize(
    "text", ["GET http://169.254.169.254/latest/api/token failed", "Generic S3 error: Credential lookup error"]
)
def test_missing_aws_credentials_are_explained_with_what_to_set(text):
    """s3.explain_s3_error 49, 50, 53, 54, 56–62: the instance-metadata address, or 'credential' with
    'error' (any case), gives the exact credentials line."""
    assert explained(Exception(text)) == (
        "remote origin (s3://b/p): no AWS credentials found; set AWS_ACCESS_KEY_ID and AWS_SECRET_ACCESS_KEY, "
        "or a profile (`accrue remote set NAME profile PROFILE`)"
    )
    assert explained(Exception("credential provider configured")).startswith("remote origin (s3://b/p): credential")


@pytest.mark.parametrize("phrase", REACH)
def test_an_s3_connection_failure_is_explained_as_cannot_reach_the_endpoint(phrase):
    """s3.explain_s3_error 64–80, 83, 84: each phrase of a failed connection (any case), and only those."""
    assert explained(Exception(f"Generic S3 error: {phrase.upper()}")) == (
        "remote origin (s3://b/p): cannot reach http://127.0.0.1:9 (no answer, or the connection failed); "
        "check the network and the endpoint (`accrue remote set NAME endpoint URL`, or AWS_ENDPOINT_URL)"
    )
    assert explained(Exception("Generic S3 error: bucket is read-only")) == (
        "remote origin (s3://b/p): Generic S3 error: bucket is read-only"
    )
