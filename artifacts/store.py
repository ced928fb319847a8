"""The content-addressed object store: layout, config, write-once objects, id resolution.

Layout under the store root (default `.accrue/`, or $ACCRUE_STORE):
    config                     {"format": 1, "hash": "blake3"}
    objects/blake3/ab/cd…      write-once, read-only objects named by their BLAKE3 id
    refs/<name…>               mutable names, each file holds one id (see refs.py)
    records/<cache key>/NNNN.json   per-attempt step records (see stages/records.py)
    log/events.jsonl           hash-chained audit log (see auditlog.py)
    locks/                     kernel file locks (released by the OS if the holder dies)
    tmp/                       staging area on the same filesystem as objects/
    quarantine/                objects that failed verification, moved aside, never deleted
    remotes/<name>/            what this store knows of remote <name> (see artifacts/remotes)

A handle that writes or names objects holds a shared writer lock until close() (see writers.py):
gc sweeps only while no writer is alive.
"""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path
from typing import Any, Callable, Iterator

from artifacts import writers
from artifacts.atomic import fsync_dir, link_into_place, temp_name, write_new_fsynced, write_replace
from artifacts.errors import StoreError, os_error_text, quote, store_os_error
from artifacts.hashing import HASH_NAME, canonical_json, copy_hashing, hash_bytes, hash_file, is_full_id

STORE_FORMAT = 1
ENV_VAR = "ACCRUE_STORE"
DEFAULT_DIRNAME = ".accrue"
_SUBDIRS = ("objects", "refs", "records", "log", "locks", "tmp", "quarantine")


# How objects a partial clone left on a remote come back: the remotes package installs its fetcher
# (artifacts/__init__.py wires it), so this module never imports the remotes that import it.
_MISSING_FETCHERS: list[Callable[["Store", list[str]], bool]] = []


def add_missing_fetcher(fetch: Callable[["Store", list[str]], bool]) -> None:
    """fetch(store, missing ids) brings what it can into the store; True when all arrived."""
    if fetch not in _MISSING_FETCHERS:
        _MISSING_FETCHERS.append(fetch)


def default_store_path() -> Path:
    env = os.environ.get(ENV_VAR)
    return Path(env) if env else Path.cwd() / DEFAULT_DIRNAME


class Store:
    """Handle on an initialised store. Objects are immutable; only refs and attempt files change."""

    def __init__(self, root: Path) -> None:
        self.root = Path(root).absolute()
        self.objects_dir = self.root / "objects" / HASH_NAME
        self.refs_dir = self.root / "refs"
        self.records_dir = self.root / "records"
        self.log_path = self.root / "log" / "events.jsonl"
        self.locks_dir = self.root / "locks"
        self.tmp_dir = self.root / "tmp"
        self.quarantine_dir = self.root / "quarantine"
        self._promised: set[str] | None = None  # see is_promised

    # ----------------------------------------------------------------- open / init
    @classmethod
    def init(cls, root: Path | None = None) -> tuple["Store", bool]:
        """Create the store (idempotent). Returns (store, created)."""
        root = Path(root) if root is not None else default_store_path()
        config = root / "config"
        if config.exists():
            return cls.open(root), False
        if root.exists() and not root.is_dir():
            raise StoreError(f"{root}: exists and is not a directory")
        try:
            for sub in _SUBDIRS:
                (root / sub).mkdir(parents=True, exist_ok=True)
            (root / "objects" / HASH_NAME).mkdir(exist_ok=True)
            write_replace(config, canonical_json({"format": STORE_FORMAT, "hash": HASH_NAME}) + b"\n")
        except OSError as exc:
            raise StoreError(f"cannot create a store at {root}: {os_error_text(exc)}") from None
        return cls(root), True

    @classmethod
    def open(cls, root: Path | None = None) -> "Store":
        root = Path(root) if root is not None else default_store_path()
        config = root / "config"
        if not config.is_file():
            raise StoreError(f"no accrue store at {root} (run `accrue init` or pass --store PATH)")
        try:
            cfg = json.loads(config.read_bytes())
        except ValueError:  # also UnicodeDecodeError
            raise StoreError(f"{config}: not valid JSON") from None
        except OSError as exc:
            raise StoreError(f"cannot read the store's config: {os_error_text(exc)}") from None
        if not isinstance(cfg, dict):
            raise StoreError(f"{config}: not a store config (expected a JSON object, got {type(cfg).__name__})")
        if cfg.get("format") != STORE_FORMAT or cfg.get("hash") != HASH_NAME:
            raise StoreError(
                f"{config}: unsupported store format {cfg.get('format')!r} / hash "
                f"{cfg.get('hash')!r} (this accrue reads format {STORE_FORMAT}, {HASH_NAME})"
            )
        store = cls(root)
        try:  # tolerate a store whose empty dirs were lost (e.g. copied with git)
            for sub in _SUBDIRS:
                (store.root / sub).mkdir(exist_ok=True)
            store.objects_dir.mkdir(exist_ok=True)
        except OSError:
            pass  # a read-only store can still be read and verified
        return store

    def close(self) -> None:
        """Let gc run again (see writers.py); the handle may still be used, and re-registers."""
        writers.release(self)

    def _writing(self) -> "_WriteErrors":
        """Register as a writer; an OSError while writing becomes one StoreError line."""
        writers.hold(self)
        return _WriteErrors(self.root)

    # ----------------------------------------------------------------- objects
    def object_path(self, oid: str) -> Path:
        return self.objects_dir / oid[:2] / oid[2:]

    def has_object(self, oid: str) -> bool:
        return self.object_path(oid).is_file()

    def iter_object_ids(self) -> Iterator[str]:
        for fan in sorted(self.objects_dir.iterdir()) if self.objects_dir.is_dir() else ():
            if len(fan.name) != 2 or not fan.is_dir():
                continue
            for obj in sorted(fan.iterdir()):
                oid = fan.name + obj.name
                if is_full_id(oid):
                    yield oid

    def _publish_tmp(self, tmp: Path, oid: str) -> bool:
        """fsynced tmp -> objects/…; read-only; the temp name is always removed."""
        try:
            os.chmod(tmp, 0o444)
            return link_into_place(tmp, self.object_path(oid))
        finally:
            tmp.unlink(missing_ok=True)

    def put_bytes(self, data: bytes) -> str:
        oid = hash_bytes(data)
        with self._writing():
            if self.has_object(oid):
                return oid
            tmp = temp_name(self.tmp_dir, "obj-")
            write_new_fsynced(tmp, data)
            self._publish_tmp(tmp, oid)
        return oid

    def put_json(self, value: Any) -> str:
        return self.put_bytes(canonical_json(value))

    def ingest_file(self, src: Path) -> tuple[str, int]:
        """Copy an outside file in, hashing while it is written (one pass). Returns (id, size).

        A source that changes size meanwhile is refused (nothing is stored)."""
        with self._writing():
            try:
                f = open(src, "rb", buffering=0)
            except OSError as exc:
                raise StoreError(f"cannot read {os_error_text(exc)}") from None
            with f:
                tmp = temp_name(self.tmp_dir, "obj-")
                fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
                try:
                    before = os.fstat(f.fileno()).st_size
                    oid, size = copy_hashing(f, fd, before)
                    after = os.fstat(f.fileno()).st_size
                    if not before == size == after:
                        raise StoreError(
                            f"{src}: changed size while it was being stored ({before} -> "
                            f"{after} bytes); nothing was stored"
                        )
                    os.fsync(fd)
                except BaseException:
                    os.close(fd)
                    tmp.unlink(missing_ok=True)
                    raise
                os.close(fd)
            self._publish_tmp(tmp, oid)
        return oid, size

    def adopt_file(self, path: Path) -> tuple[str, int]:
        """Turn a finished file in the store's tmp area into an object without copying it.

        Hash in place; if the object exists already nothing is written (checkpoints of unchanged
        replay shards cost one read); otherwise the file itself is fsynced and hard-linked in.
        """
        with self._writing():
            oid, size = hash_file(path)
            if self.object_size(oid) == size:
                return oid, size
            if self.has_object(oid):  # a damaged copy of the same id: move it aside, then replace it
                self.quarantine(oid)
            fd = os.open(path, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
            os.chmod(path, 0o444)
            link_into_place(path, self.object_path(oid))
        return oid, size

    def copy_in_checked(self, path: Path, expected: str | None = None) -> tuple[str, int]:
        """Store a file the caller may still hold open (checkpoints): hash first so a file that is
        already an object is never rewritten; else copy it, and refuse if it changed meanwhile."""
        with self._writing():
            oid, size = hash_file(path)
            if self.object_size(oid) == size:
                return oid, size
            if self.has_object(oid):
                self.quarantine(oid)
        copied, copied_size = self.ingest_file(path)
        if copied != oid:
            raise StoreError(f"{path}: file changed while it was being stored")
        return copied, copied_size

    def read_bytes(self, oid: str, verify: bool = True) -> bytes:
        path = self.object_path(oid)
        try:
            data = path.read_bytes()
        except FileNotFoundError:
            if not self.fetch_missing(oid):
                raise StoreError(f"object {oid[:12]} is missing from the store") from None
            data = path.read_bytes()
        if verify and hash_bytes(data) != oid:
            raise StoreError(
                f"object {oid[:12]} is corrupt (its bytes no longer match its id); run `accrue verify --full`"
            )
        return data

    def read_json(self, oid: str) -> dict:
        try:
            value = json.loads(self.read_bytes(oid))
        except ValueError:
            raise StoreError(f"object {oid[:12]} is not a JSON manifest") from None
        if not isinstance(value, dict):
            raise StoreError(f"object {oid[:12]} is not a JSON manifest")
        return value

    def object_size(self, oid: str) -> int | None:
        try:
            return self.object_path(oid).stat().st_size
        except FileNotFoundError:
            return None

    # ----------------------------------------------------------------- config, partial clones
    def read_config(self) -> dict:
        return json.loads((self.root / "config").read_bytes())

    def update_config(self, change: Callable[[dict], None]) -> dict:
        """Read-modify-write the config under a lock; keys this code does not know are kept."""
        from artifacts.locks import store_lock

        with store_lock(self.locks_dir, "config"):
            cfg = self.read_config()
            change(cfg)
            write_replace(self.root / "config", canonical_json(cfg) + b"\n")
        return cfg

    def fetch_missing(self, *oids: str) -> bool:
        """True when every object is here. A partial clone (`accrue pull --only`) left some objects
        on its promisor remote: those are fetched and verified now (by the fetchers installed with
        add_missing_fetcher: artifacts.remotes'); otherwise nothing happens."""
        missing = [o for o in oids if not self.has_object(o)]
        if not missing:
            return True
        if not any(r.get("promisor") for r in self.read_config().get("remotes", {}).values()):
            return False
        return any(fetch(self, missing) for fetch in _MISSING_FETCHERS)

    def is_promised(self, oid: str) -> bool:
        """Whether a partial pull deliberately left this object on a remote (verify excuses it):
        its id is listed in remotes/<name>/promised."""
        if self._promised is None:
            promised: set[str] = set()
            base = self.root / "remotes"
            for path in base.glob("*/promised") if base.is_dir() else ():
                promised.update(line for line in path.read_text().split() if line)
            self._promised = promised
        return oid in self._promised

    def quarantine(self, oid: str) -> Path:
        """Move a corrupt object aside (never delete it): readers then see it as missing."""
        src = self.object_path(oid)
        dest = self.quarantine_dir / f"{oid}.{os.getpid()}-{int.from_bytes(os.urandom(3), 'big')}"
        self.quarantine_dir.mkdir(exist_ok=True)
        os.rename(src, dest)
        fsync_dir(src.parent)
        fsync_dir(self.quarantine_dir)
        return dest

    # ----------------------------------------------------------------- ids
    def resolve_prefix(self, prefix: str) -> str:
        """A full id from an unambiguous hex prefix of at least 4 digits (like git)."""
        text = prefix.lower()
        if is_full_id(text):
            return text
        if len(text) < 4 or any(c not in "0123456789abcdef" for c in text):
            raise StoreError(f"{quote(prefix)} is neither a ref nor an id (ids are hex, at least 4 digits)")
        fan = self.objects_dir / text[:2]
        matches = (
            sorted(fan.name + p.name for p in fan.iterdir() if p.name.startswith(text[2:])) if fan.is_dir() else []
        )
        if not matches:
            raise StoreError(f"no object or ref matches {quote(prefix)}")
        if len(matches) > 1:
            raise StoreError(
                f"id prefix {quote(prefix)} is ambiguous ({len(matches)} objects: "
                f"{', '.join(m[:12] for m in matches[:4])}…); give more digits"
            )
        return matches[0]

    def new_tmp_dir(self, prefix: str) -> Path:
        path = self.tmp_dir / f"{prefix}-{os.getpid()}-{os.urandom(4).hex()}"
        path.mkdir(parents=True)
        return path


class _WriteErrors:
    """Context: an OSError (disk full, read-only filesystem, …) becomes one StoreError line."""

    def __init__(self, root: Path) -> None:
        self.root = root

    def __enter__(self) -> None:
        return None

    def __exit__(self, kind, exc, tb) -> bool:
        if isinstance(exc, OSError):
            raise store_os_error(exc, f"cannot write to the store at {self.root}") from None
        return False


def make_writable_tree(path: Path) -> None:
    """Give the owner write access to the directories (not the files: some may be hard links to
    read-only objects) so a materialised read-only copy can be removed."""
    for root, _dirs, _files in os.walk(path):
        os.chmod(root, stat.S_IRWXU)


def remove_tree(path: Path) -> None:
    import shutil

    if path.exists():
        make_writable_tree(path)
        shutil.rmtree(path, ignore_errors=True)
