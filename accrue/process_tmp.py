"""Temporary directories owned by one process: the pid is in the name, so a later process can remove
what a killed one (kill -9 runs no cleanup) left behind. Used by both ends of the robot link."""

from __future__ import annotations

import os
import shutil
import tempfile
import weakref
from pathlib import Path


def process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def sweep_dead(prefix: str, root: Path | None = None) -> list[Path]:
    """Remove `<prefix><pid>-*` dirs under `root` (the temp dir) whose process is gone; dirs of live
    processes, and names without a pid, are left alone."""
    removed = []
    for d in Path(root or tempfile.gettempdir()).glob(f"{prefix}*-*"):
        pid = d.name[len(prefix) :].split("-", 1)[0]
        if pid.isdigit() and int(pid) != os.getpid() and not process_alive(int(pid)) and d.is_dir():
            shutil.rmtree(d, ignore_errors=True)
            removed.append(d)
    return removed


def owned_tmpdir(owner: object, prefix: str) -> tuple[Path, weakref.finalize]:
    """A fresh `<prefix><pid>-*` temp dir, after sweeping dead processes' ones; the returned finalizer
    removes it (call it at close; it also runs when `owner` is collected or the interpreter exits)."""
    sweep_dead(prefix)
    path = Path(tempfile.mkdtemp(prefix=f"{prefix}{os.getpid()}-"))
    return path, weakref.finalize(owner, shutil.rmtree, path, ignore_errors=True)
