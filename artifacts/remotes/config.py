"""The remotes a store knows (kept in the store's config) and what their URLs mean."""

from __future__ import annotations

import re
import uuid
from dataclasses import dataclass
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


def parse_url(name: str, url: str, promisor: bool = False) -> RemoteSpec:
    """s3://bucket[/prefix] (any S3-compatible service), or a directory (path or file://path)."""
    if url.startswith(("s3://", "s3a://")):
        rest = url.split("://", 1)[1]
        bucket, _, prefix = rest.partition("/")
        if not bucket:
            raise StoreError(f"remote URL {url!r} names no bucket (use s3://BUCKET/PREFIX)")
        return RemoteSpec(name, url, "s3", bucket=bucket, prefix=prefix.strip("/"), promisor=promisor)
    if "://" in url and not url.startswith("file://"):
        raise StoreError(f"remote URL {url!r}: unsupported scheme (use s3://BUCKET/PREFIX or a directory)")
    path = Path(url[len("file://") :] if url.startswith("file://") else url).expanduser()
    return RemoteSpec(name, url, "dir", path=path.absolute(), promisor=promisor)


def check_remote_name(name: str) -> str:
    if not _NAME.match(name):
        raise StoreError(f"bad remote name {name!r}: use letters, digits, '.', '_', '-' (e.g. origin, nas)")
    return name


def list_remotes(store: Store) -> dict[str, RemoteSpec]:
    return {
        name: parse_url(name, r["url"], bool(r.get("promisor")))
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
    stored = str(spec.path) if spec.kind == "dir" else url  # a relative path means where it was added

    def change(cfg: dict) -> None:
        remotes = cfg.setdefault("remotes", {})
        if name in remotes:
            raise StoreError(f"remote {name!r} exists already ({remotes[name]['url']}); remove it first")
        remotes[name] = {"url": stored}

    store.update_config(change)
    return parse_url(name, stored)


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


def store_id(store: Store) -> str:
    """A stable random id for this store, made on first use: names its audit log on remotes."""
    cfg = store.read_config()
    if cfg.get("store_id"):
        return cfg["store_id"]

    def change(c: dict) -> None:
        c.setdefault("store_id", uuid.uuid4().hex)

    return store.update_config(change)["store_id"]
