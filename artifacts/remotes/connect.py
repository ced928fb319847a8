"""Which backend a remote's URL means (kept apart from backends.py, which both backends import)."""

from __future__ import annotations

from artifacts.remotes.backends import Backend
from artifacts.remotes.config import RemoteSpec


def open_backend(spec: RemoteSpec) -> Backend:
    if spec.kind == "s3":
        from artifacts.remotes.s3 import S3Backend  # obstore is imported only for S3 remotes

        return S3Backend(spec)
    from artifacts.remotes.directory import DirBackend

    return DirBackend(spec)
