"""Artifacts: a manifest object (kind, producing step, inputs by role, config, code version, sizes)
pointing at its content — one file object, or a tree object listing a directory's files.

An artifact's id is the id of its manifest, so the manifest holds only what the artifact is a
function of: two machines that run the same step on the same inputs get the same id (as a git
object's id is its content). When, where and by which attempt it was made is provenance, kept
outside it: the attempt record and step record (time, host, attempt, cache key) and the audit
log's artifact-written / checkpoint-saved events (time, host, an added file's source path) — see
artifacts/provenance.py. Format 1 manifests (older stores) also held `created` and the producer's attempt,
cache key or source; they are still read.

Manifest kinds used by accrue: base-policy, replay, teacher-targets, checkpoint, eval, handoff,
demos, episodes (any short lowercase name is accepted).
"""

from __future__ import annotations

import os
import re
import stat
from pathlib import Path
from typing import Any, Callable, Literal

from artifacts.clock import now_iso  # noqa: F401 - also imported from here by older callers
from artifacts.errors import StoreError, os_error_text, path_text, quote
from artifacts.hashing import copy_hashing, hash_file
from artifacts.store import Store

MANIFEST_FORMAT = 1  # trees, step records and log segments (unchanged since format 1)
ARTIFACT_FORMAT = 2  # artifact manifests: 2 = no time, attempt, cache key or source path inside
# The producer fields an artifact's id depends on; the rest of what callers pass (attempt, cache
# key, an added file's source path) is provenance that the attempt record and audit log hold.
PRODUCER_IDENTITY = ("step",)
KNOWN_KINDS = ("base-policy", "replay", "teacher-targets", "checkpoint", "eval", "handoff", "demos", "episodes")
_KIND_RE = re.compile(r"^[a-z][a-z0-9-]{0,39}$")


def check_kind(kind: str) -> str:
    if not _KIND_RE.match(kind):
        raise StoreError(
            f"bad artifact kind {quote(kind)}: use lowercase letters, digits and '-' (e.g. {', '.join(KNOWN_KINDS)})"
        )
    return kind


# ------------------------------------------------------------------------- trees
def put_tree(store: Store, directory: Path, how: Literal["copy", "adopt", "checked"]) -> dict:
    """Store every regular file under directory; returns {"tree": id, "size": n, "files": n}.

    how: "copy" (outside data, one pass), "adopt" (finished staging files, hard-linked in),
    "checked" (files a step may still hold open: hash first, never rewrite an existing object).
    The tree object is a canonical sorted list of {path, id, size, exec}.
    """
    store_file: Callable[[Path], tuple[str, int]] = {
        "copy": store.ingest_file,
        "adopt": store.adopt_file,
        "checked": store.copy_in_checked,
    }[how]
    entries = []
    for root, dirs, files in os.walk(directory, onerror=_walk_error):
        dirs.sort()
        for name in dirs:  # os.walk lists a symlinked directory but does not enter it: refuse, as for files
            if os.path.islink(os.path.join(root, name)):
                raise StoreError(
                    f"{_shown(Path(root) / name)}: a symlink; only regular files and directories "
                    "can be stored (copy the target in instead)"
                )
        for name in sorted(files):
            path = Path(root) / name
            st = os.lstat(path)
            if not stat.S_ISREG(st.st_mode):
                raise StoreError(f"{_shown(path)}: only regular files can be stored (symlinks and devices are refused)")
            rel = utf8_name(path.relative_to(directory).as_posix(), path)
            oid, size = store_file(path)
            entries.append({"path": rel, "id": oid, "size": size, "exec": bool(st.st_mode & stat.S_IXUSR)})
    entries.sort(key=lambda e: e["path"])
    tree_id = store.put_json({"type": "tree", "format": MANIFEST_FORMAT, "entries": entries})
    return {"tree": tree_id, "size": sum(e["size"] for e in entries), "files": len(entries)}


def _walk_error(exc: OSError) -> None:
    raise StoreError(f"cannot read {os_error_text(exc)}")


def _shown(path: Path | str) -> str:
    return path_text(path)  # undecodable bytes escaped, long paths shortened


def utf8_name(name: str, path: Path | str) -> str:
    """Names are recorded as UTF-8 JSON; a file name that is not UTF-8 is refused, not mangled."""
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        raise StoreError(f"{_shown(path)}: file name is not valid UTF-8; rename it to store it") from None
    return name


def read_tree(store: Store, tree_id: str) -> list[dict]:
    tree = store.read_json(tree_id)
    if tree.get("type") != "tree":
        raise StoreError(f"object {tree_id[:12]} is not a tree")
    return tree["entries"]


# ------------------------------------------------------------------------- artifacts
def store_content(store: Store, path: Path, how: Literal["copy", "adopt", "checked"] = "copy") -> dict:
    """Store a file or directory's bytes (objects only). Returns the manifest's content fields."""
    path = Path(path)
    if path.is_symlink():
        raise StoreError(f"{_shown(path)}: a symlink; only regular files and directories can be stored")
    if not (path.is_file() or path.is_dir()):
        raise StoreError(f"{_shown(path)}: no such file or directory")
    utf8_name(path.name, path)
    if path.is_dir():
        tree = put_tree(store, path, how)
        return {"layout": "dir", "content": tree["tree"], "size": tree["size"], "files": tree["files"]}
    oid, size = {"copy": store.ingest_file, "adopt": store.adopt_file, "checked": store.copy_in_checked}[how](path)
    return {"layout": "file", "content": oid, "size": size, "files": 1, "name": path.name}


def write_manifest(
    store: Store,
    content: dict,
    kind: str,
    *,
    producer: dict[str, Any],
    inputs: dict[str, str] | None = None,
    config: dict[str, Any] | None = None,
    code_version: str = "",
    meta: dict[str, Any] | None = None,
) -> str:
    """Write the manifest of already-stored content (see store_content); returns the artifact id.

    Only the producer's PRODUCER_IDENTITY fields enter the manifest: the caller records the rest
    (attempt, cache key, source) with the attempt or in the audit log event it appends."""
    manifest: dict[str, Any] = {
        "type": "artifact",
        "format": ARTIFACT_FORMAT,
        "kind": check_kind(kind),
        "producer": {k: producer[k] for k in PRODUCER_IDENTITY if k in producer},
        "inputs": dict(inputs or {}),
        "config": config or {},
        "code_version": code_version,
        "meta": meta or {},
        **content,
    }
    return store.put_json(manifest)


def publish_artifact(
    store: Store,
    path: Path,
    kind: str,
    *,
    producer: dict[str, Any],
    inputs: dict[str, str] | None = None,
    config: dict[str, Any] | None = None,
    code_version: str = "",
    meta: dict[str, Any] | None = None,
    how: Literal["copy", "adopt", "checked"] = "copy",
) -> str:
    """Store a file or directory as an artifact: objects first, then its manifest. Returns its id."""
    check_kind(kind)
    content = store_content(store, path, how)
    return write_manifest(
        store, content, kind, producer=producer, inputs=inputs, config=config, code_version=code_version, meta=meta
    )


def read_artifact(store: Store, artifact_id: str) -> dict:
    manifest = store.read_json(artifact_id)
    if manifest.get("type") != "artifact":
        raise StoreError(f"{artifact_id[:12]} is a {manifest.get('type', 'raw')} object, not an artifact")
    return manifest


def content_objects(store: Store, manifest: dict) -> list[tuple[str, int, str]]:
    """(object id, expected size, path inside the artifact) for every data object of an artifact."""
    if manifest["layout"] == "file":
        return [(manifest["content"], manifest["size"], manifest.get("name", ""))]
    return [(e["id"], e["size"], e["path"]) for e in read_tree(store, manifest["content"])]


def verify_artifact(store: Store, artifact_id: str, full: bool = True, quarantine: bool = False) -> None:
    """Raise StoreError if the artifact's manifest or any of its objects is missing or corrupt.

    With quarantine, a corrupt object is moved aside first, so that the next writer of the same
    bytes re-creates it instead of deduplicating against the damaged copy."""
    manifest = read_artifact(store, artifact_id)  # manifests are always re-hashed
    objects = content_objects(store, manifest)
    store.fetch_missing(*(oid for oid, _, _ in objects))  # a partial clone fetches them now
    for oid, size, rel in objects:
        actual = store.object_size(oid)
        if actual is None:
            raise StoreError(f"artifact {artifact_id[:12]}: object {oid[:12]} ({rel}) is missing")
        if actual != size or (full and hash_file(store.object_path(oid))[0] != oid):
            if quarantine:
                _quarantine(store, oid)
            why = "is corrupt" if actual == size else f"has size {actual}, expected {size}"
            raise StoreError(f"artifact {artifact_id[:12]}: object {oid[:12]} ({rel}) {why}")


def _quarantine(store: Store, oid: str) -> None:
    from artifacts.auditlog import append_event

    try:
        store.quarantine(oid)
    except FileNotFoundError:
        return
    append_event(store, "quarantined", object=oid, reason="hash mismatch found on use")


def materialize(store: Store, artifact_id: str, dest: Path, quarantine: bool = False) -> Path:
    """A verified, read-only view of an artifact.

    A file artifact is its object itself (read-only, re-hashed now). A directory artifact is copied
    to dest — copies, never hard links, so a step writing into its input cannot damage the store —
    and every file is hashed while it is copied.
    """
    manifest = read_artifact(store, artifact_id)
    if manifest["layout"] == "file":
        verify_artifact(store, artifact_id, full=True, quarantine=quarantine)
        return store.object_path(manifest["content"])
    dest.mkdir(parents=True, exist_ok=False)
    objects = content_objects(store, manifest)
    store.fetch_missing(*(oid for oid, _, _ in objects))  # a partial clone fetches them now
    for oid, size, rel in objects:
        target = dest / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        try:
            src = open(store.object_path(oid), "rb", buffering=0)
        except FileNotFoundError:
            raise StoreError(f"artifact {artifact_id[:12]}: object {oid[:12]} ({rel}) is missing") from None
        with src:
            fd = os.open(target, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
            try:
                got, n = copy_hashing(src, fd, size)
            finally:
                os.close(fd)
        if got != oid or n != size:
            if quarantine:
                _quarantine(store, oid)
            raise StoreError(f"artifact {artifact_id[:12]}: object {oid[:12]} ({rel}) is corrupt")
    _make_read_only(dest)
    return dest


def _make_read_only(path: Path) -> None:
    for root, _dirs, files in os.walk(path, topdown=False):
        for name in files:
            os.chmod(os.path.join(root, name), 0o444)
        os.chmod(root, 0o555)
