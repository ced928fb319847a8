"""Where outputs may go: never inside a store. A dataset written to STORE/refs/x would be read as a
ref (and objects/, records/ and log/ have formats of their own), so commands that write files
refuse a destination inside any accrue store — the default one or any other."""

from __future__ import annotations

import os
from pathlib import Path

from artifacts.errors import StoreError, path_text


def _is_store(directory: Path) -> bool:
    return (directory / "config").is_file() and (directory / "objects").is_dir() and (directory / "refs").is_dir()


def store_containing(path: Path | str) -> Path | None:
    """The root of the accrue store that path lies in (or is), else None."""
    here = Path(os.path.abspath(path))
    for directory in (here, *here.parents):
        try:
            if _is_store(directory):
                return directory
        except OSError:
            continue
    return None


def refuse_inside_store(path: Path | str, what: str) -> None:
    """StoreError when path (a file or directory about to be written) lies inside a store."""
    root = store_containing(path)
    if root is not None:
        raise StoreError(
            f"{what} {path_text(path)} is inside the accrue store at {path_text(root)}; "
            "write it elsewhere (use `accrue add` to bring it into the store)"
        )
