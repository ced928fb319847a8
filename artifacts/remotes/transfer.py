"""Parallel transfers with progress, and verified downloads: a remote object is hashed while it
arrives, and only bytes that hash to its id are ever linked into the store."""

from __future__ import annotations

import os
from concurrent.futures import FIRST_EXCEPTION, ThreadPoolExecutor, wait
from pathlib import Path
from typing import Callable, Iterable, TypeVar

from artifacts.atomic import fsync_dir, temp_name
from artifacts.errors import StoreError
from artifacts.hashing import hash_bytes
from artifacts.remotes.backends import Backend, MissingOnRemote, object_key
from artifacts.store import Store

T = TypeVar("T")
R = TypeVar("R")
ATTEMPTS = 3  # a corrupt or truncated download is retried this many times in all, then refused


def default_jobs() -> int:
    return max(1, int(os.environ.get("ACCRUE_REMOTE_JOBS", "16")))


class Meter:
    """Progress of one transfer phase; the CLI draws it with rich, the API default is silent."""

    def start(self, what: str, objects: int, nbytes: int) -> None:
        pass

    def advance(self, nbytes: int) -> None:
        pass

    def stop(self) -> None:
        pass


def parallel(fn: Callable[[T], R], items: Iterable[T], jobs: int) -> list[R]:
    """fn over items on `jobs` threads (obstore and file I/O release the GIL). The first failure,
    or Ctrl-C, cancels what has not started; it is raised once the running transfers end."""
    items = list(items)
    if len(items) <= 1 or jobs <= 1:
        return [fn(i) for i in items]
    pool = ThreadPoolExecutor(max_workers=min(jobs, len(items)), thread_name_prefix="accrue-remote")
    try:
        futures = [pool.submit(fn, i) for i in items]
        wait(futures, return_when=FIRST_EXCEPTION)
        for f in futures:
            if f.done() and not f.cancelled() and f.exception() is not None:
                raise f.exception()
        return [f.result() for f in futures]
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _corrupt(backend: Backend, oid: str, why: str) -> StoreError:
    return StoreError(
        f"{backend.describe()}: object {oid[:12]} arrived {why} {ATTEMPTS} times; "
        "refused, nothing of it was stored (the remote copy is damaged: run "
        f"`accrue remote repair {backend.spec.name} --full` from a store that has it)"
    )


def download_object(
    store: Store, backend: Backend, oid: str, size: int | None = None, new_dirs: set[Path] | None = None
) -> int:
    """Fetch one object into the store, verified: its bytes are hashed as they arrive and fsynced
    before the object is linked in. Returns its size. With new_dirs, the fan-out directory is not
    fsynced here but added to the set for flush_dirs (a crash before that loses the link, never
    the bytes: the object is then merely missing and comes again on the next pull)."""
    why = "corrupt"
    for _ in range(ATTEMPTS):
        tmp = temp_name(store.tmp_dir, "dl-")
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        try:
            try:
                got, n = backend.download_to(object_key(oid), fd)
                if got == oid and (size is None or n == size):
                    os.fsync(fd)
            except MissingOnRemote:
                raise lacks(backend, oid) from None
            finally:
                os.close(fd)
            if got == oid and (size is None or n == size):
                with store._writing():  # a writer: gc waits until this process is done
                    if new_dirs is None:
                        store._publish_tmp(tmp, oid)
                    else:
                        _link_unsynced(store, tmp, oid, new_dirs)
                return n
            why = "corrupt" if size is None or n == size else f"truncated ({n} of {size} bytes)"
        finally:
            tmp.unlink(missing_ok=True)
    raise _corrupt(backend, oid, why)


def _link_unsynced(store: Store, tmp: Path, oid: str, new_dirs: set[Path]) -> None:
    final = store.object_path(oid)
    os.chmod(tmp, 0o444)
    final.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(tmp, final)
    except FileExistsError:
        return  # same id, same bytes
    new_dirs.add(final.parent)


def flush_dirs(dirs: set[Path], jobs: int) -> None:
    """fsync the directories that gained objects (once each, not once per object)."""
    parallel(fsync_dir, sorted(dirs) + ([next(iter(dirs)).parent] if dirs else []), jobs)


def lacks(backend: Backend, oid: str) -> MissingOnRemote:
    return MissingOnRemote(
        f"{backend.describe()}: lacks object {oid[:12]} that its refs reach; "
        f"run `accrue remote repair {backend.spec.name}` from a store that has it"
    )


def download_manifest(backend: Backend, oid: str) -> bytes:
    """A manifest's bytes, held in memory (published later, after what it names)."""
    from artifacts.remotes.backends import object_key as key_of

    for _ in range(ATTEMPTS):
        data = backend.get_bytes(key_of(oid))
        if data is None:
            raise lacks(backend, oid)
        if hash_bytes(data) == oid:
            return data
    raise _corrupt(backend, oid, "corrupt")
