"""The content-addressed artifact store (see docs/INTERFACES.md, "artifacts").

Knows nothing of RL: objects, artifact manifests, refs, attempt records, the audit log, verify, gc.
"""

from artifacts.errors import StoreError
from artifacts.store import Store, default_store_path

__all__ = ["Store", "StoreError", "default_store_path"]
