"""Bench cells on nodes that share only a remote with the bench's store (issue 22): each node runs its
cells on a store of its own, filled from the remote and emptied back into it.

    share(store, "team")                                 # the bench's store, first: its refs on the remote
    target = remote_target(store, "team")               # {"name", "url", "settings"} for the cell's job
    node = open_node_store("~/.cache/accrue/bench-node-{host}", target)   # on the node; made on first use
    sync_in(node, target)                                # refs, manifests, step records; no data
    ...run the cell...                                   # inputs' data fetched when a step reads them
    sync_out(node, target, cell_name)                    # push workflow/<cell>/... and what it reaches
    collect(store, "team", cell_name)                    # the bench's store: pull the cell's refs

The node's store pulls every ref's manifests and step records, not their data, so a step another
cell committed anywhere is a cache hit here (the pulled step index) and only the data a step reads
crosses the network (the promisor remote's lazy fetch). Two cells of different nodes that need the
same uncached step both compute it: the step locks are per store.
"""

from __future__ import annotations

import socket
from pathlib import Path

from artifacts.errors import StoreError
from artifacts.locks import store_lock
from artifacts.refs import list_refs
from artifacts.remotes.config import SETTINGS, add_remote, get_remote, list_remotes, set_setting
from artifacts.remotes.connect import open_backend
from artifacts.remotes.pointers import check_remote_config, local_refs
from artifacts.remotes.pull import pull
from artifacts.remotes.push import push
from artifacts.store import Store
from stages.errors import StageError

DEFAULT_NODE_STORE = "~/.cache/accrue/bench-node-{host}"
# kinds whose data the head takes at once: the report reads evaluations (the rest arrives lazily)
COLLECT_KINDS = {"eval"}
OUTCOMES = "bench/"  # stages.bench.state.outcome_ref


def remote_target(store: Store, name: str) -> dict:
    """What a worker needs to reach the bench store's remote NAME (it has no access to that store)."""
    spec = get_remote(store, name)
    return {"name": spec.name, "url": spec.url, "settings": dict(spec.settings)}


def node_store_path(template: str) -> Path:
    """The node's store: {host} is this machine's name, {node} Ray's id of this node (else the host)."""
    host = socket.gethostname()
    return Path(template.replace("{host}", host).replace("{node}", _ray_node_id() or host)).expanduser()


def _ray_node_id() -> str | None:
    try:
        import ray

        return ray.get_runtime_context().get_node_id() if ray.is_initialized() else None
    except Exception:  # noqa: BLE001 - outside a Ray worker there is no node id
        return None


def open_node_store(template: str, target: dict) -> Store:
    """The node's store with the remote added under its name (cells of one node share both)."""
    root = node_store_path(template)
    root.parent.mkdir(parents=True, exist_ok=True)
    with store_lock(root.parent, f"{root.name}-make"):  # the node's first cells may start together
        store, _ = Store.init(root)
        known = list_remotes(store).get(target["name"])
        if known is None:
            add_remote(store, target["name"], target["url"])
        elif known.url != target["url"]:
            raise StageError(
                f"node store {root}: remote {target['name']} is {known.url} there, not {target['url']} "
                "(use another --node-store)"
            )
        have = known.settings if known is not None else {}
        for key in SETTINGS:  # endpoint, profile, region as the bench's store has them
            if target["settings"].get(key) != have.get(key):
                set_setting(store, target["name"], key, target["settings"].get(key))
    return store


def share(store: Store, remote: str) -> None:
    """Before the cells start: the bench store's refs (demos, base policies, earlier cells) on the remote."""
    # the bench's own cell outcomes (bench/...) are this store's bookkeeping, not artifacts
    names = [n for n in local_refs(store) if not n.startswith(OUTCOMES)]
    if not names:  # nothing to share yet: the remote is made a store, so that nodes can pull from it
        check_remote_config(open_backend(get_remote(store, remote)), create=True)
        return
    report = push(store, remote, names)
    if report.conflicts:
        raise StageError(f"push to remote {remote}: {report.conflicts[0]}; pull it first (`accrue pull {remote}`)")


def sync_in(store: Store, target: dict) -> None:
    """Refs, manifests and step records of the remote; every artifact's data stays there until read."""
    pull(store, target["name"], only=set())


def sync_out(store: Store, target: dict, workflow: str) -> None:
    """Push the cell's workflow refs and everything they reach (none when its first step failed);
    a conflict is the cell's error."""
    if not list_refs(store, f"workflow/{workflow}/"):
        return
    report = push(store, target["name"], [f"workflow/{workflow}"])
    if report.conflicts:
        raise StageError(f"push to remote {target['name']}: {report.conflicts[0]}")


def collect(store: Store, remote: str, workflow: str) -> None:
    """On the bench's store: the cell's refs, its evaluations' data (the rest lazily when read)."""
    report = pull(store, remote, [f"workflow/{workflow}"], only=COLLECT_KINDS)
    if report.conflicts:
        raise StoreError(f"pull from remote {remote}: {report.conflicts[0]}")
