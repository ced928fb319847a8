"""Partial clones: `accrue pull --only KIND` leaves the data of other artifacts on the remote and
notes their ids here (remotes/<name>/promised). When a step needs one, the store's hook
(Store.fetch_missing, wired in artifacts/__init__.py) fetches it from a promisor remote, verified like any download."""

from __future__ import annotations

from artifacts.locks import store_lock
from artifacts.store import Store


def promised_path(store: Store, remote: str):
    return store.root / "remotes" / remote / "promised"


def add_promised(store: Store, remote: str, oids: list[str]) -> None:
    if not oids:
        return
    path = promised_path(store, remote)
    path.parent.mkdir(parents=True, exist_ok=True)
    with store_lock(store.locks_dir, "promised"):
        known = set(path.read_text().split()) if path.is_file() else set()
        new = sorted(set(oids) - known)
        if new:
            import os

            fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
            try:
                os.write(fd, ("\n".join(new) + "\n").encode())
                os.fsync(fd)
            finally:
                os.close(fd)
    store._promised = None


def fetch_promised(store: Store, missing: list[str]) -> bool:
    """Fetch missing objects from the promisor remotes (in config order). True if all arrived."""
    from artifacts.remotes.config import list_remotes
    from artifacts.remotes.connect import open_backend

    todo = list(dict.fromkeys(missing))
    for spec in (s for s in list_remotes(store).values() if s.promisor):
        if todo:
            todo = _fetch_from(store, open_backend(spec), spec.name, todo)
    return not todo


def _fetch_from(store: Store, backend, name: str, todo: list[str]) -> list[str]:
    """Download what one remote has (in parallel, verified); returns the ids it lacks."""
    from artifacts.remotes.backends import MissingOnRemote
    from artifacts.remotes.progress import RichMeter
    from artifacts.remotes.transfer import default_jobs, download_object, parallel

    meter = RichMeter()
    meter.start(f"fetching from {name}", len(todo), 0)  # sizes unknown until they arrive

    def one(oid: str) -> str | None:
        try:
            meter.advance(download_object(store, backend, oid))
            return None
        except MissingOnRemote:
            return oid

    try:
        return [o for o in parallel(one, todo, default_jobs()) if o is not None]
    finally:
        meter.stop()
