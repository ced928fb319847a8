"""`accrue add`: bring an outside file or directory (e.g. a LeRobotDataset) into the store.

Adding the same bytes under the same kind twice returns the first artifact (found through the
ref ingested/<kind>/<content id>, which also keeps it from gc)."""

from __future__ import annotations

from pathlib import Path

from artifacts.auditlog import append_event, ensure_appendable
from artifacts.manifests import check_kind, read_artifact, store_content, utf8_name, write_manifest
from artifacts.refs import read_ref, set_ref
from artifacts.store import Store


def add_path(store: Store, path: Path, kind: str, ref: str | None = None) -> tuple[str, bool]:
    """Returns (artifact id, newly created)."""
    check_kind(kind)
    path = Path(path)
    source = utf8_name(str(path.absolute()), path)
    ensure_appendable(store)  # a damaged log refuses the add before anything is copied
    content = store_content(store, path, how="copy")
    index_ref = f"ingested/{kind}/{content['content']}"
    existing = read_ref(store, index_ref)
    if existing is not None and read_artifact(store, existing).get("content") == content["content"]:
        artifact_id, created = existing, False
    else:
        # the source path goes to the log, never the manifest: the id is a function of the content alone
        artifact_id = write_manifest(store, content, kind, producer={"step": "add"})
        append_event(store, "artifact-written", artifact=artifact_id, kind=kind, source=source)
        set_ref(store, index_ref, artifact_id)
        created = True
    if ref:
        set_ref(store, ref, artifact_id)
    return artifact_id, created
