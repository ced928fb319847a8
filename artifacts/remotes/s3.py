"""An S3-compatible remote through obstore: conditional writes (If-Match / If-None-Match) move
refs, and every failure (credentials, bucket, network) becomes one StoreError line."""

from __future__ import annotations

import contextlib
import os
import re
import threading
from datetime import timedelta
from pathlib import Path
from typing import Iterator

import blake3

from artifacts.errors import StoreError
from artifacts.hashing import CHUNK_SIZE
from artifacts.remotes.backends import SINGLE_PUT_MAX, Backend, MissingOnRemote, RefMoved, local_corrupt, object_key
from artifacts.remotes.config import RemoteSpec


def _seconds(name: str, default: str) -> float:
    raw = os.environ.get(name, default)
    try:
        value = float(raw)
    except ValueError:
        value = -1.0
    if not 0 < value < 1e6:
        raise StoreError(f"${name}={raw!r}: not a number of seconds")
    return value


def endpoint_of(spec: RemoteSpec) -> str | None:
    env = os.environ
    return (
        spec.settings.get("endpoint")
        or env.get("AWS_ENDPOINT_URL_S3")
        or env.get("AWS_ENDPOINT_URL")
        or env.get("AWS_ENDPOINT")
    )


def aws_files(env) -> tuple[Path, Path]:
    """The config and credentials files boto3 reads: where AWS_CONFIG_FILE and AWS_SHARED_CREDENTIALS_FILE
    point, else ~/.aws/config and ~/.aws/credentials."""
    home = Path.home() / ".aws"
    config = env.get("AWS_CONFIG_FILE") or home / "config"
    credentials = env.get("AWS_SHARED_CREDENTIALS_FILE") or home / "credentials"
    return Path(config).expanduser(), Path(credentials).expanduser()


def _s3_store(spec: RemoteSpec):
    from obstore.store import S3Store

    env = os.environ
    endpoint = endpoint_of(spec)
    # A server that accepts and never answers ends the command within ~30 s: a read that waits
    # READ_TIMEOUT for bytes fails, and is retried only while the first try began < RETRY_WINDOW ago.
    read_s = _seconds("ACCRUE_REMOTE_READ_TIMEOUT", "10")
    client = {
        "connect_timeout": timedelta(seconds=_seconds("ACCRUE_REMOTE_CONNECT_TIMEOUT", "5")),
        "read_timeout": timedelta(seconds=read_s),
        "timeout": timedelta(seconds=_seconds("ACCRUE_REMOTE_TIMEOUT", "3600")),  # a whole (big) request
    }
    if endpoint and endpoint.startswith("http://"):
        client["allow_http"] = True
    retries = int(env.get("ACCRUE_REMOTE_RETRIES", "3"))
    retry = {
        "max_retries": retries,
        "retry_timeout": timedelta(seconds=min(15.0, read_s * 1.5) if retries else 1),
        "backoff": {"init_backoff": timedelta(milliseconds=100), "max_backoff": timedelta(seconds=2), "base": 2},
    }
    kwargs: dict = {}
    if endpoint:
        # obstore lets AWS_ENDPOINT_URL_S3 win over `endpoint`: give it endpoint_of's choice too, so a
        # remote's own endpoint setting is where requests go (and what the error lines name)
        kwargs["endpoint"] = kwargs["aws_endpoint_url_s3"] = endpoint
    region = spec.settings.get("region")
    if region:
        kwargs["region"] = region
    profile = spec.settings.get("profile") or env.get("AWS_PROFILE")
    provider = None
    has_keys = env.get("AWS_ACCESS_KEY_ID") and env.get("AWS_SECRET_ACCESS_KEY")
    config_file, credentials_file = aws_files(env)
    if spec.settings.get("profile") or (
        not has_keys and (profile or config_file.is_file() or credentials_file.is_file())
    ):
        # profiles (~/.aws/config, SSO, assume-role) are boto3's job; obstore takes it as a provider
        import boto3
        from botocore.exceptions import ProfileNotFound
        from obstore.auth.boto3 import Boto3CredentialProvider

        try:
            session = boto3.Session(profile_name=profile)
        except ProfileNotFound:
            # S3Backend names the remote in front of this
            raise StoreError(f"no AWS profile {profile!r} in {config_file} or {credentials_file}") from None
        if session.get_credentials() is not None:
            provider = Boto3CredentialProvider(session)
            if not region and session.region_name:
                kwargs["region"] = session.region_name
    return S3Store(
        spec.bucket,
        prefix=spec.prefix or None,
        client_options=client,
        retry_config=retry,
        credential_provider=provider,
        **kwargs,
    )


MULTIPART_CONCURRENCY = 16
_S3_CODE = re.compile(r"<Code>([A-Za-z]+)</Code>")


def _botocore_code(exc: BaseException) -> str:
    response = getattr(exc, "response", None)
    error = response.get("Error") if isinstance(response, dict) else None
    return str(error.get("Code") or "") if isinstance(error, dict) else ""


def _no_such_bucket(exc: BaseException) -> bool:
    """S3 said the bucket is missing: its error code, never the text elsewhere in the message (a prefix or
    bucket named "NoSuchBucket" is in the URL there). A HEAD answer has no body, hence no code: a missing bucket
    then reads as a missing object."""
    return (_S3_CODE.search(str(exc)) or [None, ""])[1] == "NoSuchBucket"


def explain_s3_error(exc: BaseException, where: str, endpoint: str | None = None) -> StoreError:
    text = str(exc)
    # obstore puts S3's XML error body in its text; botocore parses it into `response["Error"]["Code"]`
    code = (_S3_CODE.search(text) or [None, ""])[1] or _botocore_code(exc)
    low = text.lower()
    if code == "NoSuchBucket":
        return StoreError(f"{where}: the bucket does not exist (create it, or fix the URL)")
    if code in (
        "InvalidAccessKeyId",
        "SignatureDoesNotMatch",
        "AccessDenied",
        "InvalidToken",
        "ExpiredToken",
        "AuthorizationHeaderMalformed",
    ) or type(exc).__name__ in ("PermissionDeniedError", "UnauthenticatedError"):
        return StoreError(
            f"{where}: access denied ({code or type(exc).__name__}); check AWS_ACCESS_KEY_ID / "
            "AWS_SECRET_ACCESS_KEY or AWS_PROFILE"
        )
    if "169.254.169.254" in text or "credential" in low and "error" in low:
        return StoreError(
            f"{where}: no AWS credentials found; set AWS_ACCESS_KEY_ID and AWS_SECRET_ACCESS_KEY, "
            "or a profile (`accrue remote set NAME profile PROFILE`)"
        )
    if any(
        s in low
        for s in (
            "error sending request",
            "connection refused",
            "dns error",
            "timed out",  # also "operation timed out"
            "tcp connect",
            "connect error",
            "failed to lookup",
            "connection reset",
            "could not connect to the endpoint",  # botocore's EndpointConnectionError
            "deadline has elapsed",
        )
    ):
        endpoint = endpoint or "AWS S3"
        return StoreError(
            f"{where}: cannot reach {endpoint} (no answer, or the connection failed); check the network "
            "and the endpoint (`accrue remote set NAME endpoint URL`, or AWS_ENDPOINT_URL)"
        )
    first = text.strip().splitlines()[0] if text.strip() else type(exc).__name__
    return StoreError(f"{where}: {code + ': ' if code else ''}{first[:200]}")


class S3Backend(Backend):
    def __init__(self, spec: RemoteSpec) -> None:
        self.spec = spec
        self._lock, self._abandoned = threading.Lock(), None
        try:
            self.store = _s3_store(spec)
        except Exception as exc:  # noqa: BLE001 - bad configuration values, unknown keys
            raise StoreError(f"{self.describe()}: {str(exc).splitlines()[0][:200]}") from None

    @contextlib.contextmanager
    def _errors(self) -> Iterator[None]:
        from obstore.exceptions import BaseError

        try:
            yield
        except StoreError:
            raise
        except RefMoved:
            raise
        except FileNotFoundError as exc:
            if _no_such_bucket(exc):
                raise explain_s3_error(exc, self.describe(), endpoint_of(self.spec)) from None
            raise
        except (BaseError, OSError) as exc:
            raise explain_s3_error(exc, self.describe(), endpoint_of(self.spec)) from None

    def get_bytes(self, key: str) -> bytes | None:
        got = self.read_versioned(key)
        return got[0] if got else None

    def read_versioned(self, key: str) -> tuple[bytes, str] | None:
        import obstore

        with self._errors():
            try:
                result = obstore.get(self.store, key)
                data = bytes(result.bytes())
            except FileNotFoundError as exc:
                if _no_such_bucket(exc):
                    raise
                return None
        return data, result.meta["e_tag"] or ""

    def put_bytes(self, key: str, data: bytes) -> None:
        import obstore

        with self._errors():
            obstore.put(self.store, key, data, use_multipart=False)

    def swap(self, key: str, data: bytes, expect: str | None) -> str:
        import obstore
        from obstore.exceptions import AlreadyExistsError, PreconditionError

        mode = "create" if expect is None else {"e_tag": expect}
        with self._errors():
            try:
                result = obstore.put(self.store, key, data, mode=mode)
            # moved, or deleted meanwhile (If-Match's 404), unless the 404 is for the bucket: obstore reports
            # that as a failed precondition too
            except (AlreadyExistsError, PreconditionError, FileNotFoundError) as exc:
                if _no_such_bucket(exc):
                    raise
                raise RefMoved(key) from None
        return result["e_tag"] or ""

    def delete(self, key: str, expect: str) -> None:
        # One conditional request (DELETE If-Match, which obstore cannot send): the server compares
        # and deletes at once, so a push that moved the ref meanwhile keeps it (412, RefMoved).
        # A read-then-delete would lose a push landing between the two.
        from botocore.exceptions import BotoCoreError, ClientError

        base = f"{self.spec.prefix}/" if self.spec.prefix else ""
        try:
            self._boto3().delete_object(Bucket=self.spec.bucket, Key=base + key, IfMatch=expect)
        except ClientError as exc:
            err = exc.response.get("Error", {})
            status = exc.response.get("ResponseMetadata", {}).get("HTTPStatusCode")
            if err.get("Code") != "NoSuchBucket" and (status in (404, 412) or err.get("Code") == "PreconditionFailed"):
                raise RefMoved(key) from None  # moved, or deleted by someone else
            raise explain_s3_error(exc, self.describe(), endpoint_of(self.spec)) from None
        except BotoCoreError as exc:
            raise explain_s3_error(exc, self.describe(), endpoint_of(self.spec)) from None

    def remove(self, key: str) -> None:
        import obstore

        with self._errors():
            try:
                obstore.delete(self.store, key)
            except FileNotFoundError as exc:
                if _no_such_bucket(exc):
                    raise

    def list_aged(self, prefix: str) -> dict[str, tuple[int, float]]:
        return {m["path"]: (m["size"], m["last_modified"].timestamp()) for m in self._list(prefix)}

    def _boto3(self):
        import boto3
        from botocore.config import Config

        session = boto3.Session(profile_name=self.spec.settings.get("profile") or None)
        region = self.spec.settings.get("region") or session.region_name or os.environ.get("AWS_REGION")
        config = Config(  # the same limits as obstore's client: a silent endpoint ends in one line
            connect_timeout=_seconds("ACCRUE_REMOTE_CONNECT_TIMEOUT", "5"),
            read_timeout=_seconds("ACCRUE_REMOTE_READ_TIMEOUT", "10"),
            # botocore's `max_attempts` counts retries; `total_max_attempts` counts tries, like obstore's N + 1
            retries={"total_max_attempts": int(os.environ.get("ACCRUE_REMOTE_RETRIES", "3")) + 1, "mode": "standard"},
        )
        return session.client(
            "s3", endpoint_url=endpoint_of(self.spec), region_name=region or "us-east-1", config=config
        )

    def unfinished_uploads(self) -> list[tuple[str, float, object]]:
        """Unfinished multipart uploads under this remote (obstore cannot list them; boto3 can)."""
        from botocore.exceptions import BotoCoreError, ClientError

        base = f"{self.spec.prefix}/" if self.spec.prefix else ""
        out = []
        try:
            pages = self._boto3().get_paginator("list_multipart_uploads").paginate(Bucket=self.spec.bucket, Prefix=base)
            for page in pages:
                for u in page.get("Uploads", []):
                    key = u["Key"][len(base) :]
                    out.append((f"{key} (multipart upload)", u["Initiated"].timestamp(), (key, u["UploadId"])))
        except (BotoCoreError, ClientError) as exc:
            raise explain_s3_error(exc, self.describe(), endpoint_of(self.spec)) from None
        return out

    def drop_upload(self, handle: object) -> None:
        from botocore.exceptions import BotoCoreError, ClientError

        key, upload_id = handle  # type: ignore[misc]
        base = f"{self.spec.prefix}/" if self.spec.prefix else ""
        try:
            self._boto3().abort_multipart_upload(Bucket=self.spec.bucket, Key=base + key, UploadId=upload_id)
        except (BotoCoreError, ClientError) as exc:
            raise explain_s3_error(exc, self.describe(), endpoint_of(self.spec)) from None

    def _list(self, prefix: str) -> Iterator[dict]:
        import obstore

        with self._errors():
            for batch in obstore.list(self.store, prefix.rstrip("/") + "/", chunk_size=1000):
                yield from batch

    def list_sizes(self, prefix: str) -> dict[str, int]:
        return {m["path"]: m["size"] for m in self._list(prefix)}

    def list_versions(self, prefix: str) -> dict[str, str]:
        return {m["path"]: m["e_tag"] or "" for m in self._list(prefix)}

    def head(self, key: str) -> int | None:
        import obstore

        with self._errors():
            try:
                return obstore.head(self.store, key)["size"]
            except FileNotFoundError:  # a HEAD answer has no body: a missing bucket reads as a missing object
                return None

    def upload_object(self, oid: str, path: Path, size: int, replace: bool = False) -> None:
        import obstore  # a PUT replaces whatever the key held, so `replace` needs nothing more here

        key = object_key(oid)
        if size > SINGLE_PUT_MAX and self.resume_before is not None and self._resume(oid, path, size):
            return
        if size <= SINGLE_PUT_MAX:
            data = path.read_bytes()
            if blake3.blake3(data).hexdigest() != oid:
                raise local_corrupt(oid)
            with self._errors():
                obstore.put(self.store, key, data, use_multipart=False)
            return

        def chunks() -> Iterator[bytes]:
            # hashed on the way out; a mismatch raises before the last part, which aborts the
            # multipart upload, so a damaged local copy never becomes a remote object
            hasher, sent = blake3.blake3(max_threads=1), 0
            with open(path, "rb") as f:
                while chunk := f.read(CHUNK_SIZE):
                    hasher.update(chunk)
                    sent += len(chunk)
                    if sent >= size and (sent != size or hasher.hexdigest() != oid):
                        raise local_corrupt(oid)
                    yield chunk
            if sent != size:
                raise local_corrupt(oid)

        with self._errors():
            # multipart: parts of CHUNK_SIZE, up to MULTIPART_CONCURRENCY in flight (obstore's
            # default 5 MiB x 12 measured ~15% slower than a plain upload of the same file)
            obstore.put(self.store, key, chunks(), chunk_size=CHUNK_SIZE, max_concurrency=MULTIPART_CONCURRENCY)

    def _abandoned_uploads(self) -> dict[str, list[str]]:
        """Unfinished multipart uploads of objects begun before resume_before: key -> uploads (one listing
        per push, made on the first big object)."""
        with self._lock:
            if self._abandoned is None:
                begun = sorted(
                    (started, handle)
                    for _what, started, handle in self.unfinished_uploads()
                    if handle[0].startswith("objects/") and started < (self.resume_before or 0)
                )
                self._abandoned = {}
                for _started, (key, upload_id) in reversed(begun):  # the newest first
                    self._abandoned.setdefault(key, []).append(upload_id)
            return self._abandoned

    def _resume(self, oid: str, path: Path, size: int) -> bool:
        """Finish the newest abandoned multipart upload of this object: the parts already there are kept when
        their MD5 (their ETag) is that of the same bytes here, the rest sent, and the whole file hashed to oid on
        the way. False (nothing done) when there is none or its parts are not this file's: the caller uploads."""
        import hashlib

        from botocore.exceptions import BotoCoreError, ClientError

        key = object_key(oid)
        uploads = self._abandoned_uploads().get(key)
        if not uploads:
            return False
        upload_id = uploads[0]
        full = (f"{self.spec.prefix}/" if self.spec.prefix else "") + key
        client = self._boto3()
        count = -(-size // CHUNK_SIZE)
        try:
            parts = [
                part
                for page in client.get_paginator("list_parts").paginate(
                    Bucket=self.spec.bucket, Key=full, UploadId=upload_id
                )
                for part in page.get("Parts", [])
            ]
            have = {}
            for part in parts:
                n = part["PartNumber"]
                want = min(CHUNK_SIZE, size - (n - 1) * CHUNK_SIZE) if 1 <= n <= count else -1
                if part["Size"] != want:
                    return False  # another part size: not a push of this object (left for prune)
                have[n] = part["ETag"].strip('"')
            hasher, kept, todo = blake3.blake3(max_threads=1), {}, []
            with open(path, "rb") as f:
                for n in range(1, count + 1):
                    chunk = f.read(CHUNK_SIZE)
                    hasher.update(chunk)
                    if have.get(n) == hashlib.md5(chunk, usedforsecurity=False).hexdigest():
                        kept[n] = have[n]
                    else:
                        todo.append(n)
            if hasher.hexdigest() != oid:
                raise local_corrupt(oid)
            if not kept:
                return False  # nothing worth keeping: a fresh upload is as fast

            def send(n: int) -> tuple[int, str]:
                with open(path, "rb") as f:
                    f.seek((n - 1) * CHUNK_SIZE)
                    body = f.read(CHUNK_SIZE)
                got = client.upload_part(Bucket=self.spec.bucket, Key=full, UploadId=upload_id, PartNumber=n, Body=body)
                return n, got["ETag"].strip('"')

            from artifacts.remotes.transfer import parallel

            for n, etag in parallel(send, todo, MULTIPART_CONCURRENCY):
                kept[n] = etag
            client.complete_multipart_upload(
                Bucket=self.spec.bucket,
                Key=full,
                UploadId=upload_id,
                MultipartUpload={"Parts": [{"PartNumber": n, "ETag": f'"{kept[n]}"'} for n in sorted(kept)]},
            )
        except ClientError as exc:
            if exc.response.get("Error", {}).get("Code") in ("NoSuchUpload", "InvalidPart", "InvalidPartOrder"):
                return False  # finished or dropped meanwhile (a prune): upload afresh
            raise explain_s3_error(exc, self.describe(), endpoint_of(self.spec)) from None
        except BotoCoreError as exc:
            raise explain_s3_error(exc, self.describe(), endpoint_of(self.spec)) from None
        with self._lock:
            self.resumed += (f"{oid[:12]}: {len(kept) - len(todo)} of {count} parts were there",)
            uploads.pop(0)
        return True

    def download_to(self, key: str, fd: int) -> tuple[str, int]:
        import obstore

        hasher, total = blake3.blake3(max_threads=1), 0
        with self._errors():
            try:
                result = obstore.get(self.store, key)
            except FileNotFoundError as exc:
                if _no_such_bucket(exc):
                    raise
                raise MissingOnRemote(f"{self.describe()}: lacks {key}") from None
            for chunk in result.stream(min_chunk_size=CHUNK_SIZE):
                view = memoryview(chunk)
                hasher.update(view)
                written = 0
                while written < len(view):
                    written += os.write(fd, view[written:])
                total += len(view)
        return hasher.hexdigest(), total
