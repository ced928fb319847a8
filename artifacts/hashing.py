"""Content ids: BLAKE3 of raw bytes, and canonical JSON so that equal data hashes equally."""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, BinaryIO

import blake3

HASH_NAME = "blake3"
ID_LENGTH = 64  # hex digits of a 256-bit BLAKE3 digest
CHUNK_SIZE = 8 * 1024 * 1024
# Below this size threading costs more than it gains.
_THREADED_MIN = 4 * 1024 * 1024


def _hasher(size_hint: int = 0) -> "blake3.blake3":
    return blake3.blake3(max_threads=blake3.blake3.AUTO if size_hint >= _THREADED_MIN else 1)


def canonical_json(value: Any) -> bytes:
    """Sorted keys, no whitespace, UTF-8, no NaN: the one byte form used for every hashed JSON."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=False,
                      allow_nan=False).encode("utf-8")


def hash_bytes(data: bytes) -> str:
    return _hasher(len(data)).update(data).hexdigest()


def hash_json(value: Any) -> str:
    return hash_bytes(canonical_json(value))


def hash_file(path: Path) -> tuple[str, int]:
    """(content id, size) of a file, read through mmap with all cores for large files."""
    size = os.stat(path).st_size
    if size == 0:
        return hash_bytes(b""), 0
    hasher = _hasher(size)
    hasher.update_mmap(str(path))
    return hasher.hexdigest(), size


def copy_hashing(src: BinaryIO, dst_fd: int, size_hint: int = 0) -> tuple[str, int]:
    """Copy src into dst_fd while hashing it: one pass over the bytes. Returns (id, size)."""
    hasher = _hasher(size_hint)
    buffer = bytearray(CHUNK_SIZE)
    view = memoryview(buffer)
    total = 0
    while True:
        n = src.readinto(buffer)
        if not n:
            break
        chunk = view[:n]
        hasher.update(chunk)
        written = 0
        while written < n:
            written += os.write(dst_fd, chunk[written:])
        total += n
    return hasher.hexdigest(), total


def is_full_id(text: str) -> bool:
    return len(text) == ID_LENGTH and all(c in "0123456789abcdef" for c in text)
