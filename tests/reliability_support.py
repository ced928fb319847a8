"""Small filesystems for the fault tests: a tmpfs of a few MiB (a full disk on demand) that can be
remounted read-only. Needs root; tests that use them are skipped otherwise."""

from __future__ import annotations

import contextlib
import os
import subprocess
from pathlib import Path
from typing import Iterator

import pytest


def _mount(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["mount", *args], capture_output=True, text=True)


def can_mount() -> bool:
    return os.geteuid() == 0 and subprocess.run(["which", "mount"], capture_output=True).returncode == 0


@contextlib.contextmanager
def small_fs(where: Path, size: str = "4m") -> Iterator[Path]:
    """A fresh tmpfs of `size` mounted at where (skips the test if it cannot be mounted)."""
    if not can_mount():
        pytest.skip("mounting a small filesystem needs root")
    where.mkdir(parents=True, exist_ok=True)
    done = _mount("-t", "tmpfs", "-o", f"size={size},mode=0755", "tmpfs", str(where))
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], capture_output=True)


def remount(where: Path, read_only: bool) -> None:
    done = _mount("-o", f"remount,{'ro' if read_only else 'rw'}", str(where))
    assert done.returncode == 0, done.stderr


def fill(where: Path, leave: int = 0) -> Path:
    """Fill the filesystem at where, leaving about `leave` bytes free; returns the filler file."""
    filler = where / "filler"
    free = os.statvfs(where).f_bavail * os.statvfs(where).f_frsize
    with open(filler, "wb") as f:
        chunk = b"\0" * 65536
        todo = max(0, free - leave)
        try:
            while todo > 0:
                todo -= f.write(chunk[: min(len(chunk), todo)])
            f.flush()
        except OSError:
            pass
    return filler
