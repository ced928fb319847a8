"""What each side says: the remote's format check, its refs and log pointers (read with a
version cache), this store's refs and remote-tracking refs, and which refs a command means."""

from __future__ import annotations

import json
from pathlib import Path

from artifacts.atomic import write_replace
from artifacts.errors import StoreError
from artifacts.hashing import HASH_NAME, canonical_json, is_full_id
from artifacts.locks import store_lock
from artifacts.refs import check_ref_name, list_refs
from artifacts.remotes import RESERVED, TRACKING
from artifacts.remotes.backends import Backend, RefMoved
from artifacts.remotes.config import RemoteSpec
from artifacts.store import Store

REMOTE_CONFIG = {"format": 1, "hash": HASH_NAME, "type": "accrue-remote"}
HEAD_MAX = 256  # up to this many candidates are checked one HEAD each; more: one listing


def state_dir(store: Store, remote: str) -> Path:
    return store.root / "remotes" / remote


def load_json(path: Path) -> dict:
    try:
        return json.loads(path.read_bytes())
    except (FileNotFoundError, ValueError):
        return {}


def save_json(path: Path, value: dict) -> None:
    write_replace(path, canonical_json(value) + b"\n")


def local_refs(store: Store) -> dict[str, str]:
    return {n: i for n, i in list_refs(store).items() if not n.startswith(RESERVED)}


def tracking_refs(store: Store, remote: str, space: str = TRACKING) -> dict[str, str]:
    prefix = f"{space}/{remote}/"
    return {n[len(prefix) :]: i for n, i in list_refs(store, prefix).items()}


def used_before(store: Store, remote: str) -> bool:
    """Has this store pushed to or pulled from the remote (what it knows of it is kept)?"""
    state = state_dir(store, remote)
    return any((state / f).is_file() for f in ("base.json", "refs.json", "log.json")) or bool(
        tracking_refs(store, remote)
    )


def merge_bases(store: Store, remote: str) -> dict[str, str]:
    """Per ref, the id this store and the remote last agreed on (after a push or pull, not a bare
    fetch): which side moved since is what push and pull decide by. Stores from before this was
    kept fall back to their remote-tracking refs."""
    return {**tracking_refs(store, remote), **load_json(state_dir(store, remote) / "base.json")}


def record_bases(store: Store, remote: str, agreed: dict[str, str]) -> None:
    if not agreed:
        return
    path = state_dir(store, remote) / "base.json"
    with store_lock(store.locks_dir, f"remote-{remote}"):
        bases = load_json(path)
        if all(bases.get(n) == i for n, i in agreed.items()):
            return
        bases.update(agreed)
        path.parent.mkdir(parents=True, exist_ok=True)
        save_json(path, bases)


def forget_bases(store: Store, remote: str, names: list[str]) -> None:
    path = state_dir(store, remote) / "base.json"
    with store_lock(store.locks_dir, f"remote-{remote}"):
        bases = load_json(path)
        if any(n in bases for n in names):
            save_json(path, {n: i for n, i in bases.items() if n not in names})


def select_refs(names: dict[str, str], wanted: list[str], where: str) -> dict[str, str]:
    """Every ref when nothing is named; else each name picks that ref or the refs under it."""
    if not wanted:
        return dict(names)
    out: dict[str, str] = {}
    for w in wanted:
        w = w.rstrip("/")
        if w.startswith(RESERVED):
            raise StoreError(f"{w}: remote-tracking refs are never pushed or pulled")
        hit = {n: i for n, i in names.items() if n == w or n.startswith(w + "/")}
        if not hit:
            raise StoreError(f"no ref {w!r} {where}")
        out.update(hit)
    return out


def short(oid: str | None) -> str:
    return oid[:12] if oid else "nothing"


DISPLACED = "displaced"  # refs/displaced/<ref>/<id12>: what a --force took a ref away from


def displaced_ref(name: str, oid: str) -> str:
    return f"{DISPLACED}/{name}/{oid[:12]}"


def both_moved(name: str, remote: str, mine: str, theirs: str | None, last: str | None) -> str:
    """The one line for a ref that moved on both sides since this store last saw the remote:
    both ids, and the two ways on, neither of which loses the other side's work."""
    since = f"since {short(last)}" if last else "(this store never saw it there)"
    if theirs is None:  # push lost its swap to a deletion: there is nothing of the remote's to keep
        return (
            f"ref {name}: moved here to {short(mine)} and deleted on remote {remote} {since}; "
            f"`accrue push --force {remote} {name}` puts this store's back there"
        )
    return (
        f"ref {name}: moved on both sides {since}: this store has {short(mine)}, remote {remote} has "
        f"{short(theirs)}; `accrue pull --force {remote} {name}` takes the remote's (this store's kept as "
        f"ref {displaced_ref(name, mine)}), `accrue push --force {remote} {name}` sends this store's (the "
        f"remote's kept there as ref {displaced_ref(name, theirs)})"
    )


def init_hint(backend: Backend) -> str:
    return f"`accrue remote init {backend.spec.name}` makes it one"


def check_remote_config(backend: Backend, create: bool, known: bool = False) -> None:
    """Refuse what is not an accrue remote in one line. With create (push), an existing directory or
    prefix that holds nothing yet becomes one — unless this store has used it before (known): a
    remote that lost its config was unmounted, wiped or is another endpoint, and is never made again
    behind the user's back. A directory remote's own directory is never made here."""
    raw = backend.get_bytes("config")
    if raw is None:
        try:
            backend.probe(False)  # a missing directory or bucket is one line (an S3 listing tells it apart)
        except StoreError as exc:
            if create and backend.spec.kind == "dir":
                raise StoreError(f"{exc}; nothing was written — if it is a new remote, {init_hint(backend)}") from None
            raise
        if not create:
            raise StoreError(f"{backend.describe()} holds no accrue store yet (push to it first)")
        if known:
            raise StoreError(
                f"{backend.describe()} holds no accrue store, but this store has used it before (another disk "
                f"mounted there, a wiped remote, the wrong endpoint?); nothing was written — if it is meant "
                f"to start afresh, {init_hint(backend)}"
            )
        try:
            backend.swap("config", canonical_json(REMOTE_CONFIG) + b"\n", None)
        except RefMoved:
            pass  # another store created it at the same moment
        return
    try:
        cfg = json.loads(raw)
    except ValueError:
        cfg = {}
    if not isinstance(cfg, dict) or cfg.get("type") != "accrue-remote":
        raise StoreError(f"{backend.describe()}: its config is not an accrue remote's")
    if cfg.get("format") != REMOTE_CONFIG["format"] or cfg.get("hash") != HASH_NAME:
        raise StoreError(
            f"{backend.describe()}: unsupported remote format {cfg.get('format')!r} / hash {cfg.get('hash')!r}"
        )


def read_pointers(store: Store, spec: RemoteSpec, backend: Backend, space: str) -> dict[str, tuple[str, str]]:
    """Remote refs (space "refs") or log pointers ("logs"): name -> (id, version). One listing;
    a value is fetched only when its version differs from the one cached in remotes/<name>/."""
    cache_path = state_dir(store, spec.name) / f"{space}.json"
    cache = load_json(cache_path)
    out: dict[str, tuple[str, str]] = {}
    for key, version in sorted(backend.list_versions(space).items()):
        name = key[len(space) + 1 :]
        try:
            check_ref_name(name)
        except StoreError:
            continue  # not a ref (e.g. an editor's backup file)
        if name.startswith(RESERVED):
            continue  # another store's tracking refs are its own business
        cached = cache.get(name)
        if cached and version and cached[0] == version:
            out[name] = (cached[1], version)
            continue
        got = backend.read_versioned(key)
        if got is None:
            continue  # removed meanwhile
        text = got[0].decode(errors="replace").strip()
        if not is_full_id(text):
            raise StoreError(f"{backend.describe()}: {key} is damaged (holds {text[:20]!r}, not an id)")
        out[name] = (text, got[1])
    fresh = {n: [v, i] for n, (i, v) in out.items()}
    if fresh != cache:
        state_dir(store, spec.name).mkdir(parents=True, exist_ok=True)
        save_json(cache_path, fresh)
    return out


def remember_version(store: Store, remote: str, space: str, name: str, oid: str, version: str) -> None:
    path = state_dir(store, remote) / f"{space}.json"
    with store_lock(store.locks_dir, f"remote-{remote}"):
        cache = load_json(path)
        cache[name] = [version, oid]
        path.parent.mkdir(parents=True, exist_ok=True)
        save_json(path, cache)
