"""remote remove: forget a remote (nothing on the remote changes)."""

from __future__ import annotations

from artifacts.errors import StoreError
from artifacts.locks import store_lock
from artifacts.remotes import LOG_TRACKING, TRACKING
from artifacts.remotes.config import get_remote
from artifacts.remotes.pointers import state_dir
from artifacts.store import Store


def forget_remote(store: Store, remote: str, force: bool = False) -> int:
    """Drop a remote: its config entry, its remote-tracking refs and what this store cached about
    it. A partial clone still relying on it is refused unless forced. Returns refs dropped."""
    import shutil

    from artifacts.remotes.config import remove_remote_entry
    from artifacts.remotes.lazy import promised_path

    spec = get_remote(store, remote)
    promised = promised_path(store, spec.name)
    if promised.is_file() and not force:
        lacking = [o for o in promised.read_text().split() if not store.has_object(o)]
        if lacking:
            raise StoreError(
                f"remote {spec.name} still holds {len(lacking)} object(s) this partial clone "
                f"left there (e.g. {lacking[0][:12]}); pull them first, or remove --force"
            )
    dropped = 0
    with store_lock(store.locks_dir, "refs"):
        for space in (TRACKING, LOG_TRACKING):
            base = store.refs_dir / space / spec.name
            if base.is_dir():
                dropped += sum(1 for p in base.rglob("*") if p.is_file())
                shutil.rmtree(base)
    shutil.rmtree(state_dir(store, spec.name), ignore_errors=True)
    remove_remote_entry(store, spec.name)
    store._promised = None
    return dropped
