"""Two kinds of remote behind one small interface: S3-compatible object storage (through obstore)
and a plain directory (a mounted NAS, a USB disk). Every failure becomes one StoreError line."""

from __future__ import annotations

import contextlib
import os
import re
import time
from datetime import timedelta
from pathlib import Path
from typing import Iterator

import blake3

from artifacts.atomic import fsync_dir, link_into_place, temp_name, write_new_fsynced
from artifacts.errors import StoreError
from artifacts.hashing import CHUNK_SIZE, HASH_NAME, copy_hashing, is_full_id
from artifacts.remotes.config import RemoteSpec

OBJECTS = f"objects/{HASH_NAME}"
# Up to this size an object travels in one request (read and hashed in memory first).
SINGLE_PUT_MAX = 16 * 1024 * 1024


def object_key(oid: str) -> str:
    return f"{OBJECTS}/{oid[:2]}/{oid[2:]}"


class RefMoved(Exception):
    """A compare-and-swap found the remote ref somewhere else."""


class MissingOnRemote(StoreError):
    """The remote does not hold the object asked for."""


class Backend:
    """Keys are '/'-separated paths relative to the remote's root."""

    spec: RemoteSpec

    def describe(self) -> str:
        return f"remote {self.spec.name} ({self.spec.url})"

    # small values
    def get_bytes(self, key: str) -> bytes | None: ...
    def put_bytes(self, key: str, data: bytes) -> None: ...
    def read_versioned(self, key: str) -> tuple[bytes, str] | None: ...
    def swap(self, key: str, data: bytes, expect: str | None) -> str:
        """Write data if the key is still at version expect (None: absent); else RefMoved."""
        ...

    def probe(self, create: bool) -> None:
        """Reach the remote (and make its root if create); raise one clear line if that fails."""
        self.list_sizes("refs")

    # listings
    def list_sizes(self, prefix: str) -> dict[str, int]: ...
    def list_versions(self, prefix: str) -> dict[str, str]: ...
    def head(self, key: str) -> int | None: ...

    # objects
    def upload_object(self, oid: str, path: Path, size: int) -> None:
        """Send a local object; refuse (StoreError) if its bytes do not hash to oid."""
        ...

    def download_to(self, key: str, fd: int) -> tuple[str, int]:
        """Write the remote bytes into fd while hashing them: (id of what arrived, size)."""
        ...

    def remote_object_ids(self) -> dict[str, int]:
        """Every object the remote holds: id -> size (one listing)."""
        out = {}
        for key, size in self.list_sizes(OBJECTS).items():
            parts = key.split("/")
            oid = parts[-2] + parts[-1] if len(parts) >= 2 else ""
            if is_full_id(oid):
                out[oid] = size
        return out


def _local_corrupt(oid: str) -> StoreError:
    return StoreError(
        f"object {oid[:12]} in this store is corrupt (its bytes no longer match its id); "
        "nothing corrupt is pushed — run `accrue verify --full`"
    )


# ============================================================================ S3
def _s3_store(spec: RemoteSpec):
    from obstore.store import S3Store

    env = os.environ
    endpoint = env.get("AWS_ENDPOINT_URL_S3") or env.get("AWS_ENDPOINT_URL") or env.get("AWS_ENDPOINT")
    client = {
        "connect_timeout": timedelta(seconds=float(env.get("ACCRUE_REMOTE_CONNECT_TIMEOUT", "5"))),
        "timeout": timedelta(seconds=float(env.get("ACCRUE_REMOTE_TIMEOUT", "300"))),
    }
    if endpoint and endpoint.startswith("http://"):
        client["allow_http"] = True
    retries = int(env.get("ACCRUE_REMOTE_RETRIES", "3"))
    retry = {
        "max_retries": retries,
        "retry_timeout": timedelta(seconds=30 if retries else 1),
        "backoff": {"init_backoff": timedelta(milliseconds=100), "max_backoff": timedelta(seconds=2), "base": 2},
    }
    kwargs: dict = {}
    if endpoint:
        kwargs["endpoint"] = endpoint
    provider = None
    has_keys = env.get("AWS_ACCESS_KEY_ID") and env.get("AWS_SECRET_ACCESS_KEY")
    aws_files = any((Path.home() / ".aws" / f).is_file() for f in ("credentials", "config"))
    if not has_keys and (env.get("AWS_PROFILE") or aws_files):
        # profiles (~/.aws/config, SSO, assume-role) are boto3's job; obstore takes it as a provider
        import boto3
        from obstore.auth.boto3 import Boto3CredentialProvider

        session = boto3.Session(profile_name=env.get("AWS_PROFILE"))
        if session.get_credentials() is not None:
            provider = Boto3CredentialProvider(session)
    return S3Store(
        spec.bucket,
        prefix=spec.prefix or None,
        client_options=client,
        retry_config=retry,
        credential_provider=provider,
        **kwargs,
    )


_S3_CODE = re.compile(r"<Code>([A-Za-z]+)</Code>")


def explain_s3_error(exc: BaseException, where: str) -> StoreError:
    text = str(exc)
    code = (_S3_CODE.search(text) or [None, ""])[1]
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
    if any(
        s in low
        for s in (
            "error sending request",
            "connection refused",
            "dns error",
            "timed out",
            "tcp connect",
            "connect error",
            "failed to lookup",
            "connection reset",
        )
    ):
        endpoint = os.environ.get("AWS_ENDPOINT_URL_S3") or os.environ.get("AWS_ENDPOINT_URL") or "AWS S3"
        return StoreError(
            f"{where}: cannot reach {endpoint} (connection failed); check the network and AWS_ENDPOINT_URL"
        )
    first = text.strip().splitlines()[0] if text.strip() else type(exc).__name__
    return StoreError(f"{where}: {code + ': ' if code else ''}{first[:200]}")


class S3Backend(Backend):
    def __init__(self, spec: RemoteSpec) -> None:
        self.spec = spec
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
            if "NoSuchBucket" in str(exc):
                raise explain_s3_error(exc, self.describe()) from None
            raise
        except (BaseError, OSError) as exc:
            raise explain_s3_error(exc, self.describe()) from None

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
                if "NoSuchBucket" in str(exc):
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
            except (AlreadyExistsError, PreconditionError):
                raise RefMoved(key) from None
            except FileNotFoundError as exc:  # If-Match on a key deleted meanwhile
                if "NoSuchBucket" in str(exc):
                    raise
                raise RefMoved(key) from None
        return result["e_tag"] or ""

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
            except FileNotFoundError as exc:
                if "NoSuchBucket" in str(exc):
                    raise
                return None

    def upload_object(self, oid: str, path: Path, size: int) -> None:
        import obstore

        key = object_key(oid)
        if size <= SINGLE_PUT_MAX:
            data = path.read_bytes()
            if blake3.blake3(data).hexdigest() != oid:
                raise _local_corrupt(oid)
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
                        raise _local_corrupt(oid)
                    yield chunk
            if sent != size:
                raise _local_corrupt(oid)

        with self._errors():
            obstore.put(self.store, key, chunks())  # multipart: 5 MiB parts, 12 at a time

    def download_to(self, key: str, fd: int) -> tuple[str, int]:
        import obstore

        hasher, total = blake3.blake3(max_threads=1), 0
        with self._errors():
            try:
                result = obstore.get(self.store, key)
            except FileNotFoundError as exc:
                if "NoSuchBucket" in str(exc):
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


# ============================================================================ directory
class DirBackend(Backend):
    """A remote that is a directory. Refs move under an O_EXCL lock file (works on NFS/SMB, where
    kernel locks may not) that is renamed over the ref: readers see the old or the new id."""

    LOCK_WAIT_S = 10.0

    def __init__(self, spec: RemoteSpec) -> None:
        self.spec = spec
        self.root = spec.path

    def _path(self, key: str) -> Path:
        return self.root / key

    def _ensure_root(self) -> None:
        if not self.root.is_dir():
            if not self.root.parent.is_dir():
                raise StoreError(f"{self.describe()}: {self.root.parent} does not exist (is the disk mounted?)")
            try:
                self.root.mkdir(exist_ok=True)
            except OSError as exc:
                raise StoreError(f"{self.describe()}: cannot create {self.root}: {exc.strerror}") from None

    def probe(self, create: bool) -> None:
        if create:
            self._ensure_root()
        elif not self.root.is_dir():
            raise StoreError(f"{self.describe()}: the directory does not exist (is the disk mounted?)")

    def get_bytes(self, key: str) -> bytes | None:
        try:
            return self._path(key).read_bytes()
        except (FileNotFoundError, NotADirectoryError):
            return None
        except OSError as exc:
            raise StoreError(f"{self.describe()}: cannot read {key}: {exc.strerror}") from None

    def read_versioned(self, key: str) -> tuple[bytes, str] | None:
        data = self.get_bytes(key)
        return None if data is None else (data, data.decode(errors="replace"))

    def _write_new(self, final: Path, data: bytes) -> None:
        tmp_dir = self.root / "tmp"
        tmp_dir.mkdir(parents=True, exist_ok=True)
        tmp = temp_name(tmp_dir)
        write_new_fsynced(tmp, data)
        final.parent.mkdir(parents=True, exist_ok=True)
        os.replace(tmp, final)
        fsync_dir(final.parent)

    def put_bytes(self, key: str, data: bytes) -> None:
        self._ensure_root()
        try:
            self._write_new(self._path(key), data)
        except OSError as exc:
            raise StoreError(f"{self.describe()}: cannot write {key}: {exc.strerror}") from None

    def swap(self, key: str, data: bytes, expect: str | None) -> str:
        self._ensure_root()
        target = self._path(key)
        lock = self.root / "locks" / (key + ".lock")
        lock.parent.mkdir(parents=True, exist_ok=True)
        deadline = time.monotonic() + self.LOCK_WAIT_S
        while True:
            try:
                fd = os.open(lock, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
                break
            except FileExistsError:
                if time.monotonic() > deadline:
                    raise StoreError(
                        f"{self.describe()}: {key} is locked by another push ({lock}); "
                        "remove that file if no push is running"
                    ) from None
                time.sleep(0.05)
        try:
            try:
                os.write(fd, data)
                os.fsync(fd)
            finally:
                os.close(fd)
            current = self.read_versioned(key)
            if (current[1] if current else None) != expect:
                raise RefMoved(key)
            target.parent.mkdir(parents=True, exist_ok=True)
            os.replace(lock, target)  # the lock file becomes the ref: atomic
            fsync_dir(target.parent)
        finally:
            lock.unlink(missing_ok=True)
        return data.decode()

    def _walk(self, prefix: str) -> Iterator[tuple[str, Path]]:
        base = self._path(prefix)
        for root, _dirs, files in os.walk(base):
            for name in files:
                path = Path(root) / name
                yield path.relative_to(self.root).as_posix(), path

    def list_sizes(self, prefix: str) -> dict[str, int]:
        if not self.root.is_dir():
            raise StoreError(f"{self.describe()}: the directory does not exist (is the disk mounted?)")
        if prefix == OBJECTS:  # the hot path: two levels of scandir, no per-file Path objects
            out = {}
            base = self._path(OBJECTS)
            for fan in os.scandir(base) if base.is_dir() else ():
                if fan.is_dir():
                    for obj in os.scandir(fan.path):
                        out[f"{OBJECTS}/{fan.name}/{obj.name}"] = obj.stat().st_size
            return out
        return {key: path.stat().st_size for key, path in self._walk(prefix)}

    def list_versions(self, prefix: str) -> dict[str, str]:
        return {key: path.read_text(errors="replace") for key, path in self._walk(prefix)}

    def head(self, key: str) -> int | None:
        try:
            return self._path(key).stat().st_size
        except (FileNotFoundError, NotADirectoryError):
            return None

    def upload_object(self, oid: str, path: Path, size: int) -> None:
        self._ensure_root()
        final = self._path(object_key(oid))
        tmp_dir = self.root / "tmp"
        tmp_dir.mkdir(parents=True, exist_ok=True)
        tmp = temp_name(tmp_dir, "obj-")
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
            try:
                with open(path, "rb", buffering=0) as src:
                    got, n = copy_hashing(src, fd, size)
                if got != oid or n != size:
                    raise _local_corrupt(oid)
                os.fsync(fd)
            finally:
                os.close(fd)
            os.chmod(tmp, 0o444)
            link_into_place(tmp, final)
        except OSError as exc:
            raise StoreError(f"{self.describe()}: cannot write object {oid[:12]}: {exc.strerror}") from None
        finally:
            tmp.unlink(missing_ok=True)

    def download_to(self, key: str, fd: int) -> tuple[str, int]:
        try:
            with open(self._path(key), "rb", buffering=0) as src:
                return copy_hashing(src, fd, os.fstat(src.fileno()).st_size)
        except FileNotFoundError:
            raise MissingOnRemote(f"{self.describe()}: lacks {key}") from None


def open_backend(spec: RemoteSpec) -> Backend:
    return S3Backend(spec) if spec.kind == "s3" else DirBackend(spec)
