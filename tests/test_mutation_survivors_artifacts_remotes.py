"""Tests written to kill mutants of artifacts/remotes/ (and the store's hook for them) that survived
round 3 of mutmut's fourth sweep (docs/MUTATION.md, "The fourth sweep"). Each docstring names the mutmut
ids it kills. What they pin: a directory remote's ref deletion only removes the version it was told
to, with one-line refusals; and a partial clone's missing object is fetched through the fetcher the
remotes register. Everything runs in a temporary directory, without a network.
"""

from __future__ import annotations

from pathlib import Path

import pytest

import artifacts.store
from artifacts.errors import StoreError
from artifacts.hashing import hash_bytes
from artifacts.remotes.backends import RefMoved
from artifacts.remotes.config import parse_url
from artifacts.remotes.directory import DirBackend
from artifacts.store import Store, add_missing_fetcher

KEY = "refs/team/handoff"


def dir_backend(path: Path) -> DirBackend:
    b = DirBackend(parse_url("nas", str(path)))
    b.probe(create=True)
    return b


# ----------------------------------------------------------------------------- remotes.directory.delete
def test_a_directory_remote_deletes_a_ref_only_at_the_version_it_was_told(tmp_path):
    """DirBackend.delete 4 (a moved ref deleted anyway; a missing one a traceback), 8 (RefMoved carries
    the key)."""
    b = dir_backend(tmp_path / "remote")
    b.swap(KEY, b"one\n", None)
    with pytest.raises(RefMoved) as exc:
        b.delete(KEY, "two\n")
    assert exc.value.args == (KEY,)
    assert b.get_bytes(KEY) == b"one\n"
    b.delete(KEY, "one\n")
    assert b.get_bytes(KEY) is None
    with pytest.raises(RefMoved) as exc:
        b.delete(KEY, "one\n")
    assert exc.value.args == (KEY,)


def test_a_ref_deletion_that_cannot_lock_names_the_remote_key_and_reason(tmp_path):
    """DirBackend.delete 12, 13: the OSError's reason (its strerror), not its repr, after the remote and key."""
    root = tmp_path / "remote"
    b = dir_backend(root)
    b.swap(KEY, b"one\n", None)
    (root / "locks" / "refs" / "team").rmdir()  # the swap's lock directory, empty again
    (root / "locks" / "refs" / "team").write_text("a file where the lock's directory should be")
    with pytest.raises(StoreError) as exc:
        b.delete(KEY, "one\n")
    assert str(exc.value) == f"remote nas ({root}): cannot remove {KEY}: File exists"
    assert b.get_bytes(KEY) == b"one\n"


# ----------------------------------------------------------------------------- store.add_missing_fetcher
def test_a_partial_clones_missing_object_comes_through_the_registered_fetcher(tmp_path, monkeypatch):
    """store.add_missing_fetcher 1 (never registered: the object stays missing), 2 (None registered: a
    traceback); registering the same fetcher twice keeps one."""
    monkeypatch.setattr(artifacts.store, "_MISSING_FETCHERS", [])
    store, _ = Store.init(tmp_path / "store")
    store.update_config(lambda c: c.setdefault("remotes", {}).update({"origin": {"url": "x", "promisor": True}}))
    data = b"left on the remote by pull --only"
    oid = hash_bytes(data)
    asked: list[list[str]] = []

    def fetch(s: Store, missing: list[str]) -> bool:
        asked.append(list(missing))
        s.put_bytes(data)
        return True

    add_missing_fetcher(fetch)
    add_missing_fetcher(fetch)
    assert artifacts.store._MISSING_FETCHERS == [fetch]
    assert store.read_bytes(oid) == data
    assert asked == [[oid]]
    store.close()
