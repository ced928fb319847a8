"""The content-addressed artifact store (see docs/INTERFACES.md, "artifacts").

Knows nothing of RL: objects, artifact manifests, refs, attempt records, the audit log, verify, gc.
"""

from artifacts.errors import StoreError
from artifacts.store import Store, add_missing_fetcher, default_store_path


def _fetch_promised(store: Store, missing: list[str]) -> bool:
    """A partial clone's objects come from its promisor remotes (obstore loads only then)."""
    from artifacts.remotes.lazy import fetch_promised

    return fetch_promised(store, missing)


add_missing_fetcher(_fetch_promised)

__all__ = ["Store", "StoreError", "default_store_path"]
