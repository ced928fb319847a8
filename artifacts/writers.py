"""The writer/gc protocol: nothing an in-flight writer has named is ever swept.

A store handle that names objects — writes or reuses one, resolves an id, points a ref or an
attempt record at one — holds a *shared* lock on `locks/writers.lock` from that moment until the
handle is closed or dropped (for the CLI: until the process exits; the kernel drops the lock of
a dead process). gc holds the same lock *exclusively* for its whole mark-and-sweep, so it only
runs while no writer is alive, and a writer that starts meanwhile waits for the sweep to end.
This is restic's rule (backups hold non-exclusive locks, prune an exclusive one); git's
alternative — freshening reused objects and trusting a grace period — still races with a sweep
and fails for any grace shorter than the writer's gap between naming and rooting.

POSIX (fcntl) locks rather than flock: they belong to the process, so a gc inside a process that
has written (a test, a library user) converts its own shared lock instead of waiting on itself,
and F_GETLK names a holder's pid for the message. Closing any descriptor of the file drops the
process's lock, so one descriptor per lock file is kept process-wide and reference-counted.
"""

from __future__ import annotations

import errno
import fcntl
import os
import struct
import threading
import time
import weakref
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Protocol

from artifacts.errors import StoreError


class Store(Protocol):
    """What a writer lock needs of a store (the store module imports this one, not the reverse)."""

    locks_dir: Path


LOCK_NAME = "writers.lock"


@dataclass
class _Held:
    fd: int
    users: int


_held: dict[str, _Held] = {}
_mutex = threading.Lock()


def _lock_path(store: "Store") -> str:
    return str(store.locks_dir / LOCK_NAME)


def _open(path: str) -> int | None:
    """A descriptor on the lock file; read-only when the store cannot be written (a shared lock
    needs no more); None when the file neither exists nor can be made (nothing to protect)."""
    try:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        return os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError:
        try:
            return os.open(path, os.O_RDONLY)
        except OSError:
            return None


def hold(store: "Store") -> None:
    """Mark this handle as a writer (idempotent). Waits while a gc sweeps."""
    if getattr(store, "_writer_held", False):
        return
    path = _lock_path(store)
    with _mutex:
        entry = _held.get(path)
        if entry is None:
            fd = _open(path)
            if fd is None:
                return
            try:
                fcntl.lockf(fd, fcntl.LOCK_SH)  # blocks only while a gc holds it exclusively
            except OSError:
                os.close(fd)
                return  # e.g. a filesystem without POSIX locks: nothing better to do
            entry = _held[path] = _Held(fd, 0)
        entry.users += 1
    store._writer_held = True
    # one drop per hold, whichever comes first: release() or the handle being garbage-collected (a finalizer
    # runs at most once, so a closed handle collected later cannot drop a count another handle holds)
    store._writer_drop = weakref.finalize(store, _drop, path)


def release(store: "Store") -> None:
    """Stop being a writer (the handle's names are all rooted, or it is done)."""
    if getattr(store, "_writer_held", False):
        store._writer_held = False
        store._writer_drop()


def _drop(path: str) -> None:
    with _mutex:
        entry = _held.get(path)
        if entry is None:
            return
        entry.users -= 1
        if entry.users <= 0:
            del _held[path]
            os.close(entry.fd)  # drops the lock


def _holder_pid(fd: int) -> tuple[int | None, bool]:
    """(pid, is_gc) of a process whose lock blocks an exclusive one (Linux struct flock)."""
    try:
        packed = struct.pack("hhqqi4x", fcntl.F_WRLCK, os.SEEK_SET, 0, 0, 0)
        ltype, _, _, _, pid = struct.unpack("hhqqi4x", fcntl.fcntl(fd, fcntl.F_GETLK, packed))
    except (OSError, struct.error):
        return None, False
    if ltype == fcntl.F_UNLCK:
        return None, False
    return pid, ltype == fcntl.F_WRLCK


@contextmanager
def exclusive(store: "Store", wait_s: float = 0.0) -> Iterator[None]:
    """Hold the store to ourselves (gc). StoreError if writers stay active for wait_s seconds."""
    path = _lock_path(store)
    with _mutex:
        entry = _held.get(path)
        if entry is None:
            fd = _open(path)
            if fd is None:
                raise StoreError(f"{path}: cannot open the store's writer lock")
            entry = _held[path] = _Held(fd, 0)
        entry.users += 1  # the descriptor stays open, and shared by this process's writers
    try:
        _acquire_exclusive(entry.fd, path, wait_s)
        try:
            yield
        finally:
            with _mutex:  # back to shared if this process is itself a writer, else let go
                fcntl.lockf(entry.fd, fcntl.LOCK_SH if entry.users > 1 else fcntl.LOCK_UN)
    finally:
        _drop(path)


def _acquire_exclusive(fd: int, path: str, wait_s: float) -> None:
    deadline = time.monotonic() + wait_s
    while True:
        try:
            fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return
        except OSError as exc:
            if exc.errno not in (errno.EACCES, errno.EAGAIN):
                raise StoreError(f"{path}: cannot lock ({exc.strerror})") from None
        if time.monotonic() >= deadline:
            pid, is_gc = _holder_pid(fd)
            who = f"pid {pid}" if pid else "another process"
            if is_gc:
                raise StoreError(
                    f"the store (gc) is locked by another accrue process ({who}); try again when it finishes"
                )
            raise StoreError(
                f"gc needs the store to itself, but an accrue process ({who}) is using it; "
                "run gc when it finishes, or pass --wait SECONDS"
            )
        time.sleep(min(0.1, max(0.01, deadline - time.monotonic())))
