"""Two kinds of remote behind one small interface: S3-compatible object storage (through obstore)
and a plain directory (a mounted NAS, a USB disk). Every failure becomes one StoreError line."""

from __future__ import annotations

from pathlib import Path

from artifacts.errors import StoreError
from artifacts.hashing import HASH_NAME, is_full_id
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
    # S3: a multipart upload of an object begun before this time (the remote's clock) by a push that is gone
    # is finished instead of started again (set by push; None: never); what was, is noted in resumed
    resume_before: float | None = None
    resumed: tuple[str, ...] = ()

    def describe(self) -> str:
        return f"remote {self.spec.name} ({self.spec.url})"

    # small values
    def get_bytes(self, key: str) -> bytes | None: ...
    def put_bytes(self, key: str, data: bytes) -> None: ...
    def read_versioned(self, key: str) -> tuple[bytes, str] | None: ...
    def swap(self, key: str, data: bytes, expect: str | None) -> str:
        """Write data if the key is still at version expect (None: absent); else RefMoved."""
        ...

    def delete(self, key: str, expect: str) -> None:
        """Remove a ref if it is still at version expect; else RefMoved."""
        ...

    def remove(self, key: str) -> None:
        """Remove a key unconditionally (prune: objects nothing reaches); absent is fine."""
        ...

    def list_aged(self, prefix: str) -> dict[str, tuple[int, float]]:
        """Every key under prefix: (size, last modified as a Unix time)."""
        ...

    def unfinished_uploads(self) -> list[tuple[str, float, object]]:
        """Uploads a killed push left behind: (what, started as Unix time, handle for drop_upload).
        A directory's are its tmp/ files; S3 overrides this with its multipart uploads."""
        return [(key, mtime, key) for key, (_size, mtime) in self.list_aged("tmp").items()]

    def drop_upload(self, handle: object) -> None:
        self.remove(str(handle))

    def probe(self, create: bool) -> None:
        """Reach the remote (and make its root if create); raise one clear line if that fails."""
        self.list_sizes("refs")

    # listings
    def list_sizes(self, prefix: str) -> dict[str, int]: ...
    def list_versions(self, prefix: str) -> dict[str, str]: ...
    def head(self, key: str) -> int | None: ...

    # objects
    def upload_object(self, oid: str, path: Path, size: int, replace: bool = False) -> None:
        """Send a local object; refuse (StoreError) if its bytes do not hash to oid. With replace,
        a (damaged) copy already at that key is overwritten."""
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


def local_corrupt(oid: str) -> StoreError:
    return StoreError(
        f"object {oid[:12]} in this store is corrupt (its bytes no longer match its id); "
        "nothing corrupt is pushed — run `accrue verify --full`"
    )
