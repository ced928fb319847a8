"""A remote that is a plain directory (a mounted NAS, a USB disk)."""

from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path
from typing import Iterator

from artifacts.atomic import fsync_dir, link_into_place, temp_name, write_new_fsynced
from artifacts.errors import StoreError
from artifacts.hashing import copy_hashing
from artifacts.remotes.backends import OBJECTS, Backend, MissingOnRemote, RefMoved, local_corrupt, object_key
from artifacts.remotes.config import RemoteSpec


class DirBackend(Backend):
    """A remote that is a directory. Refs move under an O_EXCL lock file (works on NFS/SMB, where
    kernel locks may not) that is renamed over the ref: readers see the old or the new id."""

    LOCK_WAIT_S = 10.0

    def __init__(self, spec: RemoteSpec) -> None:
        self.spec = spec
        self.root = spec.path

    def _path(self, key: str) -> Path:
        return self.root / key

    def _missing(self) -> StoreError:
        return StoreError(f"{self.describe()}: the directory does not exist (is the disk mounted?)")

    def _mkdirs(self, path: Path) -> None:
        """Make path and its missing parents below the root (each new one synced into its parent),
        never the root itself: a remote whose directory vanished (an unmounted disk) is refused, not
        made again on the local disk."""
        if path == self.root:
            if not self.root.is_dir():
                raise self._missing()
            return
        try:
            path.mkdir()
        except FileExistsError:
            if path.is_dir():
                return
            raise
        except FileNotFoundError:
            if self.root not in path.parents:
                raise
            self._mkdirs(path.parent)
            try:
                path.mkdir()
            except FileExistsError:
                return  # another push made it meanwhile
            except FileNotFoundError:  # the root went meanwhile
                raise self._missing() from None
        fsync_dir(path.parent)

    def _ensure_root(self) -> None:
        """Make the remote's directory (`accrue remote init`, `remote add --create` only)."""
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
            raise self._missing()

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
        self._mkdirs(tmp_dir)
        tmp = temp_name(tmp_dir)
        try:
            write_new_fsynced(tmp, data)
            self._mkdirs(final.parent)
            os.replace(tmp, final)
        except BaseException:
            tmp.unlink(missing_ok=True)  # a refused write leaves nothing for prune to find later
            raise
        fsync_dir(final.parent)

    def put_bytes(self, key: str, data: bytes) -> None:
        try:
            self._write_new(self._path(key), data)
        except OSError as exc:
            raise StoreError(f"{self.describe()}: cannot write {key}: {exc.strerror}") from None

    def swap(self, key: str, data: bytes, expect: str | None) -> str:
        try:
            return self._swap(key, data, expect)
        except OSError as exc:  # e.g. a read-only mount: one line that names the remote
            raise StoreError(f"{self.describe()}: cannot write {key}: {exc.strerror or exc}") from None

    def delete(self, key: str, expect: str) -> None:
        try:
            with self._locked(key):
                current = self.read_versioned(key)
                if current is None or current[1] != expect:
                    raise RefMoved(key)
                self._path(key).unlink()
                fsync_dir(self._path(key).parent)
        except OSError as exc:
            raise StoreError(f"{self.describe()}: cannot remove {key}: {exc.strerror or exc}") from None

    def remove(self, key: str) -> None:
        try:
            self._path(key).unlink()
        except FileNotFoundError:
            pass
        except OSError as exc:
            raise StoreError(f"{self.describe()}: cannot remove {key}: {exc.strerror or exc}") from None

    def list_aged(self, prefix: str) -> dict[str, tuple[int, float]]:
        if not self.root.is_dir():
            raise self._missing()
        out = {}
        for key, path in self._walk(prefix):
            try:
                st = path.stat()
            except FileNotFoundError:
                continue
            out[key] = (st.st_size, st.st_mtime)
        return out

    def _take_lock(self, key: str) -> tuple[Path, int]:
        """Create the key's O_EXCL lock file (waiting up to LOCK_WAIT_S): its path and an fd on it."""
        lock = self.root / "locks" / (key + ".lock")
        self._mkdirs(lock.parent)
        deadline = time.monotonic() + self.LOCK_WAIT_S
        while True:
            try:
                return lock, os.open(lock, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
            except FileExistsError:
                if time.monotonic() > deadline:
                    raise StoreError(
                        f"{self.describe()}: {key} is locked by another push ({lock}); "
                        "remove that file if no push is running"
                    ) from None
                time.sleep(0.05)

    @contextlib.contextmanager
    def _locked(self, key: str) -> Iterator[None]:
        """The lock swap uses, held while a ref is removed (its content is irrelevant)."""
        lock, fd = self._take_lock(key)
        os.close(fd)
        try:
            yield
        finally:
            lock.unlink(missing_ok=True)

    def _swap(self, key: str, data: bytes, expect: str | None) -> str:
        target = self._path(key)
        lock, fd = self._take_lock(key)
        try:
            try:
                os.write(fd, data)
                os.fsync(fd)
            finally:
                os.close(fd)
            current = self.read_versioned(key)
            if (current[1] if current else None) != expect:
                raise RefMoved(key)
            self._mkdirs(target.parent)
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
            raise self._missing()
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

    def upload_object(self, oid: str, path: Path, size: int, replace: bool = False) -> None:
        final = self._path(object_key(oid))
        tmp_dir = self.root / "tmp"
        try:
            self._mkdirs(tmp_dir)
        except OSError as exc:
            raise StoreError(f"{self.describe()}: cannot write object {oid[:12]}: {exc.strerror}") from None
        tmp = temp_name(tmp_dir, "obj-")
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
            try:
                with open(path, "rb", buffering=0) as src:
                    got, n = copy_hashing(src, fd, size)
                if got != oid or n != size:
                    raise local_corrupt(oid)
                os.fsync(fd)
            finally:
                os.close(fd)
            os.chmod(tmp, 0o444)
            self._mkdirs(final.parent)
            if replace:  # repair: a damaged copy is there under this name; the verified one takes its place
                os.replace(tmp, final)
                fsync_dir(final.parent)
            else:
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
