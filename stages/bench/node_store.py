"""Bench cells on nodes that share only a remote with the bench's store (issue 22): each node runs its
cells on a store of its own, filled from the remote and emptied back into it.

    share(store, "team")                                 # the bench's store, first: its refs on the remote
    target = remote_target(store, "team")               # {"name", "url", "settings"} for the cell's job
    node = open_node_store("~/.cache/accrue/bench-node-{host}", target)   # on the node; made on first use
    sync_in(node, target)                                # refs, manifests, step records; no data
    ...run the cell...                                   # inputs' data fetched when a step reads them
    sync_out(node, target, cell_name)                    # push workflow/<cell>/... and what it reaches
    collect(store, "team", cell_name)                    # the bench's store: pull the cell's refs

A worker starts with the remote's settings as the bench's process resolved them (remote_target: the
endpoint and region, from the remote's config or the AWS_* environment) and with the credentials
that process was given (worker_credentials: AWS_ACCESS_KEY_ID, AWS_SECRET_ACCESS_KEY, AWS_SESSION_TOKEN
from its environment, or resolved from its AWS profile). The credentials travel in the cell's job
(CellJob.env, left out of its repr) into the worker's environment only: never into a log, a store's
config or the node store; the node store keeps the endpoint and region as its remote's settings.

The node's store pulls every ref's manifests and step records, not their data, so a step another
cell committed anywhere is a cache hit here (the pulled step index) and only the data a step reads
crosses the network (the promisor remote's lazy fetch). Two cells of different nodes that need the
same uncached step both compute it: the step locks are per store.
"""

from __future__ import annotations

import os
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


CREDENTIALS = ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY", "AWS_SESSION_TOKEN")


def remote_target(store: Store, name: str) -> dict:
    """What a worker needs to reach the bench store's remote NAME (it has no access to that store):
    its URL and S3 settings as this process resolves them (the environment's endpoint and region
    included; a profile left out when its credentials are passed instead: a worker may lack it)."""
    spec = get_remote(store, name)
    settings = dict(spec.settings)
    if spec.kind == "s3":
        from artifacts.remotes.s3 import endpoint_of

        endpoint = endpoint_of(spec)
        region = settings.get("region") or os.environ.get("AWS_REGION") or os.environ.get("AWS_DEFAULT_REGION")
        settings.update({k: v for k, v in (("endpoint", endpoint), ("region", region)) if v})
        if worker_credentials(store, name):
            settings.pop("profile", None)
    return {"name": spec.name, "url": spec.url, "settings": settings}


def worker_credentials(store: Store, name: str) -> dict:
    """The credentials this process was given for remote NAME, as AWS_* variables for a worker's
    environment (empty for a directory remote, or when there are none: the worker's own apply)."""
    spec = get_remote(store, name)
    if spec.kind != "s3":
        return {}
    env = os.environ
    profile = spec.settings.get("profile")
    if not profile and env.get("AWS_ACCESS_KEY_ID") and env.get("AWS_SECRET_ACCESS_KEY"):
        return {k: env[k] for k in CREDENTIALS if env.get(k)}
    import boto3
    from botocore.exceptions import BotoCoreError, ProfileNotFound

    try:
        found = boto3.Session(profile_name=profile or env.get("AWS_PROFILE") or None).get_credentials()
        frozen = found.get_frozen_credentials() if found is not None else None
    except (BotoCoreError, ProfileNotFound):
        return {}
    if frozen is None or not frozen.access_key or not frozen.secret_key:
        return {}
    keys = {"AWS_ACCESS_KEY_ID": frozen.access_key, "AWS_SECRET_ACCESS_KEY": frozen.secret_key}
    return {**keys, **({"AWS_SESSION_TOKEN": frozen.token} if frozen.token else {})}


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
