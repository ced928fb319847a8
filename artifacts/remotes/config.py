"""The remotes a store knows (kept in the store's config) and what their URLs mean."""

from __future__ import annotations

import re
import uuid
from dataclasses import dataclass, field
from pathlib import Path

from artifacts.errors import StoreError
from artifacts.store import Store

_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,39}$")


@dataclass(frozen=True)
class RemoteSpec:
    name: str
    url: str
    kind: str  # "s3" or "dir"
    bucket: str = ""  # s3 only
    prefix: str = ""  # s3 only: key prefix inside the bucket, no slashes at either end
    path: Path | None = None  # dir only: absolute directory
    promisor: bool = False
    settings: dict = field(default_factory=dict, hash=False, compare=False)  # s3 only: endpoint, profile, region


# `s3:/x`, `s3:x`, `file:/x`: a scheme without its `//` is a typo, never a directory name
_SCHEME_TYPO = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]+:(?!//)")
# S3's bucket naming rules (3-63 of a-z 0-9 . -, starting and ending with a letter or digit)
_BUCKET = re.compile(r"^[a-z0-9][a-z0-9.-]{1,61}[a-z0-9]$")
SETTINGS = ("endpoint", "profile", "region")  # per-remote S3 settings (`accrue remote set`)


def parse_url(name: str, url: str, promisor: bool = False, settings: dict | None = None) -> RemoteSpec:
    """s3://bucket[/prefix] (any S3-compatible service), or a directory (path or file://path)."""
    if not url.strip():
        raise StoreError("remote URL is empty (use s3://BUCKET/PREFIX or a directory)")
    if url.startswith(("s3://", "s3a://")):
        rest = url.split("://", 1)[1]
        bucket, _, prefix = rest.partition("/")
        if not bucket:
            raise StoreError(f"remote URL {url!r} names no bucket (use s3://BUCKET/PREFIX)")
        if not _BUCKET.match(bucket):
            raise StoreError(f"remote URL {url!r}: {bucket!r} is not a valid S3 bucket name (3-63 of a-z 0-9 . -)")
        return RemoteSpec(
            name, url, "s3", bucket=bucket, prefix=prefix.strip("/"), promisor=promisor, settings=settings or {}
        )
    if "://" in url and not url.startswith("file://"):
        raise StoreError(f"remote URL {url!r}: unsupported scheme (use s3://BUCKET/PREFIX or a directory)")
    if _SCHEME_TYPO.match(url):
        raise StoreError(
            f"remote URL {url!r} is malformed (a scheme needs '//': s3://BUCKET/PREFIX or file:///PATH; "
            "a directory whose name has ':' as ./NAME)"
        )
    path = Path(url[len("file://") :] if url.startswith("file://") else url).expanduser()
    return RemoteSpec(name, url, "dir", path=path.absolute(), promisor=promisor)


def check_remote_name(name: str) -> str:
    if not _NAME.match(name):
        raise StoreError(f"bad remote name {name!r}: use letters, digits, '.', '_', '-' (e.g. origin, nas)")
    return name


def list_remotes(store: Store) -> dict[str, RemoteSpec]:
    return {
        name: parse_url(name, r["url"], bool(r.get("promisor")), {k: r[k] for k in SETTINGS if r.get(k)})
        for name, r in sorted(store.read_config().get("remotes", {}).items())
    }


def get_remote(store: Store, name: str) -> RemoteSpec:
    remotes = list_remotes(store)
    if name not in remotes:
        known = ", ".join(remotes) or "none; add one with `accrue remote add NAME URL`"
        raise StoreError(f"no remote named {name!r} (known: {known})")
    return remotes[name]


def add_remote(store: Store, name: str, url: str) -> RemoteSpec:
    spec = parse_url(check_remote_name(name), url)
    if spec.kind == "dir":
        _outside_store(store, spec)
    stored = str(spec.path) if spec.kind == "dir" else url  # a relative path means where it was added

    def change(cfg: dict) -> None:
        remotes = cfg.setdefault("remotes", {})
        if name in remotes:
            raise StoreError(f"remote {name!r} exists already ({remotes[name]['url']}); remove it first")
        remotes[name] = {"url": stored}

    store.update_config(change)
    return parse_url(name, stored)


def _outside_store(store: Store, spec: RemoteSpec) -> None:
    """A directory remote inside the store would write its objects/ and refs/ among the store's."""
    here, there = store.root.resolve(), spec.path.resolve()
    if there == here or here in there.parents:
        raise StoreError(
            f"remote {spec.name}: {spec.path} is inside this store ({store.root}); use a directory outside it"
        )


def check_setting(spec: RemoteSpec, key: str, value: str | None) -> None:
    if key not in SETTINGS:
        raise StoreError(f"unknown remote setting {key!r} (settings: {', '.join(SETTINGS)})")
    if spec.kind != "s3":
        raise StoreError(f"remote {spec.name} is a directory; {key} applies to S3 remotes only")
    if key == "endpoint" and value is not None and not re.match(r"^https?://[^/\s]+", value):
        raise StoreError(f"endpoint {value!r} is not an http(s) URL (e.g. http://minio.lab:9000)")


def set_setting(store: Store, name: str, key: str, value: str | None) -> RemoteSpec:
    """Per-remote S3 settings (over the AWS_* environment): endpoint, profile, region; None unsets."""
    spec = get_remote(store, name)
    check_setting(spec, key, value)

    def change(cfg: dict) -> None:
        entry = cfg["remotes"][spec.name]
        if value is None:
            entry.pop(key, None)
        else:
            entry[key] = value

    store.update_config(change)
    return get_remote(store, spec.name)


def set_promisor(store: Store, name: str) -> None:
    def change(cfg: dict) -> None:
        cfg["remotes"][name]["promisor"] = True

    store.update_config(change)


def remove_remote_entry(store: Store, name: str) -> None:
    def change(cfg: dict) -> None:
        cfg.get("remotes", {}).pop(name, None)

    store.update_config(change)


def pick_remote(store: Store, words: list[str]) -> tuple[RemoteSpec, list[str]]:
    """`push [NAME] [REF…]`: the first word is a remote if one has that name; else the only
    remote (or the one named origin) is meant and every word is a ref."""
    remotes = list_remotes(store)
    if words and words[0] in remotes:
        return remotes[words[0]], words[1:]
    if len(remotes) == 1:
        return next(iter(remotes.values())), words
    if "origin" in remotes:
        return remotes["origin"], words
    if not remotes:
        raise StoreError("this store has no remotes; add one with `accrue remote add NAME URL`")
    raise StoreError(f"which remote? this store has {', '.join(remotes)}; name one first")


def _home(store: Store) -> dict:
    """Where the store lives: a copy (`cp -a`, rsync) carries the config but has another path and
    inode. A move (`mv`) keeps the inode; a store left in place keeps its path (an inode that
    changes under a remount, as on some overlay filesystems, is not a copy)."""
    return {"path": str(store.root.resolve()), "ino": store.root.stat().st_ino}


def _copied(recorded: object, now: dict) -> bool:
    if isinstance(recorded, int):  # a marker of the inode alone
        return recorded != now["ino"]
    if not isinstance(recorded, dict):
        return False
    return recorded.get("path") != now["path"] and recorded.get("ino") != now["ino"]


def check_not_copied(store: Store) -> str | None:
    """This store's id if it has one with its directory recorded; StoreError if that directory
    is another (the store was copied). Reads only."""
    cfg = store.read_config()
    sid, home = cfg.get("store_id"), cfg.get("store_home")
    if sid and home is not None and _copied(home, _home(store)):
        raise StoreError(
            f"this store's id {sid[:12]} was made in another directory (a copy, e.g. cp -a?); "
            "run `accrue remote rekey` to give this copy its own id"
        )
    return sid if sid and home is not None else None


def store_id(store: Store) -> str:
    """A stable random id for this store, made on first use: names its audit log on remotes. A
    copied store would share it and push over the original's log chain, so the directory the id
    was made in is recorded and a copy is refused until it is re-keyed."""
    sid = check_not_copied(store)
    if sid:
        return sid

    def change(c: dict) -> None:
        c.setdefault("store_id", uuid.uuid4().hex)
        c.setdefault("store_home", _home(store))

    return store.update_config(change)["store_id"]


def rekey_store(store: Store) -> tuple[str | None, str]:
    """A new store id (after a copy): its audit log starts a new chain on every remote."""
    old = store.read_config().get("store_id")

    def change(c: dict) -> None:
        c["store_id"], c["store_home"] = uuid.uuid4().hex, _home(store)

    new = store.update_config(change)["store_id"]
    base = store.root / "remotes"
    for state in base.glob("*/log.json") if base.is_dir() else ():
        state.unlink()  # the chain position on each remote was the old id's
    for logs in base.glob("*/logs.json") if base.is_dir() else ():
        logs.unlink()
    return old, new
