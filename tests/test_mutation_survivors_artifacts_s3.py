"""Tests written to kill mutants of artifacts/remotes/s3.py that survived mutmut's fourth sweep
(docs/MUTATION.md, "The fourth sweep"): the boto3 paths of the S3 remote (`S3Backend.delete`, the client
`_boto3` builds, `unfinished_uploads`, `drop_upload`) and `explain_s3_error`. Each docstring names the
mutmut ids it kills.

What they pin: a ref is deleted only at the version it was told, with or without a prefix; a moved or
vanished ref is `RefMoved(key)`, a missing bucket or a refusal an error line naming the remote;
unfinished uploads are listed and aborted under the remote's prefix only; the client signs for the
remote's profile and region, goes to the remote's endpoint, and keeps to ACCRUE_REMOTE_CONNECT_TIMEOUT,
_READ_TIMEOUT and _RETRIES (with their defaults when unset).

The S3 is the suite's moto server (tests/remote_support.py) where moto answers as S3 does; a scripted
stand-in on 127.0.0.1 answers where a test needs a reply moto never gives (a bare 412, a gateway that
cannot reach its backend, silence) or needs to read how a request was signed. No network is used.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import socket
import sys
import threading
import uuid
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from remote_support import S3_ENV, moto_endpoint, s3_client  # noqa: E402,F401

from artifacts.errors import StoreError  # noqa: E402
from artifacts.hashing import hash_bytes  # noqa: E402
from artifacts.remotes.backends import RefMoved  # noqa: E402
from artifacts.remotes.config import parse_url  # noqa: E402
from artifacts.remotes.s3 import S3Backend, aws_files, explain_s3_error  # noqa: E402

KEY = "refs/team/handoff"
WHERE = "remote origin (s3://b/p)"


# ----------------------------------------------------------------------------- environment and servers
@pytest.fixture
def aws(monkeypatch, tmp_path):
    """The suite's test keys, and nothing from this machine's AWS configuration."""
    for k, v in S3_ENV.items():
        monkeypatch.setenv(k, v)
    monkeypatch.setenv("AWS_CONFIG_FILE", str(tmp_path / "aws-config"))
    monkeypatch.setenv("AWS_SHARED_CREDENTIALS_FILE", str(tmp_path / "aws-credentials"))
    for k in (
        "AWS_PROFILE",
        "AWS_DEFAULT_REGION",
        "AWS_MAX_ATTEMPTS",
        "AWS_RETRY_MODE",
        "AWS_ENDPOINT_URL_S3",
        "AWS_ENDPOINT",
    ):
        monkeypatch.delenv(k, raising=False)
    monkeypatch.delenv("AWS_ENDPOINT_URL", raising=False)
    return monkeypatch


@pytest.fixture
def moto(aws, moto_endpoint):
    aws.setenv("AWS_ENDPOINT_URL", moto_endpoint)
    return moto_endpoint


def new_bucket(endpoint: str) -> str:
    bucket = f"b-{uuid.uuid4().hex[:12]}"
    s3_client(endpoint).create_bucket(Bucket=bucket)
    return bucket


def backend(url: str, **settings: str) -> S3Backend:
    return S3Backend(parse_url("origin", url, settings=settings))


class ScriptedS3(ThreadingHTTPServer):
    """Answers every request with `reply` (status, body), or, while `silent`, with nothing until the
    test ends; keeps each request's method, path and headers."""

    daemon_threads = True

    def __init__(self, handler: type[BaseHTTPRequestHandler] | None = None) -> None:
        super().__init__(("127.0.0.1", 0), handler or _Handler)
        self.reply: tuple[int, bytes] = (204, b"")
        self.headers: dict[str, str] = {}  # sent with every reply
        self.silent = False
        self.released = threading.Event()
        self.requests: list[tuple[str, str, dict[str, str]]] = []
        self.url = f"http://127.0.0.1:{self.server_address[1]}"


class _Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    server: ScriptedS3

    def _answer(self) -> None:
        length = int(self.headers.get("Content-Length") or 0)
        if length:
            self.rfile.read(length)
        self.server.requests.append((self.command, self.path, dict(self.headers)))
        if self.server.silent:
            self.server.released.wait(30)
            return
        status, body = self.server.reply
        self.send_response(status)
        self.send_header("Content-Type", "application/xml")
        for name, value in self.server.headers.items():
            self.send_header(name, value)
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    do_GET = do_PUT = do_POST = do_DELETE = do_HEAD = _answer

    def log_message(self, *args) -> None:  # quiet: the test reads self.server.requests
        pass


@contextlib.contextmanager
def serving(server: ScriptedS3, aws):
    """`server` answering on a thread, reached through AWS_ENDPOINT_URL; stopped (its silence released) after."""
    threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True).start()
    aws.setenv("AWS_ENDPOINT_URL", server.url)
    try:
        yield server
    finally:
        server.released.set()
        server.shutdown()
        server.server_close()


@pytest.fixture
def scripted(aws):
    """A scripted S3 reached through AWS_ENDPOINT_URL, tried once (ACCRUE_REMOTE_RETRIES=0)."""
    with serving(ScriptedS3(), aws) as server:
        aws.setenv("ACCRUE_REMOTE_RETRIES", "0")
        yield server


EMPTY_LISTING = b'<?xml version="1.0" encoding="UTF-8"?><ListBucketResult><KeyCount>0</KeyCount></ListBucketResult>'


def s3_error_body(code: str, message: str) -> bytes:
    return f'<?xml version="1.0" encoding="UTF-8"?>\n<Error><Code>{code}</Code><Message>{message}</Message></Error>'.encode()


def signed_as(request_headers: dict[str, str]) -> tuple[str, str]:
    """(access key id, region) of a SigV4-signed request."""
    authorization = {k.lower(): v for k, v in request_headers.items()}["authorization"]  # obstore sends it lower-case
    found = re.search(r"Credential=([^/]+)/\d{8}/([^/]+)/s3/aws4_request", authorization)
    assert found, authorization
    return found.group(1), found.group(2)


def raised_within(seconds: float, call) -> BaseException | None:
    """What `call` raised (None if nothing), failing the test if it is still waiting after `seconds`."""
    box: dict[str, BaseException | None] = {}

    def run() -> None:
        try:
            call()
            box["raised"] = None
        except BaseException as exc:  # noqa: BLE001 - handed to the test
            box["raised"] = exc

    worker = threading.Thread(target=run, daemon=True)
    worker.start()
    worker.join(seconds)
    if worker.is_alive():
        pytest.fail(f"still waiting after {seconds} s")
    return box["raised"]


def refused_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# ----------------------------------------------------------------------------- S3Backend.delete
@pytest.mark.parametrize("prefix", ["/team/store", ""])
def test_a_ref_is_deleted_only_at_the_version_it_was_told(moto, prefix):
    """S3Backend.delete 3, 4 (a remote without a prefix deletes under `None/` or `XXXX`), 10 (no If-Match:
    a moved ref deleted), 12, 15, 24 (a traceback instead of RefMoved), 20, 21, 22, 26–31, 41, 42, 43 (a ref
    deleted by someone else is an error, not RefMoved), 37 (a moved ref is an error), 53 (RefMoved without
    the key)."""
    b = backend(f"s3://{new_bucket(moto)}{prefix}")
    version = b.swap(KEY, b"one\n", None)
    with pytest.raises(RefMoved) as moved:
        b.delete(KEY, '"not-the-version"')
    assert moved.value.args == (KEY,)
    assert b.get_bytes(KEY) == b"one\n"
    b.delete(KEY, version)
    assert b.get_bytes(KEY) is None
    with pytest.raises(RefMoved) as gone:
        b.delete(KEY, version)
    assert gone.value.args == (KEY,)


def assert_names_the_missing_bucket(message: str, where: str) -> None:
    assert message.startswith(f"{where}: ") and "\n" not in message
    assert message == f"{where}: the bucket does not exist (create it, or fix the URL)"


def test_a_ref_deletion_on_a_missing_bucket_is_an_error_naming_the_remote_not_a_moved_ref(moto):
    """S3Backend.delete 13, 17, 18, 19, 32–36, 38, 39, 40 (NoSuchBucket taken for a moved ref), 54, 55, 57, 58
    (the line is not the remote's and the bucket's), 60 (a traceback)."""
    b = backend("s3://no-such-bucket-here/team")
    with pytest.raises(StoreError) as exc:
        b.delete(KEY, '"v"')
    assert_names_the_missing_bucket(str(exc.value), b.describe())


@pytest.mark.parametrize(
    "status,body",
    [
        (412, s3_error_body("PreconditionFailed", "At least one of the pre-conditions you specified did not hold")),
        (412, b""),
        (409, s3_error_body("PreconditionFailed", "At least one of the pre-conditions you specified did not hold")),
    ],
    ids=["412-with-code", "bare-412", "code-only"],
)
def test_a_refused_conditional_delete_is_a_moved_ref_however_the_server_words_it(scripted, status, body):
    """S3Backend.delete 44 (a bare 412, without a body), 45–48, 50–52 (a PreconditionFailed code under another
    status): each is RefMoved(key), the ref having moved."""
    scripted.reply = (status, body)
    with pytest.raises(RefMoved) as moved:
        backend("s3://bucket/team").delete(KEY, '"v"')
    assert moved.value.args == (KEY,)
    method, path, headers = scripted.requests[-1]
    assert (method, path, headers.get("If-Match")) == ("DELETE", f"/bucket/team/{KEY}", '"v"')


def test_a_ref_deletion_the_server_refuses_is_an_error_not_a_moved_ref(scripted):
    """S3Backend.delete 49 (any code but PreconditionFailed taken for a moved ref): a 403 AccessDenied is
    the remote's error line."""
    scripted.reply = (403, s3_error_body("AccessDenied", "Access Denied"))
    b = backend("s3://bucket/team")
    with pytest.raises(StoreError) as exc:
        b.delete(KEY, '"v"')
    assert str(exc.value).startswith(f"{b.describe()}: ") and "AccessDenied" in str(exc.value)


GATEWAY_DOWN = s3_error_body(
    "BadGateway", "upstream connect error or disconnect/reset before headers. reset reason: connection failure"
)


def test_a_gateway_that_cannot_reach_its_backend_is_explained_with_the_remotes_endpoint(scripted):
    """S3Backend.delete 56, 59, unfinished_uploads 34, 37, drop_upload 15, 18 (the endpoint left out: "cannot
    reach AWS S3"): the S3 error says a connection failed, so the line names the endpoint to check."""
    scripted.reply = (502, GATEWAY_DOWN)
    b = backend("s3://bucket/team")
    expected = (
        f"{b.describe()}: cannot reach {scripted.url} (no answer, or the connection failed); check the network "
        "and the endpoint (`accrue remote set NAME endpoint URL`, or AWS_ENDPOINT_URL)"
    )
    for call in (lambda: b.delete(KEY, '"v"'), b.unfinished_uploads, lambda: b.drop_upload(("objects/ab", "u1"))):
        with pytest.raises(StoreError) as exc:
            call()
        assert str(exc.value) == expected


def test_a_ref_deletion_that_cannot_connect_names_the_remote_and_the_endpoint(aws):
    """S3Backend.delete 61, 62, 64, 65 (the line is not the remote's, or loses the error), 63, 66 (the
    endpoint not passed on), 67 (a traceback): a connection refused is one line naming the remote and the
    endpoint it tried, with the hint."""
    endpoint = f"http://127.0.0.1:{refused_port()}"
    aws.setenv("AWS_ENDPOINT_URL", endpoint)
    aws.setenv("ACCRUE_REMOTE_RETRIES", "0")
    b = backend("s3://bucket/team")
    with pytest.raises(StoreError) as exc:
        b.delete(KEY, '"v"')
    message = str(exc.value)
    assert message.startswith(f"{b.describe()}: cannot reach {endpoint} ") and "\n" not in message


# ----------------------------------------------------------------------------- unfinished_uploads, drop_upload
def uploads_under(endpoint: str, bucket: str) -> list[str]:
    return sorted(u["Key"] for u in s3_client(endpoint).list_multipart_uploads(Bucket=bucket).get("Uploads", []))


@pytest.mark.parametrize("prefix", ["team/store", ""])
def test_unfinished_uploads_are_listed_and_dropped_under_the_remotes_prefix_only(moto, prefix):
    """unfinished_uploads 2 (listed from the bucket's root, with the prefix in the key), 3, 4 (a remote
    without a prefix lists under `None/` or `XXXX`), 10 (another prefix's uploads listed); the listed handle
    drops the upload."""
    bucket = new_bucket(moto)
    base = f"{prefix}/" if prefix else ""
    client = s3_client(moto)
    upload_id = client.create_multipart_upload(Bucket=bucket, Key=f"{base}objects/ab/cdef")["UploadId"]
    outside = ["other/objects/ab/cdef"] if prefix else []  # another store's, in the same bucket
    for key in outside:
        client.create_multipart_upload(Bucket=bucket, Key=key)
    b = backend(f"s3://{bucket}/{prefix}" if prefix else f"s3://{bucket}")
    listed = b.unfinished_uploads()
    assert [(label, handle) for label, _, handle in listed] == [
        ("objects/ab/cdef (multipart upload)", ("objects/ab/cdef", upload_id))
    ]
    assert isinstance(listed[0][1], float)
    b.drop_upload(listed[0][2])
    assert b.unfinished_uploads() == []
    assert uploads_under(moto, bucket) == outside


@pytest.mark.parametrize("url,path", [("s3://bucket/team", "/bucket/team/"), ("s3://bucket", "/bucket/")])
def test_an_upload_is_aborted_at_its_own_key_under_the_remotes_prefix(scripted, url, path):
    """drop_upload 3 (the prefix left out), 4, 5 (a remote without a prefix aborts under `None/` or `XXXX`).
    moto aborts an upload by its id alone; S3 answers NoSuchUpload for any other key, and the parts stay."""
    backend(url).drop_upload(("objects/ab/cdef", "u1"))
    assert [(m, p) for m, p, _ in scripted.requests] == [("DELETE", f"{path}objects/ab/cdef?uploadId=u1")]


def test_unfinished_uploads_of_a_missing_bucket_are_an_error_naming_the_remote(moto):
    """unfinished_uploads 32, 33, 35, 36, 38; drop_upload 13, 14, 16, 17, 19 (the line is not the remote's and
    the bucket's, or a traceback)."""
    b = backend("s3://no-such-bucket-here/team")
    for call in (b.unfinished_uploads, lambda: b.drop_upload(("objects/ab/cdef", "u1"))):
        with pytest.raises(StoreError) as exc:
            call()
        assert_names_the_missing_bucket(str(exc.value), b.describe())


# ----------------------------------------------------------------------------- the boto3 client (_boto3)
@pytest.mark.parametrize(
    "settings,env,region",
    [
        ({"region": "eu-west-3"}, {"AWS_REGION": "us-east-1"}, "eu-west-3"),
        ({}, {"AWS_DEFAULT_REGION": "ap-south-1", "AWS_REGION": "eu-north-1"}, "ap-south-1"),
        ({}, {"AWS_REGION": "eu-north-1"}, "eu-north-1"),
        ({}, {}, "us-east-1"),
    ],
    ids=["remote-setting", "aws-default-region", "aws-region", "none"],
)
def test_ref_deletion_is_signed_for_the_remotes_region_and_sent_to_its_endpoint(
    scripted, monkeypatch, settings, env, region
):
    """_boto3 7, 9–12, 55, 59, 64 (the remote's `region` setting ignored), 8 (AWS_REGION over the session's
    region), 14, 15 (AWS_REGION ignored), 65, 66 (no region anywhere: not us-east-1), 54, 58 (the remote's
    `endpoint` setting ignored: the request goes to AWS)."""
    monkeypatch.delenv("AWS_REGION")
    monkeypatch.delenv("AWS_ENDPOINT_URL")  # the remote's own setting names the endpoint
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    backend("s3://bucket/team", endpoint=scripted.url, **settings).delete(KEY, '"v"')
    assert [(m, p) for m, p, _ in scripted.requests] == [("DELETE", f"/bucket/team/{KEY}")]
    assert signed_as(scripted.requests[0][2]) == ("testing", region)


def test_a_remote_with_a_profile_deletes_refs_with_the_profiles_keys_and_region(scripted, monkeypatch, tmp_path):
    """_boto3 2–6 (the remote's `profile` setting ignored: the environment's keys and no region), 8 (AWS_REGION
    over the profile's region)."""
    (tmp_path / "aws-config").write_text(
        "[profile team]\nregion = eu-west-3\naws_access_key_id = TEAMKEY\naws_secret_access_key = teamsecret\n"
    )
    backend("s3://bucket/team", profile="team").delete(KEY, '"v"')
    assert signed_as(scripted.requests[0][2]) == ("TEAMKEY", "eu-west-3")


def test_a_silent_server_ends_a_ref_deletion_after_accrue_remote_read_timeout(scripted, monkeypatch):
    """_boto3 16, 18, 21 (botocore's 60 s), 34, 35 (the 10 s default over the variable)."""
    monkeypatch.setenv("ACCRUE_REMOTE_READ_TIMEOUT", "0.5")
    scripted.silent = True
    b = backend("s3://bucket/team")
    raised = raised_within(4, lambda: b.delete(KEY, '"v"'))
    assert isinstance(raised, StoreError) and str(raised).startswith(f"{b.describe()}: Read timeout")


def test_a_server_that_never_accepts_ends_a_ref_deletion_after_accrue_remote_connect_timeout(aws):
    """_boto3 16, 17, 20 (botocore's 60 s), 27, 28 (the 5 s default over the variable). The listener's one
    queue place is taken, so Linux drops the client's connection attempts unanswered."""
    aws.setenv("ACCRUE_REMOTE_CONNECT_TIMEOUT", "0.5")
    aws.setenv("ACCRUE_REMOTE_RETRIES", "0")
    with socket.socket() as listener, socket.socket() as first:
        listener.bind(("127.0.0.1", 0))
        listener.listen(0)
        first.connect(listener.getsockname())
        aws.setenv("AWS_ENDPOINT_URL", f"http://127.0.0.1:{listener.getsockname()[1]}")
        b = backend("s3://bucket/team")
        raised = raised_within(4, lambda: b.delete(KEY, '"v"'))
    assert isinstance(raised, StoreError) and str(raised).startswith(f"{b.describe()}: Connect timeout")


@pytest.mark.parametrize("retries", ["0", "1"])
def test_a_failing_ref_deletion_is_tried_once_more_than_accrue_remote_retries(scripted, monkeypatch, retries):
    """_boto3 19, 22 (botocore's legacy retries), 39 (one fewer), 45, 46 (the default 3 over the variable),
    48 (one more)."""
    monkeypatch.setenv("ACCRUE_REMOTE_RETRIES", retries)
    scripted.reply = (503, s3_error_body("SlowDown", "Please reduce your request rate."))
    with pytest.raises(StoreError, match="SlowDown"):
        backend("s3://bucket/team").delete(KEY, '"v"')
    # N retries are N + 1 tries, as on obstore's paths (botocore's `max_attempts` gave N + 2)
    assert len(scripted.requests) == int(retries) + 1


def test_the_remote_limits_have_defaults_when_their_variables_are_unset(moto, monkeypatch):
    """_boto3 24, 29 (no default connect timeout: a traceback or a refusal), 42, 44, 47 (no default number of
    retries)."""
    for name in ("ACCRUE_REMOTE_CONNECT_TIMEOUT", "ACCRUE_REMOTE_READ_TIMEOUT", "ACCRUE_REMOTE_RETRIES"):
        monkeypatch.delenv(name, raising=False)
    b = backend(f"s3://{new_bucket(moto)}/team")
    version = b.swap(KEY, b"one\n", None)
    b.delete(KEY, version)
    assert b.get_bytes(KEY) is None
    assert b.unfinished_uploads() == []


# ----------------------------------------------------------------------------- explain_s3_error
class GenericError(Exception):
    pass


def test_an_unreachable_aws_s3_is_named_as_such_when_no_endpoint_is_set():
    """explain_s3_error 87, 88: with no endpoint configured the line says AWS S3."""
    assert str(explain_s3_error(Exception("error sending request"), WHERE, None)) == (
        f"{WHERE}: cannot reach AWS S3 (no answer, or the connection failed); check the network "
        "and the endpoint (`accrue remote set NAME endpoint URL`, or AWS_ENDPOINT_URL)"
    )


def test_an_error_without_text_is_named_by_its_class():
    """explain_s3_error 95 (a traceback), 97 (`NoneType`)."""
    assert str(explain_s3_error(GenericError(), WHERE)) == f"{WHERE}: GenericError"
    assert str(explain_s3_error(GenericError("  \n "), WHERE)) == f"{WHERE}: GenericError"


def test_an_other_s3_error_shows_its_code_then_its_first_line_cut_to_200_characters():
    """explain_s3_error 99 (the code left out), 101 (a traceback), 102 (`XX: XX`), 104 (201 characters)."""
    first = "Generic S3 error: status 503: <Error><Code>SlowDown</Code></Error> " + "x" * 200
    explained = str(explain_s3_error(Exception(f"{first}\nDebug source: retry"), WHERE))
    assert explained == f"{WHERE}: SlowDown: {first[:200]}"


def test_a_missing_object_in_a_bucket_named_nosuchbucket_is_absent_not_an_error(moto):
    """S3Backend.head 8 (the bucket's own name, lower case, taken for S3's NoSuchBucket code)."""
    bucket = f"nosuchbucket-{uuid.uuid4().hex[:12]}"
    s3_client(moto).create_bucket(Bucket=bucket)
    s3_client(moto).put_object(Bucket=bucket, Key="team/objects/here", Body=b"12345")
    b = backend(f"s3://{bucket}/team")
    assert b.head("objects/missing") is None
    assert b.head("objects/here") == 5


def test_a_prefix_named_nosuchbucket_does_not_turn_a_missing_object_into_an_error(moto):
    """A missing bucket is S3's error code, not the text NoSuchBucket anywhere in the message: a remote whose
    prefix is named NoSuchBucket used to fail `head` (and so every push) on each object not yet there.
    Found through S3Backend.head 7, a mutant of a check that is now gone (a HEAD answer carries no code)."""
    bucket = f"b-{uuid.uuid4().hex[:12]}"
    s3_client(moto).create_bucket(Bucket=bucket)
    s3_client(moto).put_object(Bucket=bucket, Key="NoSuchBucket/objects/here", Body=b"123")
    b = backend(f"s3://{bucket}/NoSuchBucket")
    assert b.head("objects/missing") is None
    assert b.get_bytes("objects/missing") is None
    assert b.head("objects/here") == 3


@pytest.mark.parametrize(
    "call", ["get_bytes", "read_versioned", "put_bytes", "create", "swap", "remove", "download_to"]
)
def test_a_missing_bucket_is_one_error_line_from_every_call_that_gets_an_answer_body(moto, tmp_path, call):
    """S3 names a missing bucket in the body of its 404: a read, a write, a removal, a download and a swap of
    a ref all say the bucket does not exist instead of "no such key" (a ref read as absent, an object as
    lacking, a swap as a ref moved by someone else). Only HEAD, whose answer has no body, cannot tell a
    missing bucket from a missing key. Kills _no_such_bucket 3, 7, 8, 9. Found the swap with an expected
    version reporting RefMoved (obstore turns If-Match's 404 into a failed precondition), now fixed."""
    b = backend(f"s3://missing-{uuid.uuid4().hex[:12]}/team")
    with (tmp_path / "download").open("wb") as out:
        calls = {
            "get_bytes": lambda: b.get_bytes(KEY),
            "read_versioned": lambda: b.read_versioned(KEY),
            "put_bytes": lambda: b.put_bytes(KEY, b"v1"),
            "create": lambda: b.swap(KEY, b"v1", None),
            "swap": lambda: b.swap(KEY, b"v2", '"an-etag"'),
            "remove": lambda: b.remove(KEY),
            "download_to": lambda: b.download_to("objects/ab/cd", out.fileno()),
        }
        with pytest.raises(StoreError) as raised:
            calls[call]()
    assert str(raised.value) == f"{b.describe()}: the bucket does not exist (create it, or fix the URL)"
    assert b.head(KEY) is None


# ============================================================================= round 9 batch Y
# ----------------------------------------------------------------------------- S3Backend.download_to
def test_downloading_an_object_the_bucket_lacks_names_the_remote_and_the_key(moto, tmp_path):
    """S3Backend.download_to 11 (the message None): a pull that meets an object the remote lost stops on
    this line (MissingOnRemote is a StoreError), the same as a directory remote's."""
    from artifacts.remotes.backends import MissingOnRemote

    bucket = new_bucket(moto)
    b = backend(f"s3://{bucket}/team")
    with (tmp_path / "download").open("wb") as out:
        with pytest.raises(MissingOnRemote) as raised:
            b.download_to("objects/blake3/ab/cd", out.fileno())
    assert str(raised.value) == f"remote origin (s3://{bucket}/team): lacks objects/blake3/ab/cd"


def test_an_object_larger_than_a_chunk_downloads_whole_with_its_id_and_full_size(moto, tmp_path):
    """S3Backend.download_to 25 (the size of the last chunk returned for the whole): an object over two
    CHUNK_SIZEs arrives as several chunks; the size returned is all of them."""
    from artifacts.hashing import CHUNK_SIZE

    bucket = new_bucket(moto)
    data = bytes(range(256)) * ((2 * CHUNK_SIZE + 4096) // 256)
    s3_client(moto).put_object(Bucket=bucket, Key="team/objects/big", Body=data)
    with (tmp_path / "download").open("wb") as out:
        got = backend(f"s3://{bucket}/team").download_to("objects/big", out.fileno())
    assert got == (hash_bytes(data), len(data))
    assert (tmp_path / "download").read_bytes() == data


class ShortWrites:
    """The os module, except that a write takes at most `most` bytes (as a pipe, a socket or some network
    filesystems may), and a disk that fills after `room` bytes."""

    def __init__(self, most: int, room: int) -> None:
        self.most, self.room, self.calls = most, room, 0

    def __getattr__(self, name: str):
        return getattr(os, name)

    def write(self, fd: int, data) -> int:
        self.calls += 1
        if self.room <= 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        n = os.write(fd, bytes(data[: min(self.most, self.room)]))
        self.room -= n
        return n


def test_a_download_whose_writes_fall_short_still_writes_every_byte_once(moto, tmp_path, monkeypatch):
    """S3Backend.download_to 19 (the bytes written so far replaced by the last write's count: each short
    write sends the chunk's tail again, until the disk is full): the file holds the object exactly."""
    import artifacts.remotes.s3

    bucket = new_bucket(moto)
    data = bytes(range(256)) * 400  # 102400 bytes: seven writes of at most 16 KiB or more
    s3_client(moto).put_object(Bucket=bucket, Key="team/objects/one", Body=data)
    b = backend(f"s3://{bucket}/team")
    short = ShortWrites(most=16384, room=10 * len(data))
    monkeypatch.setattr(artifacts.remotes.s3, "os", short)
    with (tmp_path / "download").open("wb") as out:
        got = b.download_to("objects/one", out.fileno())
    assert got == (hash_bytes(data), len(data))
    assert (tmp_path / "download").read_bytes() == data
    assert short.calls >= 7  # every write fell short: at least ceil(102400 / 16384), however the body was chunked


# ============================================================================= round 10 batch S
# ----------------------------------------------------------------------------- S3Backend.upload_object
def pending_uploads(endpoint: str, bucket: str) -> list[str]:
    return sorted(u["Key"] for u in s3_client(endpoint).list_multipart_uploads(Bucket=bucket).get("Uploads", []))


def local_corrupt_line(oid: str) -> str:
    return (
        f"object {oid[:12]} in this store is corrupt (its bytes no longer match its id); "
        "nothing corrupt is pushed — run `accrue verify --full`"
    )


def test_an_object_over_single_put_max_arrives_whole_through_a_multipart_upload(moto, tmp_path):
    """S3Backend.upload_object 18 (no hasher: a traceback), 19 (`max_threads=None`: a TypeError), 21 (one byte
    counted before the first), 22–27 (the file not opened, or opened as text or with a bad mode), 29 (the hasher
    fed None), 30, 31 (the bytes sent miscounted), 32 (a part before the last taken for the end), 35, 36 (a
    whole, sound file refused at its last part), 38 (refused after its last part): a file just over
    SINGLE_PUT_MAX (three parts of CHUNK_SIZE, the last 4 KiB) lands on the remote byte for byte, as one
    multipart object, and no upload is left pending."""
    from artifacts.remotes.backends import SINGLE_PUT_MAX, object_key

    bucket = new_bucket(moto)
    data = os.urandom(SINGLE_PUT_MAX + 4096)
    oid = hash_bytes(data)
    path = tmp_path / "object"
    path.write_bytes(data)
    backend(f"s3://{bucket}/team").upload_object(oid, path, len(data))
    got = s3_client(moto).get_object(Bucket=bucket, Key=f"team/{object_key(oid)}")
    assert got["Body"].read() == data
    assert got["ETag"].endswith('-3"')  # parts of CHUNK_SIZE: 8 MiB, 8 MiB, 4 KiB
    assert pending_uploads(moto, bucket) == []


@pytest.mark.parametrize(
    "damage",
    ["last-byte-changed", "first-byte-changed", "one-byte-short", "one-byte-long", "small-byte-changed"],
)
def test_a_damaged_local_copy_is_refused_in_one_line_and_leaves_nothing_on_the_remote(moto, tmp_path, damage):
    """S3Backend.upload_object 33, 34 (a file of the right length whose bytes changed is hashed only when it is
    longer than `size`: the corrupt object is pushed), 37 (the line's id None: a TypeError traceback, and the
    multipart upload's fate left to the traceback), 8 (the same for an object under SINGLE_PUT_MAX).
    Whether the bytes changed, or the file is shorter or longer than `size`, the push stops on the one line,
    no object lands under the id's key and no multipart upload is left pending."""
    from artifacts.remotes.backends import SINGLE_PUT_MAX, object_key

    bucket = new_bucket(moto)
    data = os.urandom(4096 if damage.startswith("small") else SINGLE_PUT_MAX + 4096)
    oid = hash_bytes(data)
    on_disk = {
        "last-byte-changed": data[:-1] + bytes([data[-1] ^ 1]),
        "first-byte-changed": bytes([data[0] ^ 1]) + data[1:],
        "one-byte-short": data[:-1],
        "one-byte-long": data + b"\0",
        "small-byte-changed": data[:-1] + bytes([data[-1] ^ 1]),
    }[damage]
    path = tmp_path / "object"
    path.write_bytes(on_disk)
    b = backend(f"s3://{bucket}/team")
    with pytest.raises(StoreError) as raised:
        b.upload_object(oid, path, len(data))
    assert str(raised.value) == local_corrupt_line(oid)
    assert b.head(object_key(oid)) is None
    assert b.list_sizes("objects") == {}
    assert pending_uploads(moto, bucket) == []


@pytest.mark.parametrize("size", ["6MiB", "SINGLE_PUT_MAX"])
def test_an_object_up_to_single_put_max_is_one_plain_put_whose_etag_is_its_md5(moto, tmp_path, size):
    """S3Backend.upload_object 4 (an object of exactly SINGLE_PUT_MAX sent in two parts), 12, 16 (obstore's
    own choice: multipart above its 5 MiB default chunk), 17 (always multipart); list_versions 3 (every
    version listed as ""). Up to SINGLE_PUT_MAX an object travels in one request (backends.py), so S3 keeps
    it as a plain object whose ETag is the MD5 of its bytes (what `aws s3 sync`, rclone and S3's own
    integrity checks compare against), not a multipart ETag ("…-N") that no client can check; the listing
    shows that ETag as the object's version."""
    import hashlib

    from artifacts.remotes.backends import SINGLE_PUT_MAX, object_key

    bucket = new_bucket(moto)
    data = os.urandom(6 * 1024 * 1024 if size == "6MiB" else SINGLE_PUT_MAX)
    oid = hash_bytes(data)
    path = tmp_path / "object"
    path.write_bytes(data)
    b = backend(f"s3://{bucket}/team")
    b.upload_object(oid, path, len(data))
    etag = f'"{hashlib.md5(data).hexdigest()}"'
    got = s3_client(moto).get_object(Bucket=bucket, Key=f"team/{object_key(oid)}")
    assert (got["ETag"], got["Body"].read() == data) == (etag, True)
    assert b.list_versions("objects") == {object_key(oid): etag}
    assert pending_uploads(moto, bucket) == []


class _MultipartSink(BaseHTTPRequestHandler):
    """A multipart-upload endpoint that keeps the parts' bytes hashed, in part order, and reads each body in
    small pieces (so that what the test measures is the uploader's memory, not the server's)."""

    protocol_version = "HTTP/1.1"
    server: ScriptedS3

    def _answer(self) -> None:
        left, pieces = int(self.headers.get("Content-Length") or 0), []
        while left > 0:
            piece = self.rfile.read(min(left, 65536))
            left -= len(piece)
            pieces.append(piece)
        headers, body = {}, b""
        if self.command == "POST" and self.path.endswith("?uploads="):
            body = b"<InitiateMultipartUploadResult><UploadId>u1</UploadId></InitiateMultipartUploadResult>"
        elif self.command == "POST":
            body = b'<CompleteMultipartUploadResult><ETag>"done-1"</ETag></CompleteMultipartUploadResult>'
        else:
            found = re.search(r"partNumber=(\d+)", self.path)
            self.server.parts[int(found.group(1)) if found else 0] = hash_bytes(b"".join(pieces))
            headers["ETag"] = '"part"'
        self.send_response(200)
        for k, v in headers.items():
            self.send_header(k, v)
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    do_PUT = do_POST = do_DELETE = _answer

    def log_message(self, *args) -> None:
        pass


def test_a_multipart_upload_holds_parts_in_memory_not_the_whole_object(aws, tmp_path, monkeypatch):
    """S3Backend.upload_object 28 (`f.read(None)`: the whole object read into memory as one piece before the
    first part is sent, so pushing a checkpoint larger than the machine's memory fails). The file is read a
    CHUNK_SIZE at a time: with parts of 64 KiB (obstore in flight at most MULTIPART_CONCURRENCY of them),
    pushing a 12 MiB object never holds half of it in Python memory. Every part arrives, in order."""
    import tracemalloc

    import artifacts.remotes.s3

    part, whole = 64 * 1024, 12 * 1024 * 1024
    monkeypatch.setattr(artifacts.remotes.s3, "CHUNK_SIZE", part)
    monkeypatch.setattr(artifacts.remotes.s3, "SINGLE_PUT_MAX", part)
    server = ScriptedS3(_MultipartSink)
    server.parts = {}
    data = os.urandom(whole)
    oid = hash_bytes(data)
    path = tmp_path / "object"
    path.write_bytes(data)
    with serving(server, aws):
        b = backend("s3://bucket/team")
        tracemalloc.start()
        try:
            b.upload_object(oid, path, len(data))
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
    assert peak < whole // 2, f"{peak} bytes traced at the peak"
    assert [server.parts[n] for n in sorted(server.parts)] == [
        hash_bytes(data[i : i + part]) for i in range(0, whole, part)
    ]


class _PartsInFlight(_MultipartSink):
    """A multipart sink that holds each part until `target` parts are in flight at once (or 5 s pass), and
    keeps the most it saw."""

    def _answer(self) -> None:
        server = self.server
        if self.command == "PUT":
            with server.lock:
                server.in_flight += 1
                server.peak = max(server.peak, server.in_flight)
                if server.in_flight >= server.target:
                    server.enough.set()
            server.enough.wait(5)
        try:
            super()._answer()
        finally:
            if self.command == "PUT":
                with server.lock:
                    server.in_flight -= 1

    do_PUT = do_POST = do_DELETE = _answer


def test_a_multipart_upload_keeps_multipart_concurrency_parts_in_flight(aws, tmp_path, monkeypatch):
    """S3Backend.upload_object 49 (obstore's default of 12 parts in flight instead of MULTIPART_CONCURRENCY,
    the figure measured for a big checkpoint's push, backends.py): the setting reaches the wire. The sink
    holds every part until MULTIPART_CONCURRENCY are in flight together; no more ever are."""
    import artifacts.remotes.s3

    part = 64 * 1024
    concurrency = artifacts.remotes.s3.MULTIPART_CONCURRENCY
    monkeypatch.setattr(artifacts.remotes.s3, "CHUNK_SIZE", part)
    monkeypatch.setattr(artifacts.remotes.s3, "SINGLE_PUT_MAX", part)
    server = ScriptedS3(_PartsInFlight)
    server.parts, server.lock, server.enough = {}, threading.Lock(), threading.Event()
    server.in_flight, server.peak, server.target = 0, 0, concurrency
    data = os.urandom(part * (concurrency + 2))
    path = tmp_path / "object"
    path.write_bytes(data)
    with serving(server, aws):
        backend("s3://bucket/team").upload_object(hash_bytes(data), path, len(data))
    assert server.peak == concurrency
    assert len(server.parts) == concurrency + 2


# ----------------------------------------------------------------------------- S3Backend.list_versions
def test_a_listing_without_etags_gives_no_version_and_one_with_them_gives_each_etag(scripted):
    """S3Backend.list_versions 6 (a key listed without an ETag gets the version "XXXX"; some S3-compatible
    servers leave it out): no version is "", which read_pointers takes as "unknown, read the ref", never as a
    version to compare with the cache; an ETag listed is the version."""
    scripted.reply = (
        200,
        b'<?xml version="1.0" encoding="UTF-8"?>'
        b'<ListBucketResult xmlns="http://s3.amazonaws.com/doc/2006-03-01/"><Name>bucket</Name>'
        b"<Prefix>team/refs/</Prefix><KeyCount>2</KeyCount><MaxKeys>1000</MaxKeys><IsTruncated>false</IsTruncated>"
        b"<Contents><Key>team/refs/main</Key><LastModified>2026-12-01T00:00:00.000Z</LastModified>"
        b"<Size>65</Size><StorageClass>STANDARD</StorageClass></Contents>"
        b"<Contents><Key>team/refs/dev</Key><LastModified>2026-12-01T00:00:00.000Z</LastModified>"
        b'<ETag>"abc"</ETag><Size>65</Size><StorageClass>STANDARD</StorageClass></Contents></ListBucketResult>',
    )
    assert backend("s3://bucket/team").list_versions("refs") == {"refs/main": "", "refs/dev": '"abc"'}
    assert [(m, p) for m, p, _ in scripted.requests] == [("GET", "/bucket?list-type=2&prefix=team%2Frefs%2F")]


# ----------------------------------------------------------------------------- S3Backend.put_bytes
@pytest.mark.parametrize("size", [65, 6 * 1024 * 1024])
def test_bytes_put_to_s3_are_one_plain_put_whose_etag_is_their_md5(moto, size):
    """S3Backend.put_bytes 9 (always multipart), 4, 8 (obstore's own choice: multipart above its 5 MiB
    chunk, e.g. the manifest of a tree of many files, pushed by put_bytes). A ref, a lease or a manifest is
    one request, so S3 keeps a plain object whose ETag is the MD5 of its bytes (what a ref's compare-and-swap
    and other S3 clients check), not a multipart ETag ("…-N")."""
    import hashlib

    bucket = new_bucket(moto)
    data = os.urandom(size)
    backend(f"s3://{bucket}/team").put_bytes("objects/ab/cdef", data)
    got = s3_client(moto).get_object(Bucket=bucket, Key="team/objects/ab/cdef")
    assert (got["ETag"], got["Body"].read() == data) == (f'"{hashlib.md5(data).hexdigest()}"', True)
    assert pending_uploads(moto, bucket) == []


# ----------------------------------------------------------------------------- S3Backend.read_versioned, swap
def test_an_answer_with_an_empty_etag_gives_the_version_unknown_not_a_made_up_one(scripted):
    """S3Backend.read_versioned 12, swap 23 (a GET or PUT answered with an empty ETag gives the version
    "XXXX"; obstore refuses an answer with no ETag at all). An empty ETag is the version "": unknown, so the
    next compare-and-swap reads the ref again rather than sending an If-Match no server could match."""
    b = backend("s3://bucket/team")
    scripted.headers = {"ETag": ""}
    scripted.reply = (200, b"ref bytes\n")
    assert b.read_versioned("refs/main") == (b"ref bytes\n", "")
    scripted.reply = (200, b"")
    assert b.swap("refs/main", b"new\n", None) == ""
    assert [m for m, _p, _h in scripted.requests] == ["GET", "PUT"]


def test_a_remote_that_cannot_be_opened_is_one_line_with_the_cause_cut_at_200_characters(aws):
    """S3Backend.__init__ 7 (the cause cut at 201): a setting pasted wrong (here a whole paragraph) does not
    fill the screen; the line keeps the remote's name and the first 200 characters of why."""
    raw = "x" * 300
    aws.setenv("ACCRUE_REMOTE_READ_TIMEOUT", raw)
    with pytest.raises(StoreError) as raised:
        backend("s3://bucket/team")
    cause = f"$ACCRUE_REMOTE_READ_TIMEOUT={raw!r}: not a number of seconds"
    assert str(raised.value) == f"remote origin (s3://bucket/team): {cause[:200]}"


# ----------------------------------------------------------------------------- _seconds
@pytest.mark.parametrize("raw", ["soon", "0", "-3", "1e6", "nan"])
def test_a_timeout_setting_that_is_no_positive_number_of_seconds_is_refused_in_one_line(aws, raw):
    """s3._seconds 8 (a setting that is no number: a TypeError traceback), 9 (taken as 1 second), 13 (0
    accepted: every request would time out at once). The remote is not opened; the line names the setting
    and the value as the user wrote it."""
    aws.setenv("ACCRUE_REMOTE_CONNECT_TIMEOUT", raw)
    with pytest.raises(StoreError) as raised:
        backend("s3://bucket/team").list_sizes("refs")
    assert (
        str(raised.value)
        == f"remote origin (s3://bucket/team): $ACCRUE_REMOTE_CONNECT_TIMEOUT={raw!r}: not a number of seconds"
    )


# ----------------------------------------------------------------------------- S3Backend._list
def test_a_prefix_lists_the_keys_under_it_written_with_or_without_its_slash(moto):
    """S3Backend._list 8, 9 (a prefix written with its trailing slash listed as "refs//": nothing). A
    prefix names a folder, as on a directory remote: "refs" and "refs/" list the keys under refs/, and
    not those of a sibling whose name merely starts the same."""
    bucket = new_bucket(moto)
    b = backend(f"s3://{bucket}/team")
    b.put_bytes("refs/main", b"a\n")
    b.put_bytes("refs-old/main", b"bb\n")
    assert b.list_sizes("refs/") == b.list_sizes("refs") == {"refs/main": 2}


# ----------------------------------------------------------------------------- endpoint_of
def a_ref_goes_round(b: S3Backend) -> None:
    """Write a ref (obstore), delete it at its version (boto3's conditional DELETE), list it gone (obstore)."""
    b.put_bytes("refs/main", b"a\n")
    b.delete("refs/main", b.list_versions("refs")["refs/main"])
    assert b.list_sizes("refs") == {}


def test_the_s3_specific_endpoint_variable_wins_over_the_general_one(aws, moto_endpoint):
    """endpoint_of 9, 10 (AWS_ENDPOINT_URL_S3 not read: the remote is sought at AWS_ENDPOINT_URL). As in
    the AWS tools, the service-specific AWS_ENDPOINT_URL_S3 is used before AWS_ENDPOINT_URL, which here
    points at a port where nothing listens: by every request, including the conditional DELETE that boto3
    sends (obstore reads AWS_ENDPOINT_URL_S3 itself; boto3 is given the endpoint), and by the line that
    says the endpoint cannot be reached."""
    aws.setenv("ACCRUE_REMOTE_RETRIES", "0")
    aws.setenv("AWS_ENDPOINT_URL", "http://127.0.0.1:9")
    aws.setenv("AWS_ENDPOINT_URL_S3", moto_endpoint)
    bucket = new_bucket(moto_endpoint)
    a_ref_goes_round(backend(f"s3://{bucket}/team"))
    aws.setenv("AWS_ENDPOINT_URL_S3", "http://127.0.0.1:7")
    with pytest.raises(StoreError) as raised:
        backend(f"s3://{bucket}/team").list_sizes("refs")
    assert "cannot reach http://127.0.0.1:7 " in str(raised.value)


def test_a_remotes_own_endpoint_setting_wins_over_aws_endpoint_url_s3(aws, moto_endpoint):
    """A remote given its endpoint (`accrue remote set NAME endpoint URL`) is reached there even when
    AWS_ENDPOINT_URL_S3 names another S3 service (obstore alone lets the variable win: the push went to the
    other service, and its failure named the remote's endpoint)."""
    aws.setenv("ACCRUE_REMOTE_RETRIES", "0")
    aws.setenv("AWS_ENDPOINT_URL_S3", "http://127.0.0.1:7")
    bucket = new_bucket(moto_endpoint)
    b = backend(f"s3://{bucket}/team", endpoint=moto_endpoint)
    b.put_bytes("refs/main", b"a\n")
    assert b.list_sizes("refs") == {"refs/main": 2}


def test_the_older_aws_endpoint_variable_is_the_last_one_read(aws, moto_endpoint):
    """endpoint_of 14, 15, 16 (AWS_ENDPOINT not read: obstore reads it itself but refuses its http://
    without allow_http, and boto3's DELETE goes to AWS). With only AWS_ENDPOINT set, every request,
    the conditional DELETE included, goes there."""
    aws.setenv("AWS_ENDPOINT", moto_endpoint)
    bucket = new_bucket(moto_endpoint)
    a_ref_goes_round(backend(f"s3://{bucket}/team"))


# ----------------------------------------------------------------------------- _s3_store
def test_a_remote_with_no_endpoint_anywhere_is_opened_for_aws_itself(aws):
    """_s3_store 36 (`or` for `and`: with no endpoint set, None.startswith is a traceback). A bucket on AWS
    itself needs no endpoint: the remote opens (no request is sent) with obstore's own AWS endpoint."""
    b = backend("s3://bucket/team", region="eu-west-3")
    assert "endpoint" not in b.store.config


def test_a_silent_server_ends_a_listing_after_accrue_remote_read_timeout(scripted, monkeypatch):
    """_s3_store 9, 10 (obstore's read timeout at the 10 s default whatever the variable says). A server that
    accepts and never answers ends the command in one line once ACCRUE_REMOTE_READ_TIMEOUT passes."""
    monkeypatch.setenv("ACCRUE_REMOTE_READ_TIMEOUT", "0.5")
    scripted.silent = True
    raised = raised_within(5, lambda: backend("s3://bucket/team").list_sizes("refs"))
    assert isinstance(raised, StoreError), raised


def test_a_request_is_cut_at_accrue_remote_timeout_however_long_reads_may_wait(scripted, monkeypatch):
    """_s3_store 33, 34 (the whole request's limit at the 3600 s default whatever the variable says). With
    reads allowed 30 s, a silent server still ends the request at ACCRUE_REMOTE_TIMEOUT."""
    monkeypatch.setenv("ACCRUE_REMOTE_READ_TIMEOUT", "30")
    monkeypatch.setenv("ACCRUE_REMOTE_TIMEOUT", "0.5")
    scripted.silent = True
    raised = raised_within(5, lambda: backend("s3://bucket/team").list_sizes("refs"))
    assert isinstance(raised, StoreError), raised


@pytest.mark.parametrize("retries", [0, 2])
def test_a_server_error_is_tried_accrue_remote_retries_more_times(scripted, monkeypatch, retries):
    """_s3_store 50, 51 (obstore's retries at the default 3 whatever the variable says): a listing answered
    503 each time is sent 1 + ACCRUE_REMOTE_RETRIES times, then fails in one line."""
    monkeypatch.setenv("ACCRUE_REMOTE_RETRIES", str(retries))
    scripted.reply = (503, s3_error_body("SlowDown", "Please reduce your request rate."))
    with pytest.raises(StoreError):
        backend("s3://bucket/team").list_sizes("refs")
    assert len(scripted.requests) == 1 + retries


def test_a_silent_server_is_tried_again_only_within_the_retry_window(scripted, monkeypatch):
    """_s3_store 53, 56, 57 (obstore's own retry window, 180 s: every retry spent on a server that never
    answers). A read that timed out is retried only while the first try began less than 1.5 read timeouts
    ago: with reads of 0.5 s and 3 retries allowed, a silent server gets at most 2 requests."""
    monkeypatch.setenv("ACCRUE_REMOTE_READ_TIMEOUT", "0.5")
    monkeypatch.setenv("ACCRUE_REMOTE_RETRIES", "3")
    scripted.silent = True
    raised = raised_within(8, lambda: backend("s3://bucket/team").list_sizes("refs"))
    assert isinstance(raised, StoreError), raised
    assert 1 <= len(scripted.requests) <= 2


@pytest.mark.parametrize("read_s, window_s", [("0.5", 0.75), ("4", 6.0), ("20", 15.0)])
def test_the_retry_window_is_one_and_a_half_read_timeouts_and_at_most_15_s(aws, read_s, window_s):
    """_s3_store 53–57, 65–67, 69, 70 (obstore's defaults, 10 retries in a 180 s window backing off up to
    15 s, or another window): what obstore is given, so that a server that accepts and never answers ends
    the command within ~30 s (s3.py). obstore ignores a retry setting it does not know by that exact name."""
    from datetime import timedelta

    aws.setenv("ACCRUE_REMOTE_READ_TIMEOUT", read_s)
    aws.setenv("ACCRUE_REMOTE_RETRIES", "3")
    given = backend("s3://bucket/team").store.retry_config
    assert given == {
        "max_retries": 3,
        "retry_timeout": timedelta(seconds=window_s),
        "backoff": {"init_backoff": timedelta(milliseconds=100), "max_backoff": timedelta(seconds=2), "base": 2.0},
    }


def test_a_remotes_region_setting_signs_its_requests(scripted):
    """_s3_store 88, 89, 90 (the remote's `region` setting ignored: requests signed for the environment's
    AWS_REGION, which a bucket in another region refuses)."""
    scripted.reply = (200, EMPTY_LISTING)
    backend("s3://bucket/team", region="eu-west-3").list_sizes("refs")
    assert signed_as(scripted.requests[0][2]) == ("testing", "eu-west-3")


def test_a_remotes_region_setting_wins_over_its_profiles_region(aws, scripted, tmp_path):
    """_s3_store 129 (the profile's region taken when the remote has its own: requests signed for a region
    the bucket is not in). Without the setting the profile's region signs them."""
    (tmp_path / "aws-config").write_text(
        "[profile team]\nregion = eu-west-3\naws_access_key_id = TEAMKEY\naws_secret_access_key = teamsecret\n"
    )
    for k in ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY", "AWS_REGION"):
        aws.delenv(k)
    scripted.reply = (200, EMPTY_LISTING)
    backend("s3://bucket/team", profile="team", region="ap-south-1").list_sizes("refs")
    backend("s3://bucket/team", profile="team").list_sizes("refs")
    assert [signed_as(headers) for _m, _p, headers in scripted.requests] == [
        ("TEAMKEY", "ap-south-1"),
        ("TEAMKEY", "eu-west-3"),
    ]


@pytest.mark.parametrize(
    "keys, signer",
    [
        ({}, ("TEAMKEY", "eu-west-3")),
        ({"AWS_ACCESS_KEY_ID": "testing", "AWS_SECRET_ACCESS_KEY": "testing"}, ("testing", "us-east-1")),
        ({"AWS_ACCESS_KEY_ID": "half"}, ("TEAMKEY", "eu-west-3")),
    ],
)
def test_aws_profile_signs_requests_unless_the_environment_holds_a_whole_key_pair(
    aws, scripted, tmp_path, keys, signer
):
    """_s3_store 101, 102 (AWS_PROFILE not read: no credentials), 104 (the profile over the environment's
    keys), 105 (an access key id without its secret taken for keys: the profile ignored). As in the AWS
    tools, keys in the environment come before AWS_PROFILE, but only a whole pair of them."""
    (tmp_path / "aws-config").write_text(
        "[profile team]\nregion = eu-west-3\naws_access_key_id = TEAMKEY\naws_secret_access_key = teamsecret\n"
    )
    for k in ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY"):
        aws.delenv(k)
    for k, v in {**keys, "AWS_PROFILE": "team"}.items():
        aws.setenv(k, v)
    scripted.reply = (200, EMPTY_LISTING)
    backend("s3://bucket/team").list_sizes("refs")
    assert signed_as(scripted.requests[0][2]) == signer


@pytest.mark.parametrize("aws_file", ["credentials", "config"])
def test_keys_in_the_home_aws_files_sign_requests_when_the_environment_has_none(aws, scripted, tmp_path, aws_file):
    """_s3_store 112, 116, 117, 118 (~/.aws/credentials or ~/.aws/config not noticed: obstore, which reads
    no AWS files, sends the request without keys). With no keys and no profile in the environment, the
    default profile of ~/.aws signs the requests, whichever of the two files holds it."""
    home = tmp_path / "home"
    (home / ".aws").mkdir(parents=True)
    section = "[default]" if aws_file == "credentials" else "[default]\nregion = eu-west-3"
    (home / ".aws" / aws_file).write_text(f"{section}\naws_access_key_id = HOMEKEY\naws_secret_access_key = s\n")
    aws.setenv("HOME", str(home))
    for k in ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY", "AWS_CONFIG_FILE", "AWS_SHARED_CREDENTIALS_FILE"):
        aws.delenv(k)
    scripted.reply = (200, EMPTY_LISTING)
    backend("s3://bucket/team").list_sizes("refs")
    assert signed_as(scripted.requests[0][2])[0] == "HOMEKEY"


@pytest.mark.parametrize("variable", ["AWS_SHARED_CREDENTIALS_FILE", "AWS_CONFIG_FILE"])
def test_keys_in_the_aws_file_a_variable_names_sign_requests_when_home_has_none(aws, scripted, tmp_path, variable):
    """Keys kept only where AWS_SHARED_CREDENTIALS_FILE or AWS_CONFIG_FILE point (a container, a CI job, a
    second account) sign obstore's requests, as they do boto3's: before round 11 only ~/.aws was looked at,
    so such a remote's objects went unsigned."""
    aws.setenv("HOME", str(tmp_path / "empty-home"))
    for k in ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY", "AWS_CONFIG_FILE", "AWS_SHARED_CREDENTIALS_FILE"):
        aws.delenv(k)
    elsewhere = tmp_path / "team" / "aws-file"
    elsewhere.parent.mkdir()
    elsewhere.write_text("[default]\naws_access_key_id = ELSEWHEREKEY\naws_secret_access_key = s\n")
    aws.setenv(variable, str(elsewhere))
    scripted.reply = (200, EMPTY_LISTING)
    backend("s3://bucket/team").list_sizes("refs")
    assert signed_as(scripted.requests[0][2])[0] == "ELSEWHEREKEY"


def test_aws_files_are_where_their_variables_point_else_in_home(monkeypatch, tmp_path):
    monkeypatch.setenv("HOME", str(tmp_path))
    assert aws_files({}) == (tmp_path / ".aws" / "config", tmp_path / ".aws" / "credentials")
    named = {"AWS_CONFIG_FILE": "~/team/config", "AWS_SHARED_CREDENTIALS_FILE": "/etc/team/keys"}
    assert aws_files(named) == (tmp_path / "team" / "config", Path("/etc/team/keys"))


def test_an_unknown_profile_is_one_line_naming_the_files_it_was_looked_for_in(aws, tmp_path):
    """The files named are the ones boto3 read (AWS_CONFIG_FILE here), not a fixed ~/.aws/config, and the
    remote is named once."""
    with pytest.raises(StoreError) as err:
        backend("s3://bucket/team", profile="nope")
    message = str(err.value)
    files = f"{tmp_path / 'aws-config'} or {tmp_path / 'aws-credentials'}"
    assert message == f"{WHERE.replace('b/p', 'bucket/team')}: no AWS profile 'nope' in {files}"
