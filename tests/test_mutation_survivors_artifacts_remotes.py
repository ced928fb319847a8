"""Tests written to kill mutants of artifacts/remotes/ (and the store's hook for them) that survived
round 3 of mutmut's fourth sweep (docs/MUTATION.md, "The fourth sweep"). Each docstring names the mutmut
ids it kills. What they pin: a directory remote's ref deletion only removes the version it was told
to, with one-line refusals; and a partial clone's missing object is fetched through the fetcher the
remotes register. Everything runs in a temporary directory, without a network.
"""

from __future__ import annotations

import threading
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


# ----------------------------------------------------------------------------- remotes.repair / rekey / push
def pushed_store(tmp_path: Path) -> tuple[Store, Path, dict[str, str]]:
    """A store with three file artifacts (500, 200 and 0 bytes) pushed to directory remote nas; returns
    the store, the remote's root and each artifact's content id."""
    from artifacts.ingest import add_path
    from artifacts.refs import read_ref
    from artifacts.remotes.config import add_remote
    from artifacts.remotes.push import push

    store, _ = Store.init(tmp_path / "store")
    contents = {}
    for name, data in (("a", b"alpha" * 100), ("b", b"beta" * 50), ("e", b"")):
        (tmp_path / f"{name}.bin").write_bytes(data)
        add_path(store, tmp_path / f"{name}.bin", "replay", ref=f"team/{name}")
        contents[name] = store.read_json(read_ref(store, f"team/{name}"))["content"]
    add_remote(store, "nas", str(tmp_path / "remote"))
    push(store, "nas")
    return store, tmp_path / "remote", contents


def lose_on_remote(remote: Path, oids) -> None:
    for oid in oids:
        (remote / "objects" / "blake3" / oid[:2] / oid[2:]).unlink()


class RecordingMeter:
    def __init__(self) -> None:
        self.starts: list[tuple] = []
        self.threads: set[str] = set()

    def start(self, what: str, objects: int, nbytes: int) -> None:
        self.starts.append((what, objects, nbytes))

    def advance(self, nbytes: int) -> None:
        self.threads.add(threading.current_thread().name)

    def stop(self) -> None:
        pass


def test_repair_with_its_defaults_resends_what_the_remote_lost_and_reports_it(tmp_path):
    """repair_remote 1 (full by default), 8 (jobs None: a traceback), 9 (no meter: a traceback), 22, 23,
    24, 27 (the report's remote, full and damaged count), 38 (an empty object counted as 1 byte)."""
    from artifacts.remotes.repair import repair_remote

    store, remote, contents = pushed_store(tmp_path)
    lose_on_remote(remote, contents.values())
    report = repair_remote(store, "nas")
    assert (report.remote, report.full, report.damaged) == ("nas", False, 3)
    assert sorted(report.resent) == sorted(contents.values())
    assert report.bytes_sent == 700 and report.unhealed == []
    assert report.as_dict()["full"] is False and report.as_dict()["remote"] == "nas"
    assert repair_remote(store, "nas").damaged == 0
    store.close()


def test_repair_passes_its_jobs_and_meter_to_the_check_and_meters_the_resend(tmp_path):
    """repair_remote 14, 19 (the check ignores jobs=1: re-hashed on worker threads), 15, 20 (the check's
    re-hashing not on the caller's meter), 40, 41 (the resend's object count and bytes)."""
    from artifacts.remotes.repair import repair_remote

    store, remote, contents = pushed_store(tmp_path)
    lose_on_remote(remote, contents.values())
    meter = RecordingMeter()
    report = repair_remote(store, "nas", full=True, jobs=1, meter=meter)
    assert report.full is True and report.damaged == 3 and report.bytes_sent == 700
    assert [s[0] for s in meter.starts] == ["re-hashing nas", "repair → nas"]
    assert meter.starts[0][1] > 1  # the manifests and log objects still there
    assert meter.starts[1] == ("repair → nas", 3, 700)
    assert meter.threads == {threading.main_thread().name}
    store.close()


def test_rekey_returns_the_old_id_and_forgets_each_remotes_log_chain_position(tmp_path):
    """config.rekey_store 1-4 (the old id lost), 17-19, 22, 23 (log.json kept), 24, 27, 28 (logs.json kept)."""
    from artifacts.remotes.config import rekey_store, store_id

    store, _, _ = pushed_store(tmp_path)
    state = tmp_path / "store" / "remotes" / "nas"
    assert (state / "log.json").is_file() and (state / "logs.json").is_file()
    sid = store_id(store)
    old, new = rekey_store(store)
    assert old == sid and new != sid and store_id(store) == new
    assert not (state / "log.json").exists() and not (state / "logs.json").exists()
    assert (state / "refs.json").is_file()  # the refs' positions are this store's, whatever its id
    store.close()


def test_a_store_whose_id_another_store_pushed_a_log_under_is_refused_in_one_exact_line(tmp_path):
    """push._same_id 1 (13 characters of the id), 2 (the message's end)."""
    from artifacts.ingest import add_path
    from artifacts.remotes.config import add_remote, store_id
    from artifacts.remotes.push import push

    store, remote, _ = pushed_store(tmp_path)
    sid = store_id(store)
    twin, _ = Store.init(tmp_path / "twin")
    (tmp_path / "t.bin").write_bytes(b"the twin's work")
    add_path(twin, tmp_path / "t.bin", "replay", ref="twin/replay")
    add_remote(twin, "nas", str(remote))
    store_id(twin)  # its own directory recorded
    twin.update_config(lambda c: c.update(store_id=sid))
    push(twin, "nas")  # starts its chain over the first store's pointer
    with pytest.raises(StoreError) as exc:
        push(store, "nas")
    assert str(exc.value) == (
        f"remote nas: another store pushed an audit log with this store's id {sid[:12]} (a copied store?); "
        "nothing was sent; run `accrue remote rekey` in the copy, then push again"
    )
    twin.close()
    store.close()
