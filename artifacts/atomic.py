"""Durable publish primitives: temp file in the same tree, fsync, link/rename, fsync the directory."""

from __future__ import annotations

import os
import secrets
from pathlib import Path


def fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def make_dirs_durable(path: Path) -> None:
    """mkdir -p path, each directory it makes synced into its parent: a new directory's name is data of
    its parent, and a crash before that is on disk can lose the directory with every file in it."""
    missing: list[Path] = []
    while not path.is_dir():
        missing.append(path)
        path = path.parent
    for directory in reversed(missing):
        directory.mkdir(exist_ok=True)
        fsync_dir(directory.parent)


def temp_name(directory: Path, prefix: str = "") -> Path:
    return directory / f".{prefix}tmp-{os.getpid()}-{secrets.token_hex(6)}"


def write_new_fsynced(path: Path, data: bytes) -> None:
    """Create path (it must not exist) holding data, flushed to disk before returning."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    try:
        view = memoryview(data)
        while view:  # a full disk may take part of a write before it refuses the rest
            view = view[os.write(fd, view) :]
        os.fsync(fd)
    except BaseException:
        os.close(fd)
        path.unlink(missing_ok=True)  # never leave a partial file behind (e.g. disk full)
        raise
    os.close(fd)


def write_replace(path: Path, data: bytes, tmp_dir: Path | None = None) -> None:
    """Replace path with data atomically: readers see the old or the new bytes, never a mix.

    The temp file lives in the target's own directory (or tmp_dir on the same filesystem), so the
    rename never crosses filesystems.
    """
    make_dirs_durable(path.parent)
    tmp = temp_name(tmp_dir or path.parent)
    write_new_fsynced(tmp, data)
    try:
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    fsync_dir(path.parent)


def link_into_place(tmp: Path, final: Path) -> bool:
    """Publish an already-fsynced file at final without ever overwriting: True if it is new.

    os.link fails with EEXIST when the object is already there; content addressing means the
    existing copy holds the same bytes, so the temp file is simply dropped.
    """
    make_dirs_durable(final.parent)
    try:
        os.link(tmp, final)
        created = True
    except FileExistsError:
        created = False
    fsync_dir(final.parent)
    return created
