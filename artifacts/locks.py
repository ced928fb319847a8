"""Kernel file locks (flock via filelock): the OS releases them when the holder dies."""
from __future__ import annotations

from pathlib import Path

from filelock import FileLock, Timeout

from artifacts.errors import StoreError

__all__ = ["store_lock", "Timeout", "FileLock"]


def store_lock(locks_dir: Path, name: str) -> FileLock:
    """The lock file locks/<name>.lock. Use as a context manager, or .acquire(timeout=…)."""
    locks_dir.mkdir(parents=True, exist_ok=True)
    return FileLock(str(locks_dir / f"{name}.lock"))


def try_lock(lock: FileLock, what: str, timeout: float = -1) -> FileLock:
    try:
        lock.acquire(timeout=timeout)
    except Timeout:
        raise StoreError(f"{what} is locked by another accrue process; try again when it finishes") from None
    return lock
