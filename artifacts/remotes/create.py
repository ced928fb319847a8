"""remote init (and `remote add --create`): make a remote. The only way a directory remote's own
directory comes to exist through accrue — a push to one that vanished (an unmounted disk) is
refused instead — and the way a remote that lost its store (wiped) starts afresh."""

from __future__ import annotations

import shutil

from artifacts.errors import StoreError
from artifacts.hashing import canonical_json
from artifacts.locks import store_lock
from artifacts.remotes import TRACKING
from artifacts.remotes.backends import RefMoved
from artifacts.remotes.config import get_remote
from artifacts.remotes.connect import open_backend
from artifacts.remotes.pointers import REMOTE_CONFIG, check_remote_config, state_dir
from artifacts.store import Store

# what this store knows of the remote's past: a new remote has none of it
_STATE = ("base.json", "refs.json", "logs.json", "log.json", "present.json", "present.ids")


def init_remote(store: Store, name: str) -> bool:
    """Make remote NAME an (empty) accrue remote; False if it is one already (nothing changes).
    A directory remote's directory is made if its parent exists (a mounted disk); a directory that
    holds files but no accrue store is refused. What this store remembered of the remote (where refs
    were last seen, what it held) is dropped, so the next push sends everything."""
    spec = get_remote(store, name)
    backend = open_backend(spec)
    if backend.get_bytes("config") is not None:
        check_remote_config(backend, create=False)  # refuses a config that is not an accrue remote's
        return False
    backend.probe(True)
    if spec.kind == "dir" and any(p.is_file() for p in spec.path.rglob("*")):  # empty folders are fine
        raise StoreError(
            f"{backend.describe()}: the directory holds files but no accrue store; "
            "use an empty or new directory (nothing was written)"
        )
    try:
        backend.swap("config", canonical_json(REMOTE_CONFIG) + b"\n", None)
    except RefMoved:
        return False  # another store made it at the same moment
    _forget_state(store, spec.name)
    return True


def _forget_state(store: Store, remote: str) -> None:
    state = state_dir(store, remote)
    for name in _STATE:
        (state / name).unlink(missing_ok=True)
    with store_lock(store.locks_dir, "refs"):
        shutil.rmtree(store.refs_dir / TRACKING / remote, ignore_errors=True)
