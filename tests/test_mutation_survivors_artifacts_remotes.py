"""Tests written to kill mutants of artifacts/remotes/ (and the store's hook for them) that survived
round 3 of mutmut's fourth sweep (docs/MUTATION.md, "The fourth sweep"). Each docstring names the mutmut
ids it kills. What they pin: a directory remote's ref deletion only removes the version it was told
to, with one-line refusals; and a partial clone's missing object is fetched through the fetcher the
remotes register. Everything runs in a temporary directory, without a network.

The tests of round 13 (docs/MUTATION.md) were written ahead of the sweep, per function: their docstrings name
the mutants they were written against; the sweep's verdicts, not the docstrings, are the measurement.
"""

from __future__ import annotations

import json
import os
import shutil
import threading
import warnings
from pathlib import Path

import pytest

import artifacts.store
from artifacts.errors import StoreError
from artifacts.hashing import hash_bytes
from artifacts.remotes.backends import RefMoved, object_key
from artifacts.remotes.config import parse_url
from artifacts.remotes.directory import DirBackend
from artifacts.remotes.pointers import local_refs
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
    "operation timed out",
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
    from artifacts.remotes.push import push

    files = {"a": b"alpha" * 100, "b": b"beta" * 50, "e": b""}
    store = store_pushing_to(tmp_path, "store", tmp_path / "remote", {f"team/{n}": d for n, d in files.items()})
    push(store, "nas")
    return store, tmp_path / "remote", {name: hash_bytes(data) for name, data in files.items()}


def lose_on_remote(remote: Path, oids) -> None:
    for oid in oids:
        (remote / object_key(oid)).unlink()


class RecordingMeter:
    def __init__(self) -> None:
        self.starts: list[tuple] = []
        self.threads: set[str] = set()
        self.advanced: list[int] = []

    def start(self, what: str, objects: int, nbytes: int) -> None:
        self.starts.append((what, objects, nbytes))

    def advance(self, nbytes: int) -> None:
        self.threads.add(threading.current_thread().name)
        self.advanced.append(nbytes)

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
    assert meter.advanced[-3:] and sum(meter.advanced[-3:]) == 700  # the resend advances by each object's size
    store.close()


def test_repair_resends_lost_manifests_after_their_data_on_several_threads(tmp_path):
    """repair_remote 56 (the resend's meter advanced by None), 66, 74 (data and each manifest group sent
    with jobs None: a traceback); the remote's manifests come back after what they name."""
    from artifacts.refs import read_ref
    from artifacts.remotes.check import verify_remote
    from artifacts.remotes.repair import repair_remote

    store, remote, contents = pushed_store(tmp_path)
    manifests = [read_ref(store, f"team/{name}") for name in ("a", "b", "e")]
    lose_on_remote(remote, [*contents.values(), *manifests])
    meter = RecordingMeter()
    report = repair_remote(store, "nas", jobs=4, meter=meter)
    assert report.damaged == 6 and sorted(report.resent) == sorted([*contents.values(), *manifests])
    resent = meter.starts[-1]
    assert resent[0] == "repair → nas" and resent[1] == 6
    assert sum(meter.advanced[-6:]) == resent[2] == report.bytes_sent
    assert verify_remote(store, "nas").damaged == []
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
        "no ref was moved; run `accrue remote rekey` in the copy, then push again"
    )
    twin.close()
    store.close()


# ============================================================================= round 7 batch H
# ----------------------------------------------------------------------------- remotes.logchain.check_chain
SID = "f" * 64  # another store's id, as its log pointer names it


def log_lines(n: int) -> list[bytes]:
    """n audit-log lines as a store writes them: seq 0.., each `prev` the hash of the line before."""
    from artifacts.auditlog import GENESIS
    from artifacts.hashing import canonical_json

    lines, prev = [], GENESIS
    for seq in range(n):
        line = canonical_json({"seq": seq, "ts": f"2026-12-0{seq + 1}T00:00:00Z", "event": "note", "prev": prev})
        lines.append(line)
        prev = hash_bytes(line)
    return lines


def put_segment(store: Store, lines: list[bytes], previous: str | None = None, **changes) -> str:
    """A pushed audit-log segment of these lines (manifest as logsegment.next_segment writes it, with
    `changes` applied); returns its manifest id. The lines' content is stored unless content= is given."""
    from artifacts.remotes.logsegment import KIND

    data = b"".join(line + b"\n" for line in lines)
    last = json.loads(lines[-1]) if lines else {}
    manifest = {
        "type": "artifact",
        "kind": KIND,
        "producer": {"store": SID, "host": "trainer-7"},
        "inputs": {"previous": previous} if previous else {},
        "meta": {"first_seq": 0, "last_seq": last.get("seq"), "events": len(lines)},
        "layout": "file",
        "content": store.put_bytes(data),
        "size": len(data),
    }
    manifest.update(changes)
    return store.put_json(manifest)


@pytest.fixture
def bare_store(tmp_path: Path) -> Store:
    s, _ = Store.init(tmp_path / "store")
    yield s
    s.close()


def test_a_pulled_log_chain_across_segments_is_read_whole_and_names_its_host(bare_store):
    """check_chain: the clean case the other tests below break one thing in (three segments, six events)."""
    from artifacts.remotes.logchain import check_chain

    lines = log_lines(6)
    one = put_segment(bare_store, lines[:2], meta={"first_seq": 0, "last_seq": 1, "events": 2})
    two = put_segment(bare_store, lines[2:5], one, meta={"first_seq": 2, "last_seq": 4, "events": 3})
    three = put_segment(bare_store, lines[5:], two, meta={"first_seq": 5, "last_seq": 5, "events": 1})
    chain = check_chain(bare_store, SID, three)
    assert (chain.ok, chain.problems, chain.segments, chain.host) == (True, [], 3, "trainer-7")
    assert [e["seq"] for e in chain.events] == [0, 1, 2, 3, 4, 5]


def test_a_log_chain_whose_head_segment_is_missing_says_which_with_no_host(bare_store):
    """check_chain 9, 10 (the missing segment's line), 54 (no segment read: the host is "")."""
    from artifacts.remotes.logchain import check_chain

    gone = hash_bytes(b"a segment this store never received")
    chain = check_chain(bare_store, SID, gone)
    assert chain.problems == [f"segment {gone[:12]}: object {gone[:12]} is missing from the store"]
    assert (chain.segments, chain.events, chain.host) == (0, [], "")
    assert chain.summary()["host"] == "" and chain.summary()["ok"] is False


@pytest.mark.parametrize("wrong", [{"kind": "file"}, {"type": "run"}])
def test_a_log_chain_that_reaches_an_object_that_is_no_log_segment_keeps_what_it_read(bare_store, wrong):
    """check_chain 12 (only a wrong kind *and* type refused), 23, 24 (the line), 25 (the walk gives up
    with nothing instead of checking the segments after it)."""
    from artifacts.remotes.logchain import check_chain

    lines = log_lines(3)
    stranger = put_segment(bare_store, log_lines(1), **wrong)
    head = put_segment(bare_store, lines, stranger)
    chain = check_chain(bare_store, SID, head)
    assert chain.problems == [f"segment {stranger[:12]} is not an audit-log segment"]
    assert chain.segments == 1 and [e["seq"] for e in chain.events] == [0, 1, 2]


def test_a_log_segment_without_its_lines_says_which_segment_and_stops(bare_store):
    """check_chain 61, 62 (the line naming the segment whose content is missing)."""
    from artifacts.remotes.logchain import check_chain

    lines = log_lines(2)
    lost = hash_bytes(b"lines never received")
    head = put_segment(bare_store, lines, content=lost)
    chain = check_chain(bare_store, SID, head)
    assert chain.problems == [f"segment {head[:12]}: object {lost[:12]} is missing from the store"]
    assert (chain.segments, chain.events) == (1, [])


def test_a_log_segment_line_that_is_not_json_is_named_by_its_line_number(bare_store):
    """check_chain 72–75 (the line: segment, 1-based line number)."""
    from artifacts.remotes.logchain import check_chain

    lines = log_lines(3)
    head = put_segment(bare_store, [lines[0], b'{"seq": 1, "ev', lines[2]])
    chain = check_chain(bare_store, SID, head)
    assert chain.problems == [f"segment {head[:12]} line 2: not valid JSON"]
    assert [e["seq"] for e in chain.events] == [0]


def test_a_changed_log_line_breaks_the_chain_at_the_line_after_it_in_one_exact_line(bare_store):
    """check_chain 81–88 (the broken-chain line: segment, line number, the event's seq, the reason)."""
    from artifacts.remotes.logchain import check_chain

    lines = log_lines(3)
    lines[0] = lines[0].replace(b'"note"', b'"edit"')
    head = put_segment(bare_store, lines)
    chain = check_chain(bare_store, SID, head)
    assert chain.problems == [
        f"segment {head[:12]} line 2 (seq 1): hash chain broken — a line before it was changed, removed or never sent"
    ]
    assert len(chain.events) == 3


def test_a_log_line_with_a_wrong_seq_is_reported_once_and_counting_goes_on_from_it(bare_store):
    """check_chain 93–99 (the seq line), 104 (counting does not resume from the line's own seq: the line
    after it is reported too), 105 (a line with no seq: a traceback, not a problem)."""
    from artifacts.hashing import canonical_json
    from artifacts.remotes.logchain import check_chain

    lines = log_lines(1)
    for seq in (5, 6, None, 1):
        lines.append(canonical_json({"seq": seq, "event": "note", "prev": hash_bytes(lines[-1])}))
    head = put_segment(bare_store, lines)
    chain = check_chain(bare_store, SID, head)
    assert chain.problems == [
        f"segment {head[:12]} line 2: seq 5, expected 1",
        f"segment {head[:12]} line 4: seq None, expected 7",
        f"segment {head[:12]} line 5: seq 1, expected 8",
    ]


@pytest.mark.parametrize("meta", [{"events": 2, "last_seq": 2}, {"events": 3, "last_seq": 1}])
def test_a_log_segment_whose_manifest_miscounts_its_lines_is_reported(bare_store, meta):
    """check_chain 111 (only both counts wrong reported), 125, 126 (the line)."""
    from artifacts.remotes.logchain import check_chain

    head = put_segment(bare_store, log_lines(3), meta=meta)
    chain = check_chain(bare_store, SID, head)
    assert chain.problems == [f"segment {head[:12]}: its manifest's counts do not match its lines"]


@pytest.mark.parametrize("producer", [{"store": SID}, None])
def test_a_log_chain_whose_producer_names_no_host_has_an_empty_host(bare_store, producer):
    """check_chain 41, 43, 53 (a missing host shown as "None" or "XXXX", not "")."""
    from artifacts.remotes.logchain import check_chain

    chain = check_chain(bare_store, SID, put_segment(bare_store, log_lines(2), producer=producer))
    assert chain.ok and chain.host == "" and chain.summary()["host"] == ""


def test_a_log_chain_longer_than_the_bound_is_read_only_to_it_and_not_ok(bare_store, monkeypatch):
    """check_chain 6 (one segment past MAX_SEGMENTS read): the newest MAX_SEGMENTS segments only, and the
    chain is not ok, since the first read no longer starts from the beginning."""
    import artifacts.remotes.logchain
    from artifacts.remotes.logchain import check_chain

    monkeypatch.setattr(artifacts.remotes.logchain, "MAX_SEGMENTS", 2)
    lines = log_lines(3)
    head = None
    for seq, line in enumerate(lines):
        head = put_segment(bare_store, [line], head, meta={"first_seq": seq, "last_seq": seq, "events": 1})
    chain = check_chain(bare_store, SID, head)
    assert chain.segments == 2 and [e["seq"] for e in chain.events] == [1, 2]
    assert chain.problems[0].startswith("segment ") and "line 1 (seq 1): hash chain broken" in chain.problems[0]


# ----------------------------------------------------------------------------- auditlog.iter_events
def test_reading_an_audit_log_that_cannot_be_opened_is_one_line_naming_it(bare_store):
    """auditlog.iter_events 8 (the message lost), 9 (a traceback instead of the reason)."""
    from artifacts.auditlog import iter_events
    from artifacts.errors import path_text

    bare_store.log_path.unlink(missing_ok=True)
    bare_store.log_path.mkdir()
    with pytest.raises(StoreError) as exc:
        list(iter_events(bare_store))
    assert str(exc.value) == f"cannot read the audit log: {path_text(str(bare_store.log_path))}: Is a directory"


def test_an_audit_log_line_with_bytes_that_are_not_text_is_one_damaged_line(bare_store):
    """auditlog.iter_events 5 (the log read as text: a traceback at the byte, or a carriage return taken
    for a line end)."""
    from artifacts.auditlog import iter_events

    lines = log_lines(2)
    bare_store.log_path.write_bytes(lines[0] + b"\n" + b"\xff\xfe torn\r write\n" + lines[1] + b"\n")
    events = list(iter_events(bare_store))
    assert events == [
        json.loads(lines[0]),
        {"seq": None, "event": "damaged-line", "line": 2},
        json.loads(lines[1]),
    ]


# ----------------------------------------------------------------------------- provenance
def test_an_artifact_the_logs_never_mention_has_empty_provenance():
    """provenance.provenance 14, 16 (a traceback for a format-2 artifact not in the index)."""
    from artifacts.provenance import provenance

    oid = hash_bytes(b"pulled without its log")
    assert provenance({"type": "artifact", "kind": "file"}, {}, oid) == {}
    assert provenance({"type": "artifact"}, {oid: {"host": "h"}}, oid) == {"host": "h"}


def test_an_artifacts_provenance_is_its_first_writing_event_and_only_artifacts_are_indexed(bare_store):
    """provenance.provenance_index 13 (a later event for the same id overwrites the first; other events
    indexed under None)."""
    from artifacts.auditlog import append_event
    from artifacts.provenance import provenance_index

    oid = hash_bytes(b"written twice")
    append_event(bare_store, "note", text="not a write")
    first = append_event(bare_store, "artifact-written", artifact=oid, kind="file", source="first.bin")
    append_event(bare_store, "artifact-written", artifact=oid, kind="file", source="second.bin")
    index = provenance_index(bare_store)
    assert set(index) == {oid}
    assert index[oid] == {"created": first["ts"], "source": "first.bin", "host": first["host"]}


# ----------------------------------------------------------------------------- remotes.pointers.forget_bases
def test_forgetting_merge_bases_waits_for_another_operation_on_the_same_remote(bare_store):
    """pointers.forget_bases 10 (another lock than the remote's: bases rewritten under a running push)."""
    from artifacts.locks import store_lock
    from artifacts.remotes.pointers import forget_bases, merge_bases, record_bases

    record_bases(bare_store, "nas", {"team/a": "a" * 64, "team/b": "b" * 64})
    with store_lock(bare_store.locks_dir, "remote-nas"):
        t = threading.Thread(target=forget_bases, args=(bare_store, "nas", ["team/a"]))
        t.start()
        t.join(0.5)
        assert t.is_alive()
        assert merge_bases(bare_store, "nas") == {"team/a": "a" * 64, "team/b": "b" * 64}
    t.join(10)
    assert not t.is_alive() and merge_bases(bare_store, "nas") == {"team/b": "b" * 64}


# ----------------------------------------------------------------------------- remotes.s3._botocore_code
def test_a_botocore_error_without_a_code_is_shown_without_one():
    """s3._botocore_code 24 (a made-up code before botocore's line)."""
    from botocore.exceptions import ClientError

    exc = ClientError({"Error": {"Message": "Slow Down"}}, "PutObject")
    assert explained(exc) == (
        "remote origin (s3://b/p): An error occurred (Unknown) when calling the PutObject operation: Slow Down"
    )


# ----------------------------------------------------------------------------- remotes.lazy.add_promised
P_A, P_B, P_C = ("a" * 64, "b" * 64, "c" * 64)


def test_overlapping_partial_pulls_note_each_promised_object_once(bare_store, tmp_path):
    """lazy.add_promised 20 (what was noted already is noted again: remote remove miscounts), 22 (a second
    partial pull from the same remote a traceback)."""
    from artifacts.remotes.config import add_remote
    from artifacts.remotes.forget import forget_remote
    from artifacts.remotes.lazy import add_promised, promised_path

    (tmp_path / "remote").mkdir(exist_ok=True)
    add_remote(bare_store, "nas", str(tmp_path / "remote"))
    add_promised(bare_store, "nas", [P_B, P_A])
    add_promised(bare_store, "nas", [P_C, P_B])  # a later pull --only leaves P_B there again
    assert promised_path(bare_store, "nas").read_text() == f"{P_A}\n{P_B}\n{P_C}\n"
    with pytest.raises(StoreError) as exc:
        forget_remote(bare_store, "nas")
    assert str(exc.value) == (
        f"remote nas still holds 3 object(s) this partial clone left there (e.g. {P_A[:12]}); "
        "pull them first, or remove --force"
    )


def test_noting_promised_objects_waits_for_another_process_noting_them(bare_store):
    """lazy.add_promised 14, 17, 18 (another lock than locks/promised.lock: two partial pulls append at once)."""
    from artifacts.locks import store_lock
    from artifacts.remotes.lazy import add_promised, promised_path

    with store_lock(bare_store.locks_dir, "promised"):
        t = threading.Thread(target=add_promised, args=(bare_store, "nas", [P_A]))
        t.start()
        t.join(0.5)
        assert t.is_alive()
        assert not promised_path(bare_store, "nas").exists()
    t.join(10)
    assert not t.is_alive() and promised_path(bare_store, "nas").read_text() == f"{P_A}\n"
    assert bare_store.is_promised(P_A)


def test_the_promised_list_is_a_data_file_others_may_read_but_nobody_runs(bare_store):
    """lazy.add_promised 33 (created 0o777 less the umask: executable), 36 (0o645: others may execute it)."""
    import os

    from artifacts.remotes.lazy import add_promised, promised_path

    old = os.umask(0o022)
    try:
        add_promised(bare_store, "nas", [P_A])
    finally:
        os.umask(old)
    assert promised_path(bare_store, "nas").stat().st_mode & 0o777 == 0o644


def test_a_directory_remote_lacking_an_object_names_itself_and_the_key(tmp_path):
    """A pull that meets an object the remote lost stops on this line (MissingOnRemote is a StoreError);
    the object that is there downloads whole with its id and size, without a warning. Kills
    DirBackend.download_to 18 (the message None) and 10 (line buffering asked of a binary file, which Python
    refuses with a RuntimeWarning on every object)."""
    from artifacts.remotes.backends import MissingOnRemote, object_key

    b = dir_backend(tmp_path / "remote")
    data = b"an object's bytes"
    oid = hash_bytes(data)
    (tmp_path / "remote" / object_key(oid)).parent.mkdir(parents=True)
    (tmp_path / "remote" / object_key(oid)).write_bytes(data)
    missing = object_key(hash_bytes(b"never pushed"))
    with (tmp_path / "download").open("wb") as out:
        with pytest.raises(MissingOnRemote) as raised:
            b.download_to(missing, out.fileno())
        assert str(raised.value) == f"{b.describe()}: lacks {missing}"
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            assert b.download_to(object_key(oid), out.fileno()) == (oid, len(data))
    assert (tmp_path / "download").read_bytes() == data


# ============================================================================= round 9 batch V
# ----------------------------------------------------------------------------- remotes.check.verify_remote
def overwrite(path: Path, data: bytes) -> None:
    """Damage a (read-only) object file in place."""
    path.chmod(0o644)
    path.write_bytes(data)


def put_on_remote(remote: Path, data: bytes) -> str:
    """An object the remote holds under its right id, that no push sent."""
    from artifacts.remotes.backends import object_key

    oid = hash_bytes(data)
    (remote / object_key(oid)).parent.mkdir(parents=True, exist_ok=True)
    (remote / object_key(oid)).write_bytes(data)
    return oid


def remote_bytes(remote: Path) -> int:
    return sum(p.stat().st_size for p in (remote / "objects").rglob("*") if p.is_file())


def test_verify_remote_of_an_empty_directory_refuses_and_leaves_it_empty(tmp_path):
    """remotes.check.verify_remote 21 (create=True: verify would make the directory a remote)."""
    from artifacts.remotes.check import verify_remote
    from artifacts.remotes.config import add_remote

    store, _ = Store.init(tmp_path / "store")
    remote = tmp_path / "remote"
    remote.mkdir()
    add_remote(store, "nas", str(remote))
    with pytest.raises(StoreError) as exc:
        verify_remote(store, "nas")
    assert str(exc.value) == f"remote nas ({remote}) holds no accrue store yet (push to it first)"
    assert list(remote.iterdir()) == []
    store.close()


def test_verify_remote_names_a_lost_or_short_object_and_the_manifest_that_names_it(tmp_path):
    """remotes.check.verify_remote 58, 68 (13 characters of the id), 69 (the short object's id None in
    damaged), 97-101 (the naming manifest's type and 12-character id lost)."""
    from artifacts.refs import read_ref
    from artifacts.remotes.backends import object_key
    from artifacts.remotes.check import verify_remote

    store, remote, contents = pushed_store(tmp_path)
    a, b = contents["a"], contents["b"]
    ma, mb = read_ref(store, "team/a"), read_ref(store, "team/b")
    lose_on_remote(remote, [a])
    overwrite(remote / object_key(b), b"short")
    report = verify_remote(store, "nas")
    assert report.problems == [
        f"remote object {b[:12]} has size 5, expected 200 (named by artifact {mb[:12]})",
        f"remote nas lacks object {a[:12]} (named by artifact {ma[:12]})",
    ]
    assert report.damaged == [b, a]
    store.close()


def test_verify_remote_reports_a_corrupt_local_manifest_once_and_walks_the_other_refs(tmp_path):
    """remotes.check.verify_remote 75, 78 (the store's copy read unverified), 91 (None in damaged),
    93 (a StoreError shown as "not a manifest"), 96 (the walk stops at the first bad manifest)."""
    from artifacts.refs import read_ref
    from artifacts.remotes.check import verify_remote

    store, remote, contents = pushed_store(tmp_path)
    whole = verify_remote(store, "nas").reachable
    me = read_ref(store, "team/e")  # walked right after the log: team/b and team/a are still to come
    manifest = store.read_json(me)
    overwrite(store.object_path(me), json.dumps({**manifest, "size": 1}).encode())
    lose_on_remote(remote, [contents["a"]])
    report = verify_remote(store, "nas")
    assert report.problems == [
        f"object {me[:12]} is corrupt (its bytes no longer match its id); run `accrue verify --full` "
        "(named by ref team/e)",
        f"remote nas lacks object {contents['a'][:12]} (named by artifact {read_ref(store, 'team/a')[:12]})",
    ]
    assert report.damaged == [me, contents["a"]]
    assert report.reachable == whole - 1  # all but team/e's content, which only its manifest names
    store.close()


def test_verify_remote_reports_a_ref_to_an_object_that_is_no_manifest(tmp_path):
    """remotes.check.verify_remote 87 (children told no id: a traceback), 91 (None in damaged), 94 (the
    JSON error's own text shown), 95 (13 characters of the id)."""
    from artifacts.remotes.check import verify_remote

    store, remote, contents = pushed_store(tmp_path)
    mystery = put_on_remote(remote, b'{"type": "mystery"}')
    (remote / "refs" / "team" / "b").write_text(contents["a"] + "\n")  # data, not JSON
    (remote / "refs" / "team" / "e").write_text(mystery + "\n")  # JSON of no manifest type
    report = verify_remote(store, "nas")
    assert report.problems == [
        f"object {mystery[:12]} is not a manifest (named by ref team/e)",
        f"remote object {contents['a'][:12]} is not a manifest (named by ref team/b)",
    ]
    assert report.damaged == [mystery, contents["a"]]
    store.close()


def test_verify_remote_full_rehashes_every_reachable_object_on_the_callers_meter(tmp_path):
    """remotes.check.verify_remote 113 (the meter told no byte total), 131 (advanced by None), 153
    (bytes_hashed None)."""
    from artifacts.remotes.check import verify_remote

    store, remote, _ = pushed_store(tmp_path)
    total = remote_bytes(remote)
    meter = RecordingMeter()
    report = verify_remote(store, "nas", full=True, jobs=2, meter=meter)
    assert report.ok and report.bytes_hashed == total
    assert meter.starts == [("re-hashing nas", report.reachable, total)]
    assert sum(meter.advanced) == total
    store.close()


def test_verify_remote_full_adds_corrupt_and_vanished_objects_to_the_walks_problems(tmp_path):
    """remotes.check.verify_remote 130, 135 (13 characters of the id), 143 (the walk's problems
    replaced by the re-hash's)."""
    from artifacts.refs import read_ref
    from artifacts.remotes.backends import object_key
    from artifacts.remotes.check import verify_remote

    store, remote, contents = pushed_store(tmp_path)
    a, b, e = contents["a"], contents["b"], contents["e"]
    lose_on_remote(remote, [b])
    overwrite(remote / object_key(a), b"A" * 500)  # the right size: only re-hashing tells

    class VanishingMeter(RecordingMeter):
        def start(self, what: str, objects: int, nbytes: int) -> None:
            super().start(what, objects, nbytes)
            lose_on_remote(remote, [e])  # gone after the listing, before its download

    report = verify_remote(store, "nas", full=True, jobs=1, meter=VanishingMeter())
    later = {
        a: f"remote object {a[:12]} is corrupt (its bytes do not hash to its id)",
        e: f"remote nas lacks object {e[:12]}",
    }
    assert report.problems == [
        f"remote nas lacks object {b[:12]} (named by artifact {read_ref(store, 'team/b')[:12]})",
        *[later[o] for o in sorted(later)],
    ]
    assert sorted(report.damaged[1:]) == sorted([a, e]) and report.damaged[0] == b
    store.close()


NOT_MANIFESTS = {
    "a list": b"[1]",
    "an artifact without content": b'{"type": "artifact"}',
    "a tree entry that is a number": b'{"type": "tree", "entries": [1]}',
    "a tree entry whose id is a number": b'{"type": "tree", "entries": [{"id": 7, "size": 1}]}',
    "an artifact whose size is text": b'{"type": "artifact", "layout": "file", "content": "' + b"a" * 64 + b'", '
    b'"size": "200"}',
    "a step record whose inputs are a list": b'{"type": "step-record", "inputs": ["x"]}',
}


@pytest.mark.parametrize("data", NOT_MANIFESTS.values(), ids=NOT_MANIFESTS.keys())
def test_a_remote_ref_to_json_of_no_manifests_shape_is_one_problem_for_verify_and_one_error_for_fetch(tmp_path, data):
    """A found bug (round 9): a remote ref naming JSON that hashes right but is shaped like no manifest
    was a traceback from closure.children (now artifacts.links) (AttributeError, KeyError, TypeError) in `verify --remote`
    and in fetch. A remote's objects are anyone's bytes: now one problem line, and fetch refuses in one
    line and keeps what the store had."""
    from artifacts.refs import read_ref
    from artifacts.remotes.check import verify_remote
    from artifacts.remotes.pull import fetch

    store, remote, _ = pushed_store(tmp_path)
    odd = put_on_remote(remote, data)
    (remote / "refs" / "team" / "e").write_text(odd + "\n")
    report = verify_remote(store, "nas")
    assert report.problems == [f"object {odd[:12]} is not a manifest (named by ref team/e)"]
    assert report.damaged == [odd]
    before = read_ref(store, "remotes/nas/team/e")
    with pytest.raises(StoreError) as exc:
        fetch(store, "nas")
    assert f"object {odd[:12]} is not a manifest" in str(exc.value)
    assert "\n" not in str(exc.value)
    assert read_ref(store, "remotes/nas/team/e") == before
    store.close()


# ============================================================================= round 9 batch Y
# ----------------------------------------------------------------------------- remotes.config._copied
COPIED = (
    "this store's id {} was made in another directory (a copy, e.g. cp -a?); "
    "run `accrue remote rekey` to give this copy its own id"
)


def keyed_store(root: Path) -> tuple[Store, str]:
    """A store whose id was made (with its directory recorded) in root."""
    from artifacts.remotes.config import store_id

    store, _ = Store.init(root)
    return store, store_id(store)


def test_a_store_with_the_old_inode_marker_keeps_its_id_in_place_and_is_refused_elsewhere(tmp_path):
    """config._copied 1 (the inode test inverted), 2, 3 (a KeyError): a store_home written by an older
    accrue is the directory's inode alone; the same inode is this store, another one a copy."""
    from artifacts.remotes.config import check_not_copied, store_id

    store, sid = keyed_store(tmp_path / "store")
    ino = (tmp_path / "store").stat().st_ino
    store.update_config(lambda c: c.update(store_home=ino))
    assert check_not_copied(store) == sid and store_id(store) == sid
    store.update_config(lambda c: c.update(store_home=ino + 1))
    with pytest.raises(StoreError) as exc:
        store_id(store)
    assert str(exc.value) == COPIED.format(sid[:12])
    store.close()


@pytest.mark.parametrize("home", ["/somewhere/else", ["/somewhere/else", 1]], ids=["text", "list"])
def test_a_store_home_of_no_known_shape_is_not_taken_for_a_copy(tmp_path, home):
    """config._copied 5: a store_home that is neither an inode nor a {path, ino} record (a hand-edited
    config) proves nothing, so the store keeps its id and is not refused."""
    from artifacts.remotes.config import check_not_copied, store_id

    store, sid = keyed_store(tmp_path / "store")
    store.update_config(lambda c: c.update(store_home=home))
    assert check_not_copied(store) == sid and store_id(store) == sid
    store.close()


def test_a_store_put_back_at_its_path_with_a_new_inode_keeps_its_id_while_a_copy_is_refused(tmp_path):
    """config._copied 7, 8, 9 (the recorded path never read: a new inode alone taken for a copy). A copy
    elsewhere (both changed) is refused; a store moved away and back (same inode) and a store restored in
    place (copied aside, the original removed, the copy renamed back: the path it was keyed in, another
    inode, as after a remount on some overlay filesystems) keep their id. Every directory is made while
    the ones before it still exist, so no inode number is reused."""
    import shutil

    from artifacts.remotes.config import store_id

    root = tmp_path / "store"
    store, sid = keyed_store(root)
    store.close()
    shutil.copytree(root, tmp_path / "copy", symlinks=True)
    copy = Store.open(tmp_path / "copy")
    with pytest.raises(StoreError) as exc:
        store_id(copy)
    assert str(exc.value) == COPIED.format(sid[:12])
    copy.close()
    root.rename(tmp_path / "moved")
    moved = Store.open(tmp_path / "moved")
    assert store_id(moved) == sid
    moved.close()
    (tmp_path / "moved").rename(root)
    shutil.copytree(root, tmp_path / "aside", symlinks=True)
    shutil.rmtree(root)
    (tmp_path / "aside").rename(root)
    assert store.read_config()["store_home"]["ino"] != root.stat().st_ino
    restored = Store.open(root)
    assert store_id(restored) == sid
    restored.close()


# ----------------------------------------------------------------------------- remotes.directory listings
def test_a_directory_remote_lists_sizes_under_any_prefix_like_every_backend(tmp_path):
    """DirBackend.list_sizes 3 (the objects-only fast path taken for other prefixes), 12 (a traceback):
    list_sizes(prefix) is the Backend contract (S3Backend honours it for any prefix; probe lists
    "refs"): the refs' sizes, not the objects'; objects/ still lists every object."""
    from artifacts.remotes.backends import OBJECTS, object_key

    root = tmp_path / "remote"
    b = dir_backend(root)
    b.swap("refs/team/a", b"x" * 65 + b"\n", None)
    b.swap("refs/team/sub/b", b"yz", None)
    data = b"an object's bytes"
    oid = hash_bytes(data)
    (root / object_key(oid)).parent.mkdir(parents=True)
    (root / object_key(oid)).write_bytes(data)
    assert b.list_sizes("refs") == {"refs/team/a": 66, "refs/team/sub/b": 2}
    assert b.list_sizes(OBJECTS) == {object_key(oid): len(data)}
    assert b.list_sizes("logs") == {}


def test_listing_a_directory_remote_whose_disk_is_not_mounted_is_one_line(tmp_path):
    """DirBackend.list_sizes 2 (the message None)."""
    from artifacts.remotes.backends import OBJECTS

    b = DirBackend(parse_url("nas", str(tmp_path / "unmounted")))
    for prefix in (OBJECTS, "refs"):
        with pytest.raises(StoreError) as exc:
            b.list_sizes(prefix)
        assert (
            str(exc.value)
            == f"remote nas ({tmp_path / 'unmounted'}): the directory does not exist (is the disk mounted?)"
        )


def test_a_remote_ref_file_that_is_not_utf8_is_a_damaged_ref_line_not_a_traceback(tmp_path):
    """DirBackend.list_versions 1 (UnicodeDecodeError), 2, 3 (LookupError: no such error handler): a ref
    file with bytes that are not UTF-8 is listed with U+FFFD in their place, and a fetch names it as
    damaged in one line."""
    from artifacts.remotes.pull import fetch

    store, remote, _ = pushed_store(tmp_path)
    (remote / "refs" / "team" / "bad").write_bytes(b"\xff\xfe not utf-8\n")
    shown = "\ufffd\ufffd not utf-8"  # each byte that is not UTF-8 replaced
    versions = DirBackend(parse_url("nas", str(remote))).list_versions("refs")
    assert versions["refs/team/bad"] == shown + "\n"
    with pytest.raises(StoreError) as exc:
        fetch(store, "nas")
    assert str(exc.value) == (f"remote nas ({remote}): refs/team/bad is damaged (holds {shown!r}, not an id)")
    store.close()


# ----------------------------------------------------------------------------- remotes.directory.remove
def test_removing_a_key_that_is_a_directory_names_the_remote_key_and_reason(tmp_path):
    """DirBackend.remove 2 (the message None), 3 (the OSError's repr instead of its reason); a key that is
    not there is removed quietly."""
    root = tmp_path / "remote"
    b = dir_backend(root)
    b.swap("refs/team/a", b"one\n", None)
    b.remove("refs/team/never")
    with pytest.raises(StoreError) as exc:
        b.remove("refs/team")
    assert str(exc.value) == f"remote nas ({root}): cannot remove refs/team: Is a directory"
    assert b.get_bytes("refs/team/a") == b"one\n"


# ============================================================================= round 9 batch Z
# ----------------------------------------------------------------------------- remotes.directory.put_bytes
def test_a_small_write_to_a_directory_remote_is_made_in_tmp_where_unfinished_uploads_finds_it(tmp_path, monkeypatch):
    """DirBackend._write_new 3, 4 (the temp file written outside tmp/: a killed push's leftover would never be
    listed by unfinished_uploads, so `remote prune` could not drop it). While the bytes are written the
    one write in progress is listed under tmp/; once done, the key holds them and tmp/ holds nothing."""
    import os
    import re

    import artifacts.remotes.directory as directory

    b = dir_backend(tmp_path / "remote")
    seen: list[list[str]] = []
    real = directory.write_new_fsynced

    def write_and_look(path: Path, data: bytes) -> None:
        real(path, data)
        seen.append([what for what, _started, _handle in b.unfinished_uploads()])

    monkeypatch.setattr(directory, "write_new_fsynced", write_and_look)
    b.put_bytes("push-leases/abc", b"a lease\n")
    assert len(seen) == 1 and len(seen[0]) == 1
    assert re.fullmatch(rf"tmp/\.tmp-{os.getpid()}-[0-9a-f]{{12}}", seen[0][0])
    assert b.get_bytes("push-leases/abc") == b"a lease\n"
    assert b.unfinished_uploads() == []


def test_a_small_write_a_directory_remote_refuses_names_the_remote_key_and_reason(tmp_path):
    """DirBackend.put_bytes 6 (the message None); and the temp file of the refused write is gone, not left
    in tmp/ for `remote prune` to drop a day later."""
    root = tmp_path / "remote"
    b = dir_backend(root)
    (root / "push-leases").write_text("a file where the leases' folder should be")
    with pytest.raises(StoreError) as exc:
        b.put_bytes("push-leases/abc", b"a lease\n")
    assert str(exc.value) == f"remote nas ({root}): cannot write push-leases/abc: File exists"
    assert list((root / "tmp").iterdir()) == []  # its temp file went with it


def test_a_small_write_refused_before_its_temp_file_exists_names_the_refusal_not_a_missing_file(tmp_path, monkeypatch):
    """DirBackend._write_new 27, 28 (the cleanup's `missing_ok` None or False: when the write fails before
    the temp file exists, e.g. a full disk at open, removing the absent temp file raises FileNotFoundError
    over the real error, and the user reads "No such file or directory" instead of why the write failed)."""
    import errno

    import artifacts.remotes.directory as directory

    def disk_full(path: Path, data: bytes) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    root = tmp_path / "remote"
    b = dir_backend(root)
    monkeypatch.setattr(directory, "write_new_fsynced", disk_full)
    with pytest.raises(StoreError) as exc:
        b.put_bytes("push-leases/abc", b"a lease\n")
    assert str(exc.value) == f"remote nas ({root}): cannot write push-leases/abc: No space left on device"
    assert list((root / "tmp").iterdir()) == []


# ----------------------------------------------------------------------------- remotes.directory.upload_object
def local_object(tmp_path: Path, data: bytes) -> tuple[str, Path]:
    """A file holding data, and its content id."""
    path = tmp_path / "local-object"
    path.write_bytes(data)
    return hash_bytes(data), path


def test_an_object_upload_is_made_as_an_obj_temp_file_in_tmp_and_ends_read_only(tmp_path, monkeypatch):
    """DirBackend.upload_object 7, 8 (the temp file outside tmp/: unfinished_uploads, hence `remote prune`,
    would never see a killed push's leftover), 19, 21, 22, 23 (its name: prune reports it as tmp/.obj-tmp-…),
    30, 33 (made executable: rwxr-xr-x, rw-r--r-x), 42 (buffering=1 on a binary file: a RuntimeWarning on
    the user's terminal at every push), 60 (the object ends r--r--r-x, not read-only for everyone)."""
    import os
    import re
    import warnings

    import artifacts.remotes.directory as directory
    from artifacts.remotes.backends import object_key

    root = tmp_path / "remote"
    b = dir_backend(root)
    data = b"an object's bytes" * 100
    oid, path = local_object(tmp_path, data)
    seen: list[list[tuple[str, int]]] = []
    real = directory.copy_hashing

    def copy_and_look(src, fd: int, *hint) -> tuple[str, int]:
        got = real(src, fd, *hint)
        seen.append([(w, (root / w).stat().st_mode & 0o777) for w, _s, _h in b.unfinished_uploads()])
        return got

    monkeypatch.setattr(directory, "copy_hashing", copy_and_look)
    old = os.umask(0o022)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            b.upload_object(oid, path, len(data))
    finally:
        os.umask(old)
    assert [str(w.message) for w in caught] == []
    assert len(seen) == 1 and len(seen[0]) == 1
    what, mode = seen[0][0]
    assert re.fullmatch(rf"tmp/\.obj-tmp-{os.getpid()}-[0-9a-f]{{12}}", what)
    assert mode == 0o644
    assert (root / object_key(oid)).read_bytes() == data
    assert (root / object_key(oid)).stat().st_mode & 0o777 == 0o444
    assert b.unfinished_uploads() == []


def test_an_object_upload_keeps_a_copy_already_there_unless_told_to_replace_it(tmp_path):
    """DirBackend.upload_object 1 (replace by default: a push would overwrite what the remote holds, which
    content addressing says is the same bytes, instead of linking beside it). Only repair's replace=True
    puts the verified bytes in place of a damaged copy."""
    from artifacts.remotes.backends import object_key

    root = tmp_path / "remote"
    b = dir_backend(root)
    data = b"the object's true bytes"
    oid, path = local_object(tmp_path, data)
    there = root / object_key(oid)
    there.parent.mkdir(parents=True)
    there.write_bytes(b"a damaged copy")
    b.upload_object(oid, path, len(data))
    assert there.read_bytes() == b"a damaged copy"
    b.upload_object(oid, path, len(data), replace=True)
    assert there.read_bytes() == data
    assert there.stat().st_mode & 0o777 == 0o444
    assert b.unfinished_uploads() == []


@pytest.mark.parametrize("blocked", ["tmp", "fan-out"])
def test_an_object_upload_the_remote_refuses_is_one_line_naming_the_object_and_leaves_nothing(tmp_path, blocked):
    """DirBackend.upload_object 15, 16 (tmp/ cannot be made: the message None, 13 characters of the id), 76,
    77 (the object's folder cannot be made: the same)."""
    from artifacts.remotes.backends import object_key

    root = tmp_path / "remote"
    b = dir_backend(root)
    data = b"an object's bytes"
    oid, path = local_object(tmp_path, data)
    where = root / "tmp" if blocked == "tmp" else (root / object_key(oid)).parent
    where.parent.mkdir(parents=True, exist_ok=True)
    where.write_text("a file where a folder should be")
    with pytest.raises(StoreError) as exc:
        b.upload_object(oid, path, len(data))
    assert str(exc.value) == f"remote nas ({root}): cannot write object {oid[:12]}: File exists"
    assert b.head(object_key(oid)) is None
    assert b.unfinished_uploads() == []


def test_repair_sends_every_object_back_to_a_remote_whose_objects_folder_was_deleted(tmp_path):
    """DirBackend.upload_object 61, 63, 65 (repair's replace mode makes only the last folder: a lost object's
    objects/blake3/ folder may be gone too, and repair failed with "No such file or directory"). What the
    store holds goes back; the pushed audit-log segment, which only the remote held, is reported unhealed."""
    import shutil

    from artifacts.refs import read_ref
    from artifacts.remotes.check import verify_remote
    from artifacts.remotes.config import store_id
    from artifacts.remotes.repair import repair_remote

    store, remote, contents = pushed_store(tmp_path)
    manifests = [read_ref(store, f"team/{name}") for name in ("a", "b", "e")]
    shutil.rmtree(remote / "objects")
    report = repair_remote(store, "nas")
    assert sorted(report.resent) == sorted([*contents.values(), *manifests])
    again = verify_remote(store, "nas")
    assert again.damaged == report.unhealed and len(report.unhealed) == 1
    assert again.problems == [
        f"remote nas lacks object {report.unhealed[0][:12]} (named by log of store {store_id(store)[:12]})"
    ]
    store.close()


# ----------------------------------------------------------------------------- remotes.stepindex.index_step_records
def committed_record(store: Store, n: int) -> tuple[str, dict]:
    """A committed step record, as a remote's ref names one, stored in `store`: (its id, its fields)."""
    record = {
        "type": "step-record",
        "state": "committed",
        "cache_key": hash_bytes(f"key {n}".encode()),
        "step": f"step-{n}",
        "inputs": {"data": hash_bytes(b"input")},
        "outputs": {"model": hash_bytes(f"output {n}".encode())},
        "config": {"lr": n},
        "code_version": "v1",
        "started": "2026-12-01T00:00:00Z",
        "finished": "2026-12-01T01:00:00Z",
        "host": "robot-pc",
        "workflow": "wf",
        "stage": n,
    }
    return store.put_json(record), record


def test_pulled_step_records_are_indexed_once_each_as_committed_attempts_and_logged(bare_store):
    """index_step_records 31 (stop at the first record already indexed), 33, 36, 38, 39, 41, 46–49, 51, 60,
    61 (an attempt with fields missing, None or misspelt), 66 (None returned for an id), 68, 69, 70 (the log
    event without its name, source or records). Each committed record the index lacks becomes one committed
    attempt of its key, with the record's own fields and where it came from; an id twice, a record already
    indexed, or data that is no record is passed over, and one event lists what was entered."""
    from artifacts.auditlog import iter_events
    from artifacts.records import list_attempts
    from artifacts.remotes.stepindex import index_step_records

    (one, rec1), (two, _), (three, rec3) = (committed_record(bare_store, n) for n in (1, 2, 3))
    data = bare_store.put_bytes(b"not a record")
    assert index_step_records(bare_store, [two], "origin") == [two]
    assert index_step_records(bare_store, [one, one, data, two, three], "origin") == [one, three]
    for oid, rec in ((one, rec1), (three, rec3)):
        [attempt] = list_attempts(bare_store, rec["cache_key"])
        attempt.pop("log_anchor")
        assert attempt == {
            **{f: rec[f] for f in ("inputs", "config", "code_version", "outputs", "started", "finished", "host")},
            **{"workflow": rec["workflow"], "stage": rec["stage"], "cache_key": rec["cache_key"]},
            **{"attempt": 1, "step": rec["step"], "state": "committed", "mode": "normal", "pid": None},
            **{"checkpoints": [], "resumed_from": None, "record_id": oid, "imported_from": "origin"},
        }
    events = [e for e in iter_events(bare_store) if e["event"] == "step-records-indexed"]
    assert [(e["source"], e["records"]) for e in events] == [("origin", [two]), ("origin", [one, three])]
    assert index_step_records(bare_store, [one, two, three], "origin") == []


def test_a_record_whose_step_runs_here_is_skipped_after_the_lock_wait_and_the_rest_indexed(bare_store, monkeypatch):
    """index_step_records 15 (a lock of another name: a record entered while its step runs here), 19 (stop at
    the first busy key), 18 (wait for the step forever). A step of that key running here (holding the
    runner's step lock) will commit its own attempt: the record is skipped after LOCK_WAIT_S, and the
    others are entered."""
    import threading

    import artifacts.remotes.stepindex as stepindex
    from artifacts.locks import store_lock

    monkeypatch.setattr(stepindex, "LOCK_WAIT_S", 0.2)
    (one, rec1), (three, _) = (committed_record(bare_store, n) for n in (1, 3))
    got: list[list[str]] = []
    with store_lock(bare_store.locks_dir, f"step-{rec1['cache_key']}"):
        worker = threading.Thread(
            target=lambda: got.append(stepindex.index_step_records(bare_store, [one, three], "origin")), daemon=True
        )
        worker.start()
        worker.join(10)
        assert not worker.is_alive(), "still waiting for the running step"
    assert got == [[three]]


def test_a_damaged_attempt_file_of_the_key_does_not_stop_a_record_being_indexed(bare_store):
    """index_step_records 27, 30 (list_attempts without a problems list: a damaged attempt file of the key
    makes the whole pull fail). The damaged file is passed over (verify reports it); the record is entered
    as the next attempt."""
    from artifacts.records import list_attempts
    from artifacts.remotes.stepindex import index_step_records

    one, rec1 = committed_record(bare_store, 1)
    key_dir = bare_store.records_dir / rec1["cache_key"]
    key_dir.mkdir(parents=True)
    (key_dir / "0001.json").write_text("{ torn")
    assert index_step_records(bare_store, [one], "origin") == [one]
    problems: list[str] = []
    [attempt] = list_attempts(bare_store, rec1["cache_key"], problems=problems)
    assert (attempt["attempt"], attempt["record_id"], len(problems)) == (2, one, 1)


def test_indexing_reads_only_records_the_store_holds_and_never_fetches_one(tmp_path, monkeypatch):
    """stepindex._step_record 1 (`and` for `or`: an id the store lacks is read anyway, and a partial clone
    fetches it from the remote just to index it). Only records already here are indexed; a record left on
    the remote (pull --only) stays there and out of the index until it is pulled."""
    from artifacts.remotes.stepindex import index_step_records

    monkeypatch.setattr(artifacts.store, "_MISSING_FETCHERS", [])
    store, _ = Store.init(tmp_path / "store")
    store.update_config(lambda c: c.setdefault("remotes", {}).update({"origin": {"url": "x", "promisor": True}}))
    elsewhere, _ = Store.init(tmp_path / "remote-side")
    oid, _ = committed_record(elsewhere, 1)
    asked: list[list[str]] = []

    def fetch(s: Store, missing: list[str]) -> bool:
        asked.append(list(missing))
        s.put_bytes(elsewhere.read_bytes(oid))
        return True

    add_missing_fetcher(fetch)
    assert index_step_records(store, [oid], "origin") == []
    assert (asked, store.has_object(oid)) == ([], False)
    store.close()
    elsewhere.close()


def test_an_object_over_manifest_max_is_never_read_as_a_step_record(bare_store, monkeypatch):
    """stepindex._step_record 4 (`and` for `or`: the size check never refuses, so every big object, a
    checkpoint of gigabytes, is read whole to see whether it is a record). An object over MANIFEST_MAX is
    data: not read, not indexed, even when its bytes would parse as a committed record."""
    import artifacts.remotes.stepindex as stepindex

    oid, _ = committed_record(bare_store, 1)
    monkeypatch.setattr(stepindex, "MANIFEST_MAX", bare_store.object_size(oid) - 1)
    assert stepindex.index_step_records(bare_store, [oid], "origin") == []
    monkeypatch.setattr(stepindex, "MANIFEST_MAX", bare_store.object_size(oid))
    assert stepindex.index_step_records(bare_store, [oid], "origin") == [oid]


@pytest.mark.parametrize(
    "change",
    [
        {"state": "running"},
        {"type": "artifact"},
        {"cache_key": "abc123"},
        {"outputs": ["model"]},
        "a JSON list",
    ],
)
def test_an_object_that_is_no_committed_step_record_is_passed_over(bare_store, change):
    """stepindex._step_record 10 (an uncommitted step record entered as a committed attempt), 11 (JSON that
    is no object: a traceback; a committed object of another type entered), 25 (a record with a short key,
    or outputs that are no mapping, entered: an attempt file under a key that is no key). Only a committed
    step record with a full cache key and a mapping of outputs becomes an attempt."""
    from artifacts.remotes.stepindex import index_step_records

    _, record = committed_record(bare_store, 1)
    oid = bare_store.put_json([record]) if change == "a JSON list" else bare_store.put_json({**record, **change})
    assert index_step_records(bare_store, [oid], "origin") == []
    assert not bare_store.records_dir.is_dir() or list(bare_store.records_dir.iterdir()) == []


# ----------------------------------------------------------------------------- remotes.pull (round 11)
def second_store(tmp_path: Path, remote: Path) -> Store:
    from artifacts.remotes.config import add_remote

    store, _ = Store.init(tmp_path / "second")
    add_remote(store, "nas", str(remote))
    return store


def test_pull_takes_only_the_refs_named_on_the_callers_jobs_and_meter(tmp_path):
    """fetch 12 (the report names no remote), pull 15 (the refs named not passed on: every ref pulled), 17 (jobs=1 not passed on: downloads on
    worker threads), 18, 24 (the caller's meter not passed on: a pull the CLI shows no progress of)."""
    from artifacts.refs import read_ref
    from artifacts.remotes.pull import pull

    first, remote, contents = pushed_store(tmp_path)
    second = second_store(tmp_path, remote)
    meter = RecordingMeter()
    report = pull(second, "nas", refs=["team/a", "team/b"], jobs=1, meter=meter)
    assert report.remote == "nas" and sorted(report.moved) == ["team/a", "team/b"]
    assert read_ref(second, "team/e") is None and not second.has_object(contents["e"])
    assert [s[0] for s in meter.starts] == ["pull ← nas"] and meter.starts[0][2] > 700
    assert meter.threads == {threading.main_thread().name} and 500 in meter.advanced and 200 in meter.advanced
    first.close()
    second.close()


def both_stores_move_team_a(tmp_path: Path) -> tuple[Store, Store, dict[str, str]]:
    """Two stores that agreed on the remote's team/a, then each moved it: the first pushed its move.
    Returns both stores and the ids: `last` (agreed), `theirs` (the remote's now), `mine` (the second's)."""
    from artifacts.refs import read_ref, set_ref
    from artifacts.remotes.pull import pull
    from artifacts.remotes.push import push

    first, remote, _ = pushed_store(tmp_path)
    second = second_store(tmp_path, remote)
    pull(second, "nas")
    ids = {"last": read_ref(first, "team/a"), "theirs": read_ref(first, "team/b"), "mine": read_ref(first, "team/e")}
    set_ref(first, "team/a", ids["theirs"])
    push(first, "nas")
    set_ref(second, "team/a", ids["mine"])
    return first, second, ids


def test_pull_without_force_leaves_a_ref_both_stores_moved_as_a_conflict_since_they_last_agreed(tmp_path):
    """pull 1 (force on by default: the remote's id taken and this store's put under displaced/), 69 (the
    conflict line says this store never saw the ref on the remote, not the id both last agreed on)."""
    from artifacts.refs import read_ref
    from artifacts.remotes.pull import pull

    first, second, ids = both_stores_move_team_a(tmp_path)
    report = pull(second, "nas")
    assert [c.split(":")[0] for c in report.conflicts] == ["ref team/a"]
    assert f"moved on both sides since {ids['last'][:12]}: this store has {ids['mine'][:12]}" in report.conflicts[0]
    assert report.displaced == {} and report.moved == {} and read_ref(second, "team/a") == ids["mine"]
    first.close()
    second.close()


def test_pull_with_force_reports_where_it_kept_this_stores_id(tmp_path):
    """pull 63 (the report's displaced ref None: `accrue pull --force` could not say where this store's id
    went)."""
    from artifacts.refs import read_ref
    from artifacts.remotes.pull import pull

    first, second, ids = both_stores_move_team_a(tmp_path)
    report = pull(second, "nas", force=True)
    kept = f"displaced/team/a/{ids['mine'][:12]}"
    assert report.displaced == {"team/a": kept} and report.moved == {"team/a": [ids["mine"], ids["theirs"]]}
    assert read_ref(second, kept) == ids["mine"] and read_ref(second, "team/a") == ids["theirs"]
    first.close()
    second.close()


# ----------------------------------------------------------------------------- remotes.transfer (round 11)
def test_pulled_objects_are_read_only_like_the_stores_own(tmp_path):
    """transfer._link_unsynced 7 (a pulled object left 0o445: executable by others, unlike what the store
    writes itself)."""
    from artifacts.remotes.pull import pull

    first, remote, contents = pushed_store(tmp_path)
    second = second_store(tmp_path, remote)
    pull(second, "nas")
    modes = {oid: second.object_path(oid).stat().st_mode & 0o777 for oid in contents.values()}
    assert modes == {oid: 0o444 for oid in contents.values()}
    assert {first.object_path(oid).stat().st_mode & 0o777 for oid in contents.values()} == {0o444}
    first.close()
    second.close()


def test_a_store_whose_objects_directory_was_deleted_pulls_its_objects_back(tmp_path):
    """transfer._link_unsynced 8, 10, 12 (the fan-out directory made without its parents: a store whose
    objects/ was deleted by hand to free space cannot take its objects back from the remote). As the
    store's own writes do, a pull makes the directories it needs."""
    import shutil

    from artifacts.remotes.pull import pull

    first, remote, contents = pushed_store(tmp_path)
    second = second_store(tmp_path, remote)
    pull(second, "nas")
    shutil.rmtree(second.objects_dir)
    assert not second.objects_dir.exists()
    pull(second, "nas")
    assert all(second.has_object(oid) for oid in contents.values())
    first.close()
    second.close()


def test_flush_dirs_syncs_each_new_directory_and_the_one_above_them(tmp_path, monkeypatch):
    """transfer.flush_dirs 9 (the objects directory above the new fan-out directories never synced: after a
    crash a new fan-out directory, with every object in it, can be gone). Nothing is synced for no
    directories."""
    import artifacts.remotes.transfer as transfer

    synced: list[Path] = []
    monkeypatch.setattr(transfer, "fsync_dir", synced.append)
    objects = tmp_path / "objects" / "blake3"
    transfer.flush_dirs({objects / "cd", objects / "ab"}, 1)
    assert synced == [objects / "ab", objects / "cd", objects]
    transfer.flush_dirs(set(), 1)
    assert synced == [objects / "ab", objects / "cd", objects]


def test_a_download_in_flight_is_a_dl_temp_file_of_this_process_and_none_is_left(tmp_path):
    """transfer.download_object 7 (the temp file unlabelled: `.Nonetmp-…`). A person looking into a busy
    store's tmp/ tells downloads from other writes by their `.dl-tmp-PID-` names; a corrupt attempt's file
    is removed like a good one's."""
    from artifacts.remotes.transfer import download_object

    first, remote, contents = pushed_store(tmp_path)
    second = second_store(tmp_path, remote)
    seen: list[list[str]] = []

    class Peeking(DirBackend):
        def download_to(self, key: str, fd: int) -> tuple[str, int]:
            seen.append(sorted(p.name for p in second.tmp_dir.iterdir()))
            return super().download_to(key, fd)

    backend = Peeking(parse_url("nas", str(remote)))
    assert download_object(second, backend, contents["a"], 500) == 500
    assert len(seen) == 1 and len(seen[0]) == 1 and seen[0][0].startswith(f".dl-tmp-{os.getpid()}-")
    lose_on_remote(remote, [contents["b"]])
    (remote / "objects" / "blake3" / contents["b"][:2] / contents["b"][2:]).write_bytes(b"damaged")
    with pytest.raises(StoreError):
        download_object(second, backend, contents["b"], 200)
    assert list(second.tmp_dir.iterdir()) == [] and second.has_object(contents["a"])
    first.close()
    second.close()


@pytest.mark.parametrize(
    "case, synced",
    [("good", 1), ("good, size unknown", 1), ("corrupt", 0), ("shorter than told", 0)],
)
def test_a_download_is_fsynced_before_it_is_linked_in_and_only_when_it_is_good(tmp_path, monkeypatch, case, synced):
    """transfer.download_object 29, 30, 31 (a good download, with or without a known size, linked in without
    its bytes on disk: a crash can leave an object file of zeros under a valid id), 28, 31 (a corrupt or short
    download synced on each attempt, for nothing), 55 (a short download called corrupt, not truncated)."""
    import stat

    from artifacts.remotes.transfer import download_object

    first, remote, contents = pushed_store(tmp_path)
    second = second_store(tmp_path, remote)
    oid, size = contents["a"], 500
    if case == "corrupt":
        (remote / "objects" / "blake3" / oid[:2] / oid[2:]).chmod(0o644)
        (remote / "objects" / "blake3" / oid[:2] / oid[2:]).write_bytes(b"x" * 500)
    files_synced: list[int] = []
    real_fsync = os.fsync

    def fsync(fd: int) -> None:
        if stat.S_ISREG(os.fstat(fd).st_mode):
            files_synced.append(fd)
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    told = {"good": size, "good, size unknown": None, "corrupt": size, "shorter than told": size + 1}[case]
    if synced:
        assert download_object(second, DirBackend(parse_url("nas", str(remote))), oid, told) == size
    else:
        with pytest.raises(StoreError) as refused:
            download_object(second, DirBackend(parse_url("nas", str(remote))), oid, told)
        why = "corrupt" if case == "corrupt" else "truncated (500 of 501 bytes)"
        assert f"object {oid[:12]} arrived {why} 3 times; refused" in str(refused.value)
    assert len(files_synced) == synced and second.has_object(oid) == bool(synced)
    first.close()
    second.close()


# ----------------------------------------------------------------------------- remotes.pull._remote_closure
def pushed_tree(tmp_path: Path) -> tuple[Store, Path, dict]:
    """A store with a directory artifact (ref team/dir) and a ref straight to its tree (team/tree), pushed
    to directory remote nas; returns the store, the remote's root and the tree manifest with its id."""
    from artifacts.ingest import add_path
    from artifacts.refs import read_ref, set_ref
    from artifacts.remotes.config import add_remote
    from artifacts.remotes.push import push

    store, _ = Store.init(tmp_path / "store")
    folder = tmp_path / "episodes"
    folder.mkdir()
    (folder / "x.bin").write_bytes(b"x" * 100)
    (folder / "y.bin").write_bytes(b"y" * 50)
    add_path(store, folder, "replay", ref="team/dir")
    tree_id = store.read_json(read_ref(store, "team/dir"))["content"]
    set_ref(store, "team/tree", tree_id)
    (tmp_path / "remote").mkdir(exist_ok=True)
    add_remote(store, "nas", str(tmp_path / "remote"))
    push(store, "nas")
    return store, tmp_path / "remote", {"id": tree_id, **store.read_json(tree_id)}


def test_a_ref_straight_to_a_tree_is_pulled_whole_without_only(tmp_path):
    """pull._remote_closure 4 (the refs' own manifests marked "leave behind": the files of a tree a ref
    names directly stay on the remote as promised objects, though no --only was given)."""
    from artifacts.remotes.pull import pull

    first, remote, tree = pushed_tree(tmp_path)
    second = second_store(tmp_path, remote)
    report = pull(second, "nas", refs=["team/tree"])
    assert report.promised == 0 and [second.has_object(e["id"]) for e in tree["entries"]] == [True, True]
    first.close()
    second.close()


def test_a_manifest_reached_on_two_paths_is_walked_once(tmp_path, monkeypatch):
    """pull._remote_closure 7 (what was walked is looked up by size instead of id: a manifest reached again
    one level down is walked again, and in a store of stages that each name the ones before, the walk
    grows with the number of paths, not of objects). The tree is a ref's target and its artifact's
    content."""
    import artifacts.remotes.pull as pull_module

    walked: list[str] = []
    real_children = pull_module.children

    def children(oid, obj):
        walked.append(oid)
        return real_children(oid, obj)

    first, remote, tree = pushed_tree(tmp_path)
    second = second_store(tmp_path, remote)
    monkeypatch.setattr(pull_module, "children", children)
    pull_module.pull(second, "nas", refs=["team/dir", "team/tree"])
    assert walked.count(tree["id"]) == 1 and len(walked) == len(set(walked))  # with the log segment: 3
    first.close()
    second.close()


def test_bytes_left_behind_for_one_artifact_but_wanted_by_another_are_pulled_not_promised(tmp_path):
    """pull._remote_closure 43 (an object first met as "leave behind", then wanted by a kind --only takes,
    kept in the promised list though it was downloaded: the report counts it as left on the remote)."""
    from artifacts.ingest import add_path
    from artifacts.refs import read_ref
    from artifacts.remotes.config import add_remote
    from artifacts.remotes.lazy import promised_path
    from artifacts.remotes.pull import pull
    from artifacts.remotes.push import push

    first, _ = Store.init(tmp_path / "first")
    (tmp_path / "a.bin").write_bytes(b"same bytes" * 10)
    add_path(first, tmp_path / "a.bin", "replay", ref="team/a")  # its content is met one level down, left
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "weights.bin").write_bytes(b"same bytes" * 10)
    add_path(first, tmp_path / "b", "checkpoint", ref="team/b")  # met again two levels down, wanted
    content = first.read_json(read_ref(first, "team/a"))["content"]
    tree = first.read_json(first.read_json(read_ref(first, "team/b"))["content"])
    assert [e["id"] for e in tree["entries"]] == [content]
    (tmp_path / "remote").mkdir(exist_ok=True)
    add_remote(first, "nas", str(tmp_path / "remote"))
    push(first, "nas")
    second = second_store(tmp_path, tmp_path / "remote")
    report = pull(second, "nas", only={"checkpoint"})
    assert second.has_object(content) and report.promised == 0 and not promised_path(second, "nas").exists()
    first.close()
    second.close()


def test_an_input_that_names_a_bare_tree_is_pulled_whole_under_only(tmp_path):
    """pull._remote_closure 89 (an artifact's inputs inherit "leave behind"): an input has its own say, and
    a tree named as an input has no kind for --only to judge, so its files come with the artifact."""
    from artifacts.manifests import store_content, write_manifest
    from artifacts.refs import set_ref
    from artifacts.remotes.config import add_remote
    from artifacts.remotes.pull import pull
    from artifacts.remotes.push import push

    first, _ = Store.init(tmp_path / "first")
    (tmp_path / "episodes").mkdir()
    (tmp_path / "episodes" / "0.bin").write_bytes(b"episode" * 20)
    tree_id = store_content(first, tmp_path / "episodes")["content"]
    (tmp_path / "weights.bin").write_bytes(b"weights" * 30)
    content = store_content(first, tmp_path / "weights.bin")
    checkpoint = write_manifest(first, content, "checkpoint", producer={}, inputs={"episodes": tree_id})
    set_ref(first, "team/ckpt", checkpoint)
    (tmp_path / "remote").mkdir(exist_ok=True)
    add_remote(first, "nas", str(tmp_path / "remote"))
    push(first, "nas")
    second = second_store(tmp_path, tmp_path / "remote")
    report = pull(second, "nas", only={"checkpoint"})
    episode = first.read_json(tree_id)["entries"][0]["id"]
    assert second.has_object(episode) and second.has_object(content["content"]) and report.promised == 0
    first.close()
    second.close()


def test_pulling_a_ref_the_remote_lacks_is_one_line_naming_the_remote(tmp_path):
    """fetch 33 (the line ends "no ref 'team/z' None")."""
    from artifacts.remotes.pull import pull

    first, remote, _ = pushed_store(tmp_path)
    second = second_store(tmp_path, remote)
    with pytest.raises(StoreError) as refused:
        pull(second, "nas", refs=["team/z"])
    assert str(refused.value) == "no ref 'team/z' on remote nas"
    first.close()
    second.close()


def test_a_store_does_not_fetch_back_its_own_pushed_log(tmp_path):
    """fetch 38, 39 (this store's id not known: its own log, which its push left on the remote, comes back
    as another store's, with a tracking ref and a "fetched" event). Another store's log is fetched, once."""
    from artifacts.remotes.pull import pull

    first, remote, _ = pushed_store(tmp_path)
    assert pull(first, "nas").logs == {}
    second = second_store(tmp_path, remote)
    assert list(pull(second, "nas").logs) == [first.read_config()["store_id"]]
    assert pull(second, "nas").logs == {}  # seen already: not fetched again
    first.close()
    second.close()


def test_a_pulls_meter_and_report_count_every_object_it_brought_once(tmp_path):
    """fetch's meter and report: the total the meter starts with is what its advances add up to, one advance
    an object (0 for a manifest), and the report counts what the empty store now holds."""
    from artifacts.remotes.pull import pull

    first, remote, _ = pushed_store(tmp_path)
    second = second_store(tmp_path, remote)
    meter = RecordingMeter()
    report = pull(second, "nas", jobs=1, meter=meter)
    held = list(second.iter_object_ids())
    sizes = [second.object_size(oid) for oid in held]
    [(what, objects, nbytes)] = meter.starts
    assert what == "pull ← nas" and objects == len(meter.advanced) == report.objects_received == len(held)
    assert nbytes == sum(meter.advanced) and 700 <= nbytes < report.bytes_received == sum(sizes)
    assert report.steps_indexed == 0  # no step records there
    manifests = [oid for oid in held if second.read_bytes(oid).startswith(b"{")]
    assert meter.advanced.count(0) >= len(manifests) >= 4  # three artifacts, and the first store's log
    first.close()
    second.close()


@pytest.mark.parametrize("artifacts", [True, False])
def test_an_only_kind_no_artifact_has_is_one_line_naming_the_kinds_there_unless_accrue_knows_it(tmp_path, artifacts):
    """fetch 80-95: a kind nobody wrote, given to --only, would leave every artifact's data behind; it is
    refused in one line naming the kinds the remote has ("none" for a remote of logs only). A kind accrue
    knows is never refused, and two kinds are taken as well as one."""
    from artifacts.remotes.pull import pull

    if artifacts:
        from artifacts.ingest import add_path
        from artifacts.remotes.push import push

        first, remote, _ = pushed_store(tmp_path)
        (tmp_path / "c.bin").write_bytes(b"weights")
        add_path(first, tmp_path / "c.bin", "checkpoint", ref="team/c")
        push(first, "nas")
    else:
        from artifacts.remotes.config import add_remote
        from artifacts.remotes.push import push

        first, _ = Store.init(tmp_path / "store")
        remote = tmp_path / "remote"
        remote.mkdir()
        add_remote(first, "nas", str(remote))
        push(first, "nas")
    second = second_store(tmp_path, remote)
    with pytest.raises(StoreError) as refused:
        pull(second, "nas", only={"replya"})
    there = "checkpoint, replay" if artifacts else "none"
    assert str(refused.value) == f"--only replya: no artifact of that kind on remote nas (kinds there: {there})"
    report = pull(second, "nas", only={"checkpoint", "replay"})
    teams = sorted(r for r in report.refs if r.startswith("team/"))
    assert report.promised == 0 and teams == (["team/a", "team/b", "team/c", "team/e"] if artifacts else [])
    first.close()
    second.close()


def test_a_fetch_logs_one_event_naming_what_moved_on_the_remote_and_none_when_nothing_did(tmp_path):
    """fetch's audit trail: one "fetched" event naming the remote, the remote refs that moved since this
    store last looked and the other stores' log segments that came; tracking refs move without events of
    their own; a fetch that finds nothing new writes nothing, and one that finds only a new log says so."""
    from artifacts.auditlog import append_event, iter_events
    from artifacts.remotes.pull import fetch
    from artifacts.remotes.push import push

    def events(store: Store) -> list[dict]:
        return [e for e in iter_events(store) if e["event"] in ("fetched", "ref-moved")]

    first, remote, _ = pushed_store(tmp_path)
    second = second_store(tmp_path, remote)
    sid = first.read_config()["store_id"]
    report = fetch(second, "nas")
    assert [(e["event"], e["remote"], e["refs"], e["logs"]) for e in events(second)] == [
        ("fetched", "nas", report.refs, report.logs)
    ]
    assert len(report.refs) == 6 and list(report.logs) == [sid]  # team/a, b, e and their ingested/ refs
    fetch(second, "nas")
    assert len(events(second)) == 1
    append_event(first, "note", text="a log line, no ref moved")
    push(first, "nas")
    report = fetch(second, "nas")
    last = events(second)[-1]
    assert len(events(second)) == 2 and (last["refs"], last["logs"]) == ({}, report.logs) and list(report.logs) == [sid]
    first.close()
    second.close()


def test_a_pull_refuses_an_object_shorter_than_its_manifest_says(tmp_path):
    """fetch 108 (the size the manifest gives not passed to the download: an object that does not match its
    manifest is taken, and `verify` of the pulling store then fails on it). The bytes hash to their id, so
    only the size can tell."""
    from artifacts.manifests import store_content, write_manifest
    from artifacts.refs import set_ref
    from artifacts.remotes.config import add_remote
    from artifacts.remotes.pull import pull
    from artifacts.remotes.push import push

    first, _ = Store.init(tmp_path / "first")
    (tmp_path / "w.bin").write_bytes(b"w" * 100)
    content = store_content(first, tmp_path / "w.bin")
    set_ref(first, "team/w", write_manifest(first, {**content, "size": 101}, "replay", producer={}))
    (tmp_path / "remote").mkdir(exist_ok=True)
    add_remote(first, "nas", str(tmp_path / "remote"))
    push(first, "nas")
    second = second_store(tmp_path, tmp_path / "remote")
    with pytest.raises(StoreError) as refused:
        pull(second, "nas")
    assert f"object {content['content'][:12]} arrived truncated (100 of 101 bytes) 3 times" in str(refused.value)
    assert not second.has_object(content["content"])
    first.close()
    second.close()


def test_a_pull_syncs_the_objects_directory_above_the_fan_out_directories_it_made(tmp_path, monkeypatch):
    """fetch 109, 114 (downloads not told to collect their new directories: each object is synced in its
    fan-out directory, but the objects directory that gained those fan-out directories never is, so after
    a crash they, and every object in them, can be gone)."""
    import artifacts.atomic
    import artifacts.remotes.transfer
    from artifacts.remotes.pull import pull

    first, remote, _ = pushed_store(tmp_path)
    second = second_store(tmp_path, remote)
    synced: list[Path] = []
    for module in (artifacts.atomic, artifacts.remotes.transfer):
        monkeypatch.setattr(module, "fsync_dir", synced.append)
    pull(second, "nas")
    assert second.objects_dir in synced
    first.close()
    second.close()


def test_data_left_behind_by_only_is_noted_as_promised_by_that_remote_which_becomes_a_promisor(tmp_path):
    """fetch 141-153: what --only leaves on the remote is noted, object by object, as promised by that remote,
    and the remote is marked a promisor (so a step that needs the data fetches it); the report counts it."""
    from artifacts.remotes.config import get_remote
    from artifacts.remotes.lazy import promised_path
    from artifacts.remotes.pull import pull

    first, remote, contents = pushed_store(tmp_path)
    second = second_store(tmp_path, remote)
    assert not get_remote(second, "nas").promisor
    report = pull(second, "nas", only={"checkpoint"})
    assert report.promised == 3 and get_remote(second, "nas").promisor
    assert sorted(promised_path(second, "nas").read_text().split()) == sorted(contents.values())
    assert not any(second.has_object(oid) for oid in contents.values())
    first.close()
    second.close()


def test_the_progress_bar_counts_each_object_once_whichever_thread_advances_it(monkeypatch):
    """progress.RichMeter.advance 2, 3 (the objects done shown as 1, or counting down), start 11, 13, 19 (no
    bar, no speed, or the objects column garbled), 26, 27 (no total bytes; "None" objects at first): what, bar, bytes, speed, then "done/all objects".
    Not on a terminal (a log, a captured run) there is no bar at all, and no thread redrawing it."""
    import io
    import re

    from rich.console import Console

    from artifacts.remotes.progress import RichMeter

    meter = RichMeter()
    meter.start("pull ← nas", 40, 4000)
    assert meter.bar is None  # pytest's stderr is no terminal
    meter.advance(10)
    meter.stop()
    monkeypatch.setenv("TTY_COMPATIBLE", "1")  # stderr counts as a terminal for rich
    meter.start("pull ← nas", 40, 4000)
    assert (meter.bar.tasks[0].fields["objects"], meter.bar.tasks[0].total) == ("0/40", 4000)
    workers = [threading.Thread(target=lambda: [meter.advance(10) for _ in range(10)]) for _ in range(4)]
    for worker in workers:
        worker.start()
    for worker in workers:
        worker.join()
    [task] = meter.bar.tasks
    assert task.fields["objects"] == "40/40" and task.completed == 400
    shown = [type(column).__name__ for column in meter.bar.columns]
    assert shown == ["TextColumn", "BarColumn", "DownloadColumn", "TransferSpeedColumn", "TextColumn"]
    screen = Console(file=io.StringIO(), width=120)
    screen.print(meter.bar.make_tasks_table([task]))
    assert "pull ← nas" in screen.file.getvalue() and re.search(r"\b40/40 objects\b", screen.file.getvalue())
    meter.stop()
    assert meter.bar is None


def test_a_manifest_the_remote_lacks_or_holds_damaged_is_refused_in_one_exact_line(tmp_path):
    """transfer.download_manifest 6, 7 (the missing manifest's line lost, or its id cut at 13), 12, 16 (a damaged
    one not called corrupt)."""
    from artifacts.refs import read_ref
    from artifacts.remotes.transfer import download_manifest

    first, remote, _ = pushed_store(tmp_path)
    oid = read_ref(first, "team/a")
    backend = DirBackend(parse_url("nas", str(remote)))
    assert hash_bytes(download_manifest(backend, oid)) == oid
    path = remote / "objects" / "blake3" / oid[:2] / oid[2:]
    path.chmod(0o644)
    path.write_bytes(b"{}")
    with pytest.raises(StoreError) as damaged:
        download_manifest(backend, oid)
    assert f": object {oid[:12]} arrived corrupt 3 times; refused" in str(damaged.value)
    path.unlink()
    with pytest.raises(StoreError) as missing:
        download_manifest(backend, oid)
    assert str(missing.value) == (
        f"{backend.describe()}: lacks object {oid[:12]} that its refs reach; "
        "run `accrue remote repair nas` from a store that has it"
    )
    first.close()


# ----------------------------------------------------------------------------- remotes.config.pick_remote (round 12)
def test_with_several_remotes_origin_is_meant_unless_a_word_names_another(tmp_path):
    """config.pick_remote 12, 13, 15, 16: the remote named origin is the default among several."""
    from artifacts.remotes.config import add_remote, pick_remote

    store, _ = Store.init(tmp_path / "store")
    add_remote(store, "nas", str(tmp_path / "nas"))
    add_remote(store, "origin", str(tmp_path / "origin"))
    spec, words = pick_remote(store, ["runs/a"])
    assert (spec.name, words) == ("origin", ["runs/a"])
    spec, words = pick_remote(store, ["nas", "runs/a"])
    assert (spec.name, words) == ("nas", ["runs/a"])


def test_with_no_remote_or_several_and_no_origin_the_error_says_what_to_do(tmp_path):
    """config.pick_remote 19, 24: the two messages, word for word."""
    from artifacts.remotes.config import add_remote, pick_remote

    store, _ = Store.init(tmp_path / "store")
    with pytest.raises(StoreError) as exc:
        pick_remote(store, [])
    assert str(exc.value) == "this store has no remotes; add one with `accrue remote add NAME URL`"
    add_remote(store, "nas", str(tmp_path / "nas"))
    add_remote(store, "backup", str(tmp_path / "backup"))
    with pytest.raises(StoreError) as exc:
        pick_remote(store, ["runs/a"])
    assert str(exc.value) == "which remote? this store has backup, nas; name one first"


# ----------------------------------------------------------------------------- remotes.pointers (round 12)
def test_a_pushed_ref_s_version_is_remembered_under_the_remote_s_lock_so_reading_it_back_fetches_nothing(
    tmp_path, monkeypatch
):
    """pointers.remember_version 8 (the remote's own lock), 13 (the version and id are what is cached)."""
    import artifacts.remotes.pointers as pointers
    from artifacts.refs import read_ref
    from artifacts.remotes.config import get_remote

    locks = []
    real_lock = pointers.store_lock
    monkeypatch.setattr(pointers, "store_lock", lambda where, name: locks.append(name) or real_lock(where, name))
    store, remote, _ = pushed_store(tmp_path)
    assert "remote-nas" in locks and set(locks) <= {"remote-nas"}
    cache = json.loads((store.root / "remotes" / "nas" / "refs.json").read_bytes())
    assert cache["team/a"] == [(remote / "refs" / "team" / "a").read_text(), read_ref(store, "team/a")]
    spec = get_remote(store, "nas")
    backend = DirBackend(spec)
    fetched = []
    real_read = backend.read_versioned
    monkeypatch.setattr(backend, "read_versioned", lambda key: fetched.append(key) or real_read(key))
    pointed = pointers.read_pointers(store, spec, backend, "refs")
    assert {n: i for n, (i, _) in pointed.items()} == pointers.local_refs(store) and len(pointed) == 6
    assert fetched == []


def test_reading_the_remote_s_refs_skips_files_that_are_not_refs_and_tracking_refs_and_refuses_a_damaged_one(
    tmp_path,
):
    """pointers.read_pointers: a name that is not a ref (an editor's `a~`, sorted first) and another store's
    remote-tracking refs are passed over, not the end of the listing; a ref file that holds no id is one
    line; the version cache is rewritten with what was read (ids in the triage files of round 12)."""
    import artifacts.remotes.pointers as pointers
    from artifacts.remotes.config import get_remote

    store, remote, _ = pushed_store(tmp_path)
    spec = get_remote(store, "nas")
    (remote / "refs" / "a~").write_text("backup")
    (remote / "refs" / "remotes" / "other").mkdir(parents=True)
    (remote / "refs" / "remotes" / "other" / "x").write_text("f" * 64)
    (remote / "refs" / "remote-logs").mkdir()
    (remote / "refs" / "remote-logs" / "y").write_text("f" * 64)
    shutil.rmtree(store.root / "remotes")  # a store that never talked to a remote has no remotes/ yet
    pointed = pointers.read_pointers(store, spec, DirBackend(spec), "refs")
    assert sorted(pointed) == sorted(pointers.local_refs(store))
    cache = json.loads((store.root / "remotes" / "nas" / "refs.json").read_bytes())
    assert cache == {n: [v, i] for n, (i, v) in pointed.items()}
    backend = DirBackend(spec)
    real_read = backend.read_versioned
    gone = sorted(pointed)[0]
    backend.read_versioned = lambda key: None if key == f"refs/{gone}" else real_read(key)
    (store.root / "remotes" / "nas" / "refs.json").unlink()
    assert sorted(pointers.read_pointers(store, spec, backend, "refs")) == sorted(pointed)[1:]  # removed meanwhile
    for held, shown in [
        (b"not an id at all, really", "not an id at all, re"),
        (b"\xff\xfe" + b"0" * 30, "\ufffd\ufffd" + "0" * 18),
    ]:
        (remote / "refs" / "team" / "b").write_bytes(held)
        with pytest.raises(StoreError) as exc:
            pointers.read_pointers(store, spec, DirBackend(spec), "refs")
        assert str(exc.value) == f"remote nas ({remote}): refs/team/b is damaged (holds {shown!r}, not an id)"


def test_a_remote_s_config_is_made_on_first_push_and_checked_on_every_use(tmp_path, monkeypatch):
    """pointers.check_remote_config: made once (canonical bytes) when asked to create, else a missing one is
    one line; a config that is not an accrue remote's, or of another format or hash, is refused word for
    word; a config another store made at the same moment is taken (ids in the triage files of round 12)."""
    from artifacts.remotes.pointers import check_remote_config

    remote = tmp_path / "remote"
    backend = DirBackend(parse_url("nas", str(remote)))
    with pytest.raises(StoreError) as exc:
        check_remote_config(backend, create=False)
    assert str(exc.value) == f"remote nas ({remote}): the directory does not exist (is the disk mounted?)"
    remote.mkdir()
    with pytest.raises(StoreError) as exc:
        check_remote_config(backend, create=False)
    assert str(exc.value) == f"remote nas ({remote}) holds no accrue store yet (push to it first)"
    assert not (remote / "config").exists()
    check_remote_config(backend, create=True)
    assert (remote / "config").read_bytes() == b'{"format":1,"hash":"blake3","type":"accrue-remote"}\n'
    check_remote_config(backend, create=False)
    unmade = tmp_path / "second-remote"
    with pytest.raises(StoreError) as exc:  # a push never makes a remote's directory: an unmounted disk's is missing
        check_remote_config(DirBackend(parse_url("usb", str(unmade))), create=True)
    assert str(exc.value) == (
        f"remote usb ({unmade}): the directory does not exist (is the disk mounted?); nothing was written — "
        "if it is a new remote, `accrue remote init usb` makes it one"
    )
    assert not unmade.exists()
    (remote / "config").unlink()
    with pytest.raises(StoreError) as exc:  # a store that used the remote before: not made again behind its back
        check_remote_config(backend, create=True, known=True)
    assert "holds no accrue store, but this store has used it before" in str(exc.value)
    assert "`accrue remote init nas` makes it one" in str(exc.value) and not (remote / "config").exists()
    check_remote_config(backend, create=True)
    check_remote_config(backend, create=True)  # there already: kept
    for raw, why in [
        (b"not json", "its config is not an accrue remote's"),
        (b"[1]", "its config is not an accrue remote's"),
        (b'{"format":1,"hash":"blake3","type":"accrue-store"}', "its config is not an accrue remote's"),
        (b'{"format":2,"hash":"blake3","type":"accrue-remote"}', "unsupported remote format 2 / hash 'blake3'"),
        (b'{"format":1,"hash":"sha1","type":"accrue-remote"}', "unsupported remote format 1 / hash 'sha1'"),
        (b'{"type":"accrue-remote"}', "unsupported remote format None / hash None"),
    ]:
        os.chmod(remote / "config", 0o644)
        (remote / "config").write_bytes(raw)
        with pytest.raises(StoreError) as exc:
            check_remote_config(backend, create=False)
        assert str(exc.value) == f"remote nas ({remote}): {why}"
    (remote / "config").unlink()
    real_swap = backend.swap

    def raced(key, data, expect):
        real_swap(key, data, expect)  # another store made it first
        return real_swap(key, data, expect)

    monkeypatch.setattr(backend, "swap", raced)
    check_remote_config(backend, create=True)
    assert (remote / "config").read_bytes() == b'{"format":1,"hash":"blake3","type":"accrue-remote"}\n'


def test_refs_named_on_the_command_line_pick_those_refs_or_the_refs_under_them():
    """pointers.select_refs: nothing named is every ref; a name picks itself and what is under it (a
    trailing slash is the same), never a ref that only starts with its letters; a tracking ref and an
    unknown name are refused in one line (ids in the triage files of round 12)."""
    from artifacts.remotes.pointers import select_refs

    names = {"team/a": "1", "team/a/x": "2", "team/ab": "3", "solo": "4"}
    everything = select_refs(names, [], "here")
    assert everything == names and everything is not names
    assert select_refs(names, ["team/a/"], "here") == {"team/a": "1", "team/a/x": "2"}
    assert select_refs(names, ["team", "solo"], "here") == names
    assert select_refs({"run/X": "5", "run/Y": "6"}, ["run/X"], "here") == {"run/X": "5"}  # only slashes are cut
    with pytest.raises(StoreError) as exc:
        select_refs(names, ["remotes/nas/team/a"], "here")
    assert str(exc.value) == "remotes/nas/team/a: remote-tracking refs are never pushed or pulled"
    with pytest.raises(StoreError) as exc:
        select_refs(names, ["remote-logs/nas/x/"], "here")
    assert str(exc.value) == "remote-logs/nas/x: remote-tracking refs are never pushed or pulled"
    with pytest.raises(StoreError) as exc:
        select_refs(names, ["solo", "team/b"], "on remote nas")
    assert str(exc.value) == "no ref 'team/b' on remote nas"


def test_merge_bases_are_recorded_once_per_change_and_fall_back_to_tracking_refs(bare_store, monkeypatch):
    """pointers.record_bases, merge_bases, tracking_refs, local_refs: base.json (canonical, made with its
    folders) wins over the remote-tracking refs; nothing agreed or nothing new writes nothing (ids in the
    triage files of round 12)."""
    import artifacts.remotes.pointers as pointers
    from artifacts.hashing import canonical_json
    from artifacts.refs import set_ref

    a, b, c = (bare_store.put_bytes(x) for x in (b"a", b"b", b"c"))
    set_ref(bare_store, "remotes/nas/team/a", a)
    set_ref(bare_store, "remotes/nas/team/b", b)
    set_ref(bare_store, "remotes/usb/team/a", c)
    set_ref(bare_store, "remote-logs/nas/x", c)
    set_ref(bare_store, "team/mine", c)
    assert pointers.tracking_refs(bare_store, "nas") == {"team/a": a, "team/b": b}
    assert pointers.tracking_refs(bare_store, "nas", "remote-logs") == {"x": c}
    assert pointers.local_refs(bare_store) == {"team/mine": c}
    assert pointers.merge_bases(bare_store, "nas") == {"team/a": a, "team/b": b}
    saved = []
    real_save = pointers.save_json
    monkeypatch.setattr(pointers, "save_json", lambda path, value: saved.append(value) or real_save(path, value))
    pointers.record_bases(bare_store, "nas", {})
    assert saved == [] and not (bare_store.root / "remotes").exists()
    pointers.record_bases(bare_store, "nas", {"team/a": c})
    base = bare_store.root / "remotes" / "nas" / "base.json"
    assert base.read_bytes() == canonical_json({"team/a": c}) + b"\n"
    pointers.record_bases(bare_store, "nas", {"team/a": c})
    assert saved == [{"team/a": c}]  # the same again: not rewritten
    pointers.record_bases(bare_store, "nas", {"team/b": a, "team/a": c})
    assert saved[-1] == {"team/a": c, "team/b": a}
    assert pointers.merge_bases(bare_store, "nas") == {"team/a": c, "team/b": a}
    from artifacts.locks import store_lock

    with store_lock(bare_store.locks_dir, "remote-nas"):  # a push or pull of nas is running
        t = threading.Thread(target=pointers.record_bases, args=(bare_store, "nas", {"team/a": b}))
        t.start()
        t.join(0.5)
        assert t.is_alive()
    t.join(10)
    assert not t.is_alive() and pointers.merge_bases(bare_store, "nas")["team/a"] == b


def test_a_big_remotes_presence_heads_only_what_was_not_confirmed_since_its_last_full_check(tmp_path, monkeypatch):
    """present.Presence.check: a remote of more than LIST_SMALL objects is listed in full only when this store
    has no full check of it, when the last is older than ACCRUE_REMOTE_RECHECK, when a prune deleted there
    since, or when more than HEAD_MAX candidates are unconfirmed; else one HEAD per object not confirmed since."""
    import artifacts.remotes.present as present
    from artifacts.remotes.config import get_remote

    store, remote, contents = pushed_store(tmp_path)
    monkeypatch.setattr(present, "LIST_SMALL", 0)  # every remote counts as big
    backend = DirBackend(get_remote(store, "nas"))
    heads, listings = [], []
    real_head, real_list = backend.head, backend.remote_object_ids
    monkeypatch.setattr(backend, "head", lambda key: heads.append(key) or real_head(key))
    monkeypatch.setattr(backend, "remote_object_ids", lambda: listings.append(1) or real_list())
    held = [contents["a"], contents["b"]]
    sizes = remote_object_sizes(remote)
    absent = [hash_bytes(f"absent {i}".encode()) for i in range(257)]

    def check(oids):
        return present.Presence(store, "nas").check(backend, oids, 2)

    assert check(held + absent[:1]) == {o: sizes[o] for o in held}  # no full check yet: one listing
    assert (len(heads), listings) == (0, [1])
    assert check(held + absent[:1]) == {o: None for o in held}  # confirmed since: only the new one is asked
    assert heads == [object_key(absent[0])] and listings == [1]
    heads.clear()
    assert check(held + absent) == {o: sizes[o] for o in held}  # 257 unconfirmed: one listing, not 257 HEADs
    assert (heads, listings) == ([], [1, 1])
    lose_on_remote(remote, held[:1])
    assert held[0] in check(held)  # trusted until the next full check
    monkeypatch.setenv("ACCRUE_REMOTE_RECHECK", "0")
    assert check(held) == {held[1]: sizes[held[1]]} and listings == [1, 1, 1]  # the last one is too old
    monkeypatch.delenv("ACCRUE_REMOTE_RECHECK")
    present.Presence(store, "nas").confirm(held[:1])  # (wrongly) confirmed again
    assert held[0] in check(held) and listings == [1, 1, 1]
    present.mark_pruned(backend, "a prune")
    assert check(held) == {held[1]: sizes[held[1]]} and listings == [1, 1, 1, 1]  # a prune since: listed
    assert held[0] not in check(held) and listings == [1, 1, 1, 1]  # the marker read is remembered
    monkeypatch.setenv("ACCRUE_REMOTE_RECHECK", "soon")
    with pytest.raises(StoreError, match="ACCRUE_REMOTE_RECHECK='soon': not a number of seconds"):
        check(held)


# ----------------------------------------------------------------------------- remotes.closure.bottom_up (round 12)
def test_manifests_are_grouped_by_height_so_each_is_written_after_what_it_names():
    """closure.bottom_up: a manifest met before what it names still lands above it; ids that are not
    manifests (data) have no group; each group sorted; a diamond and a long chain (ids in the triage
    files of round 12)."""
    from artifacts.remotes.closure import bottom_up

    assert bottom_up({}) == []
    named = {
        "top": ["mid-b", "mid-a", "data-1"],
        "mid-b": ["low"],
        "mid-a": ["low", "data-2"],
        "low": ["data-1"],
        "lone": [],
    }
    assert bottom_up(named) == [["lone", "low"], ["mid-a", "mid-b"], ["top"]]
    chain = {f"m{i}": [f"m{i - 1}"] if i else ["data"] for i in range(6)}
    reversed_chain = dict(reversed(list(chain.items())))
    assert bottom_up(reversed_chain) == [[f"m{i}"] for i in range(6)]


# ----------------------------------------------------------------------------- remotes.config (round 12)
def test_a_remote_url_is_an_s3_bucket_and_prefix_or_a_directory_and_each_malformed_one_is_one_line(
    tmp_path, monkeypatch
):
    """config.parse_url: s3:// and s3a:// (bucket, prefix without its slashes, settings), a directory as a
    path, ~ or file://; every refusal word for word (ids in the triage files of round 12)."""
    from artifacts.remotes.config import RemoteSpec

    spec = parse_url("origin", "s3://lab-bucket.1//runs/a/", promisor=True, settings={"region": "eu-west-1"})
    assert spec == RemoteSpec(
        "origin", "s3://lab-bucket.1//runs/a/", "s3", bucket="lab-bucket.1", prefix="runs/a", promisor=True
    )
    assert spec.settings == {"region": "eu-west-1"} and spec.path is None
    assert parse_url("o", "s3://lab/a://b/").prefix == "a://b"  # only the first :// is the scheme's
    assert parse_url("o", "s3://lab/runX/").prefix == "runX"  # only slashes are cut
    bare = parse_url("o", "s3a://abc")
    assert (bare.kind, bare.bucket, bare.prefix, bare.settings, bare.promisor) == ("s3", "abc", "", {}, False)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    for url, path in [
        ("nas", tmp_path / "nas"),
        ("./odd:name", tmp_path / "odd:name"),
        ("file:///mnt/nas/accrue", Path("/mnt/nas/accrue")),
        ("~/remote", tmp_path / "home" / "remote"),
        ("file://~/r", tmp_path / "home" / "r"),
    ]:
        spec = parse_url("nas", url)
        assert (spec.name, spec.kind, spec.path, spec.url, spec.bucket, spec.prefix) == (
            "nas",
            "dir",
            path,
            url,
            "",
            "",
        )
    assert parse_url("nas", "nas", promisor=True).promisor is True
    for url, line in [
        ("", "remote URL is empty (use s3://BUCKET/PREFIX or a directory)"),
        ("  ", "remote URL is empty (use s3://BUCKET/PREFIX or a directory)"),
        ("s3:///prefix", "remote URL 's3:///prefix' names no bucket (use s3://BUCKET/PREFIX)"),
        ("s3://Bucket/x", "remote URL 's3://Bucket/x': 'Bucket' is not a valid S3 bucket name (3-63 of a-z 0-9 . -)"),
        ("s3://ab", "remote URL 's3://ab': 'ab' is not a valid S3 bucket name (3-63 of a-z 0-9 . -)"),
        (
            "s3://" + "a" * 64,
            f"remote URL {'s3://' + 'a' * 64!r}: {'a' * 64!r} is not a valid S3 bucket name (3-63 of a-z 0-9 . -)",
        ),
        ("gs://b/p", "remote URL 'gs://b/p': unsupported scheme (use s3://BUCKET/PREFIX or a directory)"),
        (
            "s3:/bucket",
            "remote URL 's3:/bucket' is malformed (a scheme needs '//': s3://BUCKET/PREFIX or file:///PATH; "
            "a directory whose name has ':' as ./NAME)",
        ),
        (
            "file:nas",
            "remote URL 'file:nas' is malformed (a scheme needs '//': s3://BUCKET/PREFIX or file:///PATH; "
            "a directory whose name has ':' as ./NAME)",
        ),
    ]:
        with pytest.raises(StoreError) as exc:
            parse_url("nas", url)
        assert str(exc.value) == line
    assert parse_url("nas", "s3://" + "a" * 63).bucket == "a" * 63 and parse_url("nas", "C:data").kind == "dir"


def test_remotes_are_added_once_listed_by_name_and_looked_up_with_a_helpful_refusal(tmp_path, monkeypatch):
    """config.add_remote, list_remotes, get_remote, check_remote_name (ids in the triage files of round 12)."""
    from artifacts.remotes.config import add_remote, get_remote, list_remotes, set_promisor, set_setting

    store, _ = Store.init(tmp_path / "store")
    with pytest.raises(StoreError) as exc:
        get_remote(store, "origin")
    assert str(exc.value) == "no remote named 'origin' (known: none; add one with `accrue remote add NAME URL`)"
    monkeypatch.chdir(tmp_path)
    spec = add_remote(store, "nas", "backup")
    assert (spec.name, spec.kind, spec.path, spec.url) == ("nas", "dir", tmp_path / "backup", str(tmp_path / "backup"))
    assert store.read_config()["remotes"] == {"nas": {"url": str(tmp_path / "backup")}}  # where it was added
    s3 = add_remote(store, "b2", "s3://lab/runs")
    assert (s3.url, s3.bucket, s3.prefix) == ("s3://lab/runs", "lab", "runs")
    with pytest.raises(StoreError) as exc:
        add_remote(store, "nas", "elsewhere")
    assert str(exc.value) == f"remote 'nas' exists already ({tmp_path / 'backup'}); remove it first"
    for bad in ("-x", "a/b", "x" * 41, ""):
        with pytest.raises(StoreError) as exc:
            add_remote(store, bad, "elsewhere")
        assert str(exc.value) == f"bad remote name {bad!r}: use letters, digits, '.', '_', '-' (e.g. origin, nas)"
    assert add_remote(store, "x" * 40, "s3://lab/long").name == "x" * 40
    for inside in (str(store.root), str(store.root / "objects" / "r")):
        with pytest.raises(StoreError) as exc:
            add_remote(store, "inside", inside)
        assert str(exc.value) == (
            f"remote inside: {Path(inside)} is inside this store ({store.root}); use a directory outside it"
        )
    set_promisor(store, "b2")
    set_setting(store, "b2", "region", "eu-west-1")
    listed = list_remotes(store)
    assert list(listed) == ["b2", "nas", "x" * 40]
    assert listed["b2"].promisor is True and listed["b2"].settings == {"region": "eu-west-1"}
    assert listed["nas"].promisor is False and listed["nas"].settings == {}
    assert get_remote(store, "b2") == listed["b2"]
    with pytest.raises(StoreError) as exc:
        get_remote(store, "origin")
    assert str(exc.value) == f"no remote named 'origin' (known: b2, nas, {'x' * 40})"


# ----------------------------------------------------------------------------- remotes.push
def store_pushing_to(tmp_path: Path, name: str, remote: Path, files: dict[str, bytes]) -> Store:
    """A store with one file artifact per ref (kind replay), and directory remote nas at `remote`."""
    from artifacts.ingest import add_path
    from artifacts.remotes.config import add_remote

    store, _ = Store.init(tmp_path / name)
    for ref, data in files.items():
        src = tmp_path / f"{name}-{ref.replace('/', '-')}.bin"
        src.write_bytes(data)
        add_path(store, src, "replay", ref=ref)
    remote.mkdir(parents=True, exist_ok=True)  # a remote's directory is made by `remote init`, never by a push
    add_remote(store, "nas", str(remote))
    return store


def remote_files(remote: Path, under: str) -> dict[str, bytes]:
    root = remote / under
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def remote_object_sizes(remote: Path) -> dict[str, int]:
    return {key.replace("/", ""): len(data) for key, data in remote_files(remote, "objects/blake3").items()}


def remote_manifest(remote: Path, oid: str) -> dict:
    return json.loads((remote / object_key(oid)).read_bytes())


def remote_state(store: Store, name: str) -> dict:
    from artifacts.remotes.pointers import load_json, state_dir

    return load_json(state_dir(store, "nas") / name)


class BackendCalls:
    """Counts a directory remote's HEADs and listings, and keeps the leases push writes."""

    def __init__(self, monkeypatch) -> None:
        self.heads, self.listings, self.leases = 0, 0, []
        real_head, real_list, real_put = DirBackend.head, DirBackend.remote_object_ids, DirBackend.put_bytes

        def head(backend, key):
            self.heads += 1
            return real_head(backend, key)

        def listing(backend):
            self.listings += 1
            return real_list(backend)

        def put_bytes(backend, key, data):
            if key.startswith("pushes/"):
                self.leases.append((key, data))
            return real_put(backend, key, data)

        monkeypatch.setattr(DirBackend, "head", head)
        monkeypatch.setattr(DirBackend, "remote_object_ids", listing)
        monkeypatch.setattr(DirBackend, "put_bytes", put_bytes)


def test_a_first_push_sends_every_object_once_and_leaves_its_bookkeeping(tmp_path, monkeypatch):
    """push.push 2-40 (the lease's name and bytes), 41-56, 59 (the lease removed); _push 1-25, 33-40 (every ref
    moved from nothing), 57-66, 79-82, 100-120 (the first log segment), 121-141, 142-160, 163-200 (what is
    checked and sent: one listing of a remote with no refs; an empty object counts 0 bytes), 201-261 (the
    segment sent, its pointer swapped and remembered), 272-286, 316-330, 337-368 (refs swapped, remembered,
    tracked without an event each, logged once); _local_closure 1-27."""
    import re
    import socket

    from artifacts.auditlog import iter_events
    from artifacts.hashing import canonical_json
    from artifacts.remotes.config import store_id
    from artifacts.remotes.pointers import REMOTE_CONFIG, merge_bases, tracking_refs
    from artifacts.remotes.push import push

    remote = tmp_path / "remote"
    store = store_pushing_to(tmp_path, "a", remote, {"team/a": b"alpha" * 100, "team/b": b"beta" * 50, "team/e": b""})
    refs, local_objects = local_refs(store), set(store.iter_object_ids())
    calls, meter = BackendCalls(monkeypatch), RecordingMeter()
    log_before = store.log_path.read_bytes()
    events_before = len(list(iter_events(store)))

    report = push(store, "nas", meter=meter)

    sid, log_state = store_id(store), remote_state(store, "log.json")
    segment = log_state["manifest"]
    sent = remote_object_sizes(remote)
    segment_data = remote_manifest(remote, segment)["content"]
    assert set(sent) == local_objects | {segment, segment_data}
    assert log_state == {"manifest": segment, "end": len(log_before)}
    assert report.as_dict() == {
        "remote": "nas",
        "moved": {name: [None, oid] for name, oid in refs.items()},
        "up_to_date": [],
        "behind": [],
        "conflicts": [],
        "displaced": {},
        "objects_sent": len(sent),
        "bytes_sent": sum(sent.values()),
        "objects_checked": len(sent),
        "log_segment": segment,
        "gone_there": [],
        "healed": [],
        "objects_rehashed": 0,
        "leases_taken_over": [],
        "uploads_resumed": [],
    }
    assert 0 in sent.values()
    local_bytes = sum(store.object_size(o) for o in local_objects)
    assert meter.starts == [("push → nas", len(local_objects), local_bytes)]
    assert sorted(meter.advanced) == sorted(store.object_size(o) for o in local_objects)
    assert (calls.heads, calls.listings) == (0, 1)  # a remote with no refs is listed once, not asked per object
    assert (remote / "config").read_bytes() == canonical_json(REMOTE_CONFIG) + b"\n"
    assert remote_files(remote, "refs") == {name: f"{oid}\n".encode() for name, oid in refs.items()}
    assert remote_files(remote, "logs") == {sid: f"{segment}\n".encode()}
    assert remote_state(store, "refs.json") == {name: [f"{oid}\n", oid] for name, oid in refs.items()}
    assert remote_state(store, "logs.json") == {sid: [f"{segment}\n", segment]}
    assert tracking_refs(store, "nas") == refs and merge_bases(store, "nas") == refs
    [pushed] = list(iter_events(store))[events_before:]  # tracking refs move without events of their own
    assert (pushed["event"], pushed["remote"], pushed["refs"]) == ("pushed", "nas", refs)
    [(lease, lease_bytes)] = calls.leases
    assert re.fullmatch(rf"pushes/{sid}-{os.getpid()}-[0-9a-f]{{8}}", lease)
    lease_info = json.loads(lease_bytes)
    assert (lease_info["host"], lease_info["pid"], lease_info["store"]) == (socket.gethostname(), os.getpid(), sid)
    assert lease_bytes == canonical_json(lease_info) + b"\n"
    assert not (remote / "pushes").exists() or not any((remote / "pushes").iterdir())


def test_later_pushes_send_only_what_is_new_and_chain_the_log_segments(tmp_path, monkeypatch):
    """_push 26-32 (a ref already there is up to date), 35, 36, 280, 286 (a ref only this store moved moves
    with the remote's version), 83-120 (the next segment continues the last from where it ended), 121-127
    (what the remote's refs reach is not checked again), 148, 149, 155 (few candidates: one HEAD each),
    345-349 (an up-to-date push tracks and logs nothing)."""
    from artifacts.auditlog import iter_events
    from artifacts.ingest import add_path
    from artifacts.refs import set_ref
    from artifacts.remotes.push import push

    remote = tmp_path / "remote"
    store = store_pushing_to(tmp_path, "a", remote, {"team/a": b"alpha" * 100, "team/b": b"beta" * 50})
    push(store, "nas")
    first = remote_state(store, "log.json")
    refs, old_objects = local_refs(store), set(store.iter_object_ids())

    (tmp_path / "c.bin").write_bytes(b"gamma" * 30)
    add_path(store, tmp_path / "c.bin", "replay", ref="team/c")
    set_ref(store, "team/a", refs["team/b"])  # moved here only
    log_before = store.log_path.read_bytes()
    calls = BackendCalls(monkeypatch)
    report = push(store, "nas")

    second = remote_state(store, "log.json")
    segment = remote_manifest(remote, second["manifest"])
    new_objects = set(store.iter_object_ids()) - old_objects
    now = local_refs(store)
    assert report.moved == {n: [refs.get(n), now[n]] for n in now if now[n] != refs.get(n)}
    assert set(report.moved) == {"team/a", "team/c", *[n for n in now if n.startswith("ingested/") and n not in refs]}
    assert report.up_to_date == [n for n in now if n not in report.moved]
    # every object the refs reach is checked (a small remote: in one listing), only the new ones sent
    assert report.objects_checked == len(set(store.iter_object_ids())) + 2
    assert report.objects_sent == len(new_objects) + 2
    assert calls.heads == 0 and calls.listings == 1
    assert second == {"manifest": report.log_segment, "end": len(log_before)}
    assert segment["inputs"] == {"previous": first["manifest"]}
    first_new = json.loads(log_before[first["end"] :].splitlines()[0])["seq"]
    assert segment["meta"]["first_seq"] == first_new
    assert remote_files(remote, "refs")["team/a"] == f"{refs['team/b']}\n".encode()

    events = len(list(iter_events(store)))
    quiet = push(store, "nas")  # the pushed event of the last push waits for a push that moves a ref
    assert (quiet.moved, quiet.objects_sent, quiet.log_segment) == ({}, 0, None)
    assert quiet.objects_checked == report.objects_checked - 2  # what the refs reach, still checked
    assert len(list(iter_events(store))) == events  # no ref changed: no pushed event


def test_a_push_of_chosen_refs_moves_only_those_and_an_unknown_one_is_refused(tmp_path):
    """push.push 11-20 (the refs chosen, and the words for one that is not in the store)."""
    from artifacts.remotes.push import push

    remote = tmp_path / "remote"
    store = store_pushing_to(tmp_path, "a", remote, {"team/a": b"alpha" * 100, "team/b": b"beta" * 50})
    report = push(store, "nas", ["team/a"])
    assert set(report.moved) == {"team/a"}
    assert set(remote_files(remote, "refs")) == {"team/a"}
    with pytest.raises(StoreError) as exc:
        push(store, "nas", ["team/nothing"])
    assert str(exc.value) == "no ref 'team/nothing' in this store"


def test_a_push_behind_the_remote_in_conflict_with_it_and_forced_over_it(tmp_path):
    """push.push 1 (not forced by default), 46; _push 33-56 (behind: nothing sent; both moved: the conflict's
    words with both ids and the last agreed one), 41, 262-271, 330-336 (--force keeps the remote's id under
    refs/displaced/ and reports it)."""
    from artifacts.refs import set_ref
    from artifacts.remotes.config import add_remote
    from artifacts.remotes.pointers import both_moved, displaced_ref
    from artifacts.remotes.pull import pull
    from artifacts.remotes.push import push

    remote = tmp_path / "remote"
    a = store_pushing_to(tmp_path, "a", remote, {"team/x": b"x1" * 40, "team/y": b"y" * 40, "team/z": b"z" * 40})
    push(a, "nas")
    b, _ = Store.init(tmp_path / "b")
    add_remote(b, "nas", str(remote))
    pull(b, "nas")
    ids = local_refs(a)
    x1, y, z = ids["team/x"], ids["team/y"], ids["team/z"]

    set_ref(a, "team/x", y)
    push(a, "nas")
    behind = push(b, "nas", ["team/x"])
    assert (behind.behind, behind.moved, behind.conflicts) == (["team/x"], {}, [])

    set_ref(b, "team/x", z)
    conflict = push(b, "nas", ["team/x"])
    assert conflict.conflicts == [both_moved("team/x", "nas", z, y, x1)]
    assert conflict.moved == {} and remote_files(remote, "refs")["team/x"] == f"{y}\n".encode()
    assert conflict.conflicts[0].startswith(f"ref team/x: moved on both sides since {x1[:12]}: this store has {z[:12]}")

    forced = push(b, "nas", ["team/x"], force=True)
    kept = displaced_ref("team/x", y)
    assert (forced.moved, forced.displaced) == ({"team/x": [y, z]}, {"team/x": kept})
    assert remote_files(remote, "refs")["team/x"] == f"{z}\n".encode()
    assert remote_files(remote, "refs")[kept] == f"{y}\n".encode()


@pytest.mark.parametrize("race", ["moved", "deleted"])
def test_a_ref_the_remote_moves_during_the_push_is_a_conflict_and_the_rest_still_move(tmp_path, monkeypatch, race):
    """_push 287-315: the swap loses to another store (the ref moved or was deleted meanwhile): that ref is a
    conflict naming what the remote has now, is neither tracked nor agreed on, and the refs after it move."""
    from artifacts.ingest import add_path
    from artifacts.refs import set_ref
    from artifacts.remotes.pointers import both_moved, merge_bases, tracking_refs
    from artifacts.remotes.push import push

    remote = tmp_path / "remote"
    store = store_pushing_to(tmp_path, "a", remote, {"team/a": b"alpha" * 100, "team/b": b"beta" * 50})
    push(store, "nas")
    before = local_refs(store)
    (tmp_path / "c.bin").write_bytes(b"gamma" * 30)
    other = add_path(store, tmp_path / "c.bin", "replay")[0]
    set_ref(store, "team/a", before["team/b"])
    set_ref(store, "team/b", before["team/a"])
    real_swap = DirBackend.swap

    def racing_swap(backend, key, data, expect):
        if key == "refs/team/a" and expect is not None:
            if race == "moved":
                real_swap(backend, key, f"{other}\n".encode(), expect)
            else:
                backend.delete(key, expect)
        return real_swap(backend, key, data, expect)

    monkeypatch.setattr(DirBackend, "swap", racing_swap)
    report = push(store, "nas", ["team/a", "team/b"])
    now = other if race == "moved" else None
    assert report.conflicts == [both_moved("team/a", "nas", before["team/b"], now, before["team/a"])]
    assert report.moved == {"team/b": [before["team/b"], before["team/a"]]}
    assert tracking_refs(store, "nas")["team/a"] == before["team/a"]
    assert merge_bases(store, "nas")["team/a"] == before["team/a"]
    assert tracking_refs(store, "nas")["team/b"] == before["team/a"]


def test_a_partial_clone_pushes_what_the_remote_has_but_not_what_no_one_has(tmp_path):
    """_push 158-162 (an object neither this store nor the remote has: one line naming it, nothing sent),
    _local_closure 10-15 (a missing object is not read, only checked)."""
    from artifacts.refs import set_ref
    from artifacts.remotes.config import add_remote
    from artifacts.remotes.pull import pull
    from artifacts.remotes.push import push

    remote = tmp_path / "remote"
    a = store_pushing_to(tmp_path, "a", remote, {"team/a": b"alpha" * 100, "team/b": b"beta" * 50})
    push(a, "nas")
    b, _ = Store.init(tmp_path / "b")
    add_remote(b, "nas", str(remote))
    pull(b, "nas", only={"handoff"})
    absent = set(a.iter_object_ids()) - set(b.iter_object_ids())
    assert absent
    set_ref(b, "team/copy", local_refs(a)["team/a"])
    assert set(push(b, "nas", ["team/copy"]).moved) == {"team/copy"}  # the remote has the data: fine

    (tmp_path / "other").mkdir()
    add_remote(b, "other", str(tmp_path / "other"))
    with pytest.raises(StoreError) as exc:
        push(b, "other")
    assert str(exc.value) == (
        f"object {min(absent)[:12]} is not in this store (a partial clone) and remote other lacks it too; "
        "pull it from the remote that has it first"
    )
    assert remote_files(tmp_path / "other", "refs") == {}


def test_push_runs_its_transfers_on_the_jobs_it_is_given_or_the_default(tmp_path, monkeypatch):
    """push.push 47, 57 (jobs given, or the default when not), _push 148, 187-198 (each transfer on them)."""
    import artifacts.remotes.push as push_module

    seen: list[int] = []
    real_parallel = push_module.parallel

    def recording_parallel(fn, items, jobs):
        seen.append(jobs)
        return real_parallel(fn, items, jobs)

    monkeypatch.setattr(push_module, "parallel", recording_parallel)
    monkeypatch.setenv("ACCRUE_REMOTE_JOBS", "5")
    remote = tmp_path / "remote"
    store = store_pushing_to(tmp_path, "a", remote, {"team/a": b"alpha" * 100})
    push_module.push(store, "nas", jobs=3)
    assert seen and set(seen) == {3}
    seen.clear()
    (tmp_path / "n.bin").write_bytes(b"new")
    from artifacts.ingest import add_path

    add_path(store, tmp_path / "n.bin", "replay", ref="team/n")
    push_module.push(store, "nas")
    assert seen and set(seen) == {5}


# ----------------------------------------------------------------------------- remotes.logsegment
def test_a_log_segment_is_the_whole_lines_since_the_last_push_as_an_audit_log_artifact(tmp_path):
    """logsegment.next_segment 1-99: no log, no whole line since `start` (a line being written waits), the
    lines since as one file artifact chained to the segment before, and a log shorter than `start` (replaced)
    sent again from its start with no previous segment; 49, 51, 54: a last line without a time leaves the
    segment's time empty."""
    import socket

    from artifacts.auditlog import append_event
    from artifacts.hashing import canonical_json
    from artifacts.manifests import MANIFEST_FORMAT
    from artifacts.remotes.logsegment import KIND, Segment, next_segment

    store, _ = Store.init(tmp_path / "store")
    previous = "p" * 64
    assert next_segment(store, "sid", previous, 0) is None
    events = [append_event(store, "custom", note=f"event {n}") for n in range(3)]
    log = store.log_path.read_bytes()
    lines = log.splitlines(keepends=True)
    store.log_path.write_bytes(log + b'{"seq": 3, "half')  # being appended right now

    def expected(data: bytes, first: int, last: int, inputs: dict) -> Segment:
        manifest = {
            "type": "artifact",
            "format": MANIFEST_FORMAT,
            "kind": KIND,
            "producer": {"store": "sid", "host": socket.gethostname()},
            "inputs": inputs,
            "config": {},
            "code_version": "",
            "created": events[last]["ts"],
            "meta": {"first_seq": first, "last_seq": last, "events": last - first + 1},
            "layout": "file",
            "content": hash_bytes(data),
            "size": len(data),
            "files": 1,
            "name": "events.jsonl",
        }
        raw = canonical_json(manifest)
        return Segment(hash_bytes(raw), raw, hash_bytes(data), data, len(log))

    assert KIND == "audit-log"
    assert next_segment(store, "sid", previous, len(lines[0])) == expected(
        b"".join(lines[1:]), 1, 2, {"previous": previous}
    )
    size = store.log_path.stat().st_size
    assert next_segment(store, "sid", previous, len(log)) is None
    assert next_segment(store, "sid", previous, size) is None  # as long as the log: not replaced
    assert next_segment(store, "sid", previous, size + 1) == expected(log, 0, 2, {})
    assert next_segment(store, "sid", None, 0) == expected(log, 0, 2, {})
    store.log_path.write_bytes(log + b'{"seq": 3, "event": "no time"}\n')  # a line without ts (hand-made)
    assert json.loads(next_segment(store, "sid", None, len(log)).manifest)["created"] == ""


# ----------------------------------------------------------------------------- remotes.config: the store's id
def test_a_stores_id_is_made_once_where_it_lives_and_a_copy_is_refused_until_rekeyed(tmp_path):
    """config.store_id 1-18 (made once, random, with the folder it was made in; an older store's id kept when
    its folder is recorded later), check_not_copied 1-24 (no id yet: None; a copy elsewhere refused word for
    word, a moved store or one whose record is an inode marker or unreadable accepted)."""
    import re

    from artifacts.remotes.config import check_not_copied, store_id

    store, _ = Store.init(tmp_path / "store")
    assert check_not_copied(store) is None
    sid = store_id(store)
    assert re.fullmatch(r"[0-9a-f]{32}", sid)
    home = {"path": str(store.root.resolve()), "ino": store.root.stat().st_ino}
    assert (store.read_config()["store_id"], store.read_config()["store_home"]) == (sid, home)
    assert store_id(store) == sid and check_not_copied(store) == sid

    shutil.copytree(store.root, tmp_path / "copy")
    copy = Store.open(tmp_path / "copy")
    refusal = (
        f"this store's id {sid[:12]} was made in another directory (a copy, e.g. cp -a?); "
        "run `accrue remote rekey` to give this copy its own id"
    )
    for call in (check_not_copied, store_id):
        with pytest.raises(StoreError) as exc:
            call(copy)
        assert str(exc.value) == refusal

    os.rename(tmp_path / "store", tmp_path / "moved")
    assert check_not_copied(Store.open(tmp_path / "moved")) == sid  # same inode: moved, not copied

    for marker, copied in ((copy.root.stat().st_ino + 1, True), (copy.root.stat().st_ino, False), ("?", False)):
        copy.update_config(lambda c, m=marker: c.update(store_home=m))
        if copied:
            with pytest.raises(StoreError):
                check_not_copied(copy)
        else:
            assert check_not_copied(copy) == sid

    copy.update_config(lambda c: c.pop("store_home"))  # an older store: an id without its folder
    assert check_not_copied(copy) is None
    assert store_id(copy) == sid
    assert copy.read_config()["store_home"] == {"path": str(copy.root.resolve()), "ino": copy.root.stat().st_ino}


# ----------------------------------------------------------------------------- remotes: listing, connecting, threads
def test_a_remotes_object_listing_keeps_only_names_that_are_ids(tmp_path):
    """Backend.remote_object_ids 1-18: the id is the fan-out folder and the file name together; other names
    (too short, not hex, no folder) are not objects."""
    oid = hash_bytes(b"an object")
    other = hash_bytes(b"another")

    class Listed(DirBackend):
        def list_sizes(self, prefix):
            assert prefix == "objects/blake3"
            return {
                f"objects/blake3/{oid[:2]}/{oid[2:]}": 9,
                f"{other[:2]}/{other[2:]}": 7,
                f"objects/blake3/{oid[:2]}/{oid[2:-1]}": 8,
                f"objects/blake3/zz/{'g' * 62}": 1,
                oid: 3,
            }

    assert Listed(parse_url("nas", str(tmp_path))).remote_object_ids() == {oid: 9, other: 7}


def test_a_remote_is_opened_by_its_kind(tmp_path):
    """connect.open_backend 1-5."""
    from artifacts.remotes.connect import open_backend
    from artifacts.remotes.s3 import S3Backend

    assert type(open_backend(parse_url("nas", str(tmp_path)))) is DirBackend
    s3 = open_backend(parse_url("cloud", "s3://bucket/prefix"))
    assert type(s3) is S3Backend and s3.spec.name == "cloud"


def test_remote_transfers_use_16_threads_unless_the_environment_says_otherwise(monkeypatch):
    """transfer.default_jobs 1-13 (never fewer than one)."""
    from artifacts.remotes.transfer import default_jobs

    monkeypatch.delenv("ACCRUE_REMOTE_JOBS", raising=False)
    assert default_jobs() == 16
    for text, jobs in (("3", 3), ("1", 1), ("0", 1), ("-4", 1)):
        monkeypatch.setenv("ACCRUE_REMOTE_JOBS", text)
        assert default_jobs() == jobs


def test_parallel_keeps_the_order_runs_at_most_jobs_at_once_and_raises_the_first_failure():
    """transfer.parallel 1-38: one item or one job runs here; more run on at most `jobs` named threads, results
    in the items' order; a failure stops what has not started and is raised as itself."""
    import time

    from artifacts.remotes.transfer import parallel

    here = threading.current_thread().name
    assert parallel(lambda i: (i, threading.current_thread().name), [7], 4) == [(7, here)]
    assert parallel(lambda i: (i, threading.current_thread().name), [1, 2, 3], 1) == [(1, here), (2, here), (3, here)]
    assert parallel(lambda i: i, [], 4) == []

    running, most, lock = [0], [0], threading.Lock()
    first_three = threading.Barrier(3, timeout=10)  # the first three items wait until all three run at once

    def work(i):
        with lock:
            running[0] += 1
            most[0] = max(most[0], running[0])
        if i < 3:
            first_three.wait()
        with lock:
            running[0] -= 1
        return i * 10, threading.current_thread().name

    out = parallel(work, range(12), 3)
    assert [r for r, _ in out] == [i * 10 for i in range(12)]
    assert most[0] == 3 and all(name.startswith("accrue-remote") for _, name in out)

    def thread_name(_item):
        return threading.current_thread().name

    for items, jobs in ((2, 8), (4, 2)):  # two items, or two jobs, already go on threads
        assert all(n.startswith("accrue-remote") for n in parallel(thread_name, range(items), jobs))

    started = []

    def fail_first(i):
        started.append(i)
        if i == 0:
            raise KeyError("the first failed")
        time.sleep(0.2)
        return i

    with pytest.raises(KeyError, match="the first failed"):
        parallel(fail_first, range(40), 2)
    assert len(started) < 40


def test_a_push_that_loses_its_log_pointer_to_another_store_moves_no_ref(tmp_path, monkeypatch):
    """_push 212-228: the log pointer's swap, after the objects and before any ref, lost to a store pushing
    under the same id: one line naming the id, and no ref moved."""
    from artifacts.hashing import hash_bytes as digest
    from artifacts.remotes.config import store_id
    from artifacts.remotes.push import push

    remote = tmp_path / "remote"
    store = store_pushing_to(tmp_path, "a", remote, {"team/a": b"alpha" * 100})
    real_swap = DirBackend.swap

    def raced(backend, key, data, expect):
        if key.startswith("logs/"):
            real_swap(backend, key, f"{digest(b'another log')}\n".encode(), expect)
        return real_swap(backend, key, data, expect)

    monkeypatch.setattr(DirBackend, "swap", raced)
    with pytest.raises(StoreError) as exc:
        push(store, "nas")
    sid = store_id(store)
    assert str(exc.value) == (
        f"remote nas: another store pushed an audit log with this store's id {sid[:12]} (a copied store?); "
        "no ref was moved; run `accrue remote rekey` in the copy, then push again"
    )
    assert remote_files(remote, "refs") == {}


def test_a_push_decides_by_what_it_last_agreed_on_not_by_a_later_fetch(tmp_path):
    """_push 337-344: push records the ids both sides agreed on; a fetch that only moves the tracking refs
    does not make this store's older id look like the newer one, so the push is behind, not a rewind."""
    from artifacts.refs import set_ref
    from artifacts.remotes.config import add_remote
    from artifacts.remotes.pull import fetch, pull
    from artifacts.remotes.push import push

    remote = tmp_path / "remote"
    b = store_pushing_to(tmp_path, "b", remote, {"team/x": b"x1" * 40, "team/y": b"y" * 40})
    push(b, "nas")
    x1, y = local_refs(b)["team/x"], local_refs(b)["team/y"]
    a, _ = Store.init(tmp_path / "a")
    add_remote(a, "nas", str(remote))
    pull(a, "nas")
    set_ref(a, "team/x", y)
    push(a, "nas")
    fetch(b, "nas")  # b's tracking ref now says y; b itself still has x1
    report = push(b, "nas", ["team/x"])
    assert (report.behind, report.moved) == (["team/x"], {})
    assert remote_files(remote, "refs")["team/x"] == f"{y}\n".encode() != f"{x1}\n".encode()


def test_a_store_that_lost_its_log_position_starts_its_log_chain_again_from_the_first_line(tmp_path):
    """_push 93, 94, 110: with no record of the last segment sent, the whole log goes again as a segment with no
    previous one (not chained onto the remote's); 102: a segment names the store that wrote it."""
    from artifacts.remotes.config import store_id
    from artifacts.remotes.pointers import state_dir
    from artifacts.remotes.push import push

    remote = tmp_path / "remote"
    store = store_pushing_to(tmp_path, "a", remote, {"team/a": b"alpha" * 100})
    push(store, "nas")
    (state_dir(store, "nas") / "log.json").unlink()
    report = push(store, "nas")
    oid = report.log_segment
    segment = remote_manifest(remote, oid)
    assert segment["inputs"] == {} and segment["meta"]["first_seq"] == 0
    assert segment["producer"]["store"] == store_id(store)


def test_a_wiped_remote_is_refused_until_remote_init_then_gets_the_whole_log_again_and_every_ref(tmp_path):
    """_push 83 (no log on the remote is no other store's log), 38, 112 (the segment starts from the log's first
    line, not where the last push to the lost remote ended), 122-125 (refs this store tracked that the remote
    no longer has are not proof it holds their objects); check_remote_config (a remote this store used is
    never made again by a push); create.init_remote (what the store knew of the old remote is forgotten)."""
    from artifacts.remotes.create import init_remote
    from artifacts.remotes.push import push

    remote = tmp_path / "remote"
    store = store_pushing_to(tmp_path, "a", remote, {"team/a": b"alpha" * 100})
    push(store, "nas")
    shutil.rmtree(remote)
    remote.mkdir()  # emptied, as a wiped (or another, empty) disk would be
    with pytest.raises(StoreError, match="holds no accrue store, but this store has used it before"):
        push(store, "nas")
    assert list(remote.iterdir()) == []
    assert init_remote(store, "nas") is True and init_remote(store, "nas") is False
    refs = local_refs(store)
    report = push(store, "nas")
    assert report.moved == {name: [None, oid] for name, oid in refs.items()}
    assert set(remote_object_sizes(remote)) >= set(store.iter_object_ids())
    oid = report.log_segment
    segment = remote_manifest(remote, oid)
    assert segment["inputs"] == {} and segment["meta"]["first_seq"] == 0


def test_a_push_reads_each_manifest_once_however_many_refs_reach_it(tmp_path, monkeypatch):
    """_local_closure 9: what the walk has seen is remembered, so a manifest many refs name is read once."""
    from artifacts.refs import set_ref
    from artifacts.remotes.push import push

    remote = tmp_path / "remote"
    store = store_pushing_to(tmp_path, "a", remote, {"team/a": b"alpha" * 100})
    aid = local_refs(store)["team/a"]
    for n in range(5):
        set_ref(store, f"team/copy{n}", aid, log=False)
    reads = []
    real_read_json = Store.read_json
    monkeypatch.setattr(Store, "read_json", lambda s, oid: reads.append(oid) or real_read_json(s, oid))
    push(store, "nas")
    assert reads.count(aid) == 1


def test_a_push_of_a_ref_that_names_no_manifest_is_refused_naming_the_object(tmp_path):
    """_local_closure 19-24: JSON of another shape is named in one line, and nothing moves."""
    from artifacts.refs import set_ref
    from artifacts.remotes.push import push

    remote = tmp_path / "remote"
    store = store_pushing_to(tmp_path, "a", remote, {"team/a": b"alpha" * 100})
    note = store.put_json({"type": "note", "text": "not a manifest"})
    set_ref(store, "team/note", note, log=False)
    with pytest.raises(StoreError) as exc:
        push(store, "nas")
    assert str(exc.value) == f"object {note[:12]} is not a manifest"
    assert remote_files(remote, "refs") == {}


def test_parallel_raises_the_failure_that_came_first_once_the_running_transfers_have_ended():
    """transfer.parallel 31 (the first failure in time, not the first item in order, is raised), 33, 37 (the
    transfers already running end before it is raised: none is left writing behind the caller's back)."""
    import time

    from artifacts.remotes.transfer import parallel

    finished = []

    def work(i):
        if i == 0:
            time.sleep(1.0)  # long enough that the other item has failed first, even on a busy machine
            finished.append(i)
            raise ValueError("a later failure")
        raise KeyError("the first failure")

    with pytest.raises(KeyError, match="the first failure"):
        parallel(work, range(2), 2)
    assert finished == [0]
