"""Kernel file locks (flock via filelock): the OS releases them when the holder dies."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from artifacts.errors import StoreError

if TYPE_CHECKING:
    from filelock import FileLock

__all__ = ["store_lock", "try_lock", "Timeout"]  # noqa: F822 - Timeout comes from __getattr__


def __getattr__(name: str):
    # filelock costs a noticeable part of a read-only command's start-up; load it on first use
    if name == "Timeout":
        from filelock import Timeout

        return Timeout
    raise AttributeError(name)


def store_lock(locks_dir: Path, name: str) -> "FileLock":
    """The lock file locks/<name>.lock. Use as a context manager, or .acquire(timeout=…)."""
    from filelock import FileLock

    locks_dir.mkdir(parents=True, exist_ok=True)
    return FileLock(str(locks_dir / f"{name}.lock"))


def try_lock(lock: "FileLock", what: str, timeout: float = -1) -> "FileLock":
    from filelock import Timeout

    try:
        lock.acquire(timeout=timeout)
    except Timeout:
        raise StoreError(f"{what} is locked by another accrue process; try again when it finishes") from None
    return lock
