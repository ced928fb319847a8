"""Hashing, objects, trees, manifests, refs, id resolution and the audit log."""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path

import blake3
import pytest

from artifacts.auditlog import append_event, check_chain, iter_events
from artifacts.errors import StoreError
from artifacts.hashing import canonical_json, copy_hashing, hash_file, hash_json
from artifacts.ingest import add_path
from artifacts.manifests import materialize, publish_artifact, put_tree, read_artifact, read_tree, verify_artifact
from artifacts.refs import list_refs, read_ref, set_ref
from artifacts.resolve import resolve
from artifacts.store import Store


@pytest.fixture
def store(tmp_path: Path) -> Store:
    return Store.init(tmp_path / "store")[0]


def make_tree(root: Path, files: dict[str, bytes], order=None) -> Path:
    root.mkdir(parents=True)
    for rel in order or files:
        p = root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(files[rel])
    return root


def test_init_writes_config_and_is_idempotent(tmp_path):
    st, created = Store.init(tmp_path / "s")
    assert created
    assert json.loads((tmp_path / "s" / "config").read_text()) == {"format": 1, "hash": "blake3"}
    assert Store.init(tmp_path / "s")[1] is False


def test_open_refuses_missing_or_foreign_store(tmp_path):
    with pytest.raises(StoreError, match="no accrue store"):
        Store.open(tmp_path / "nothing")
    Store.init(tmp_path / "s")
    os.chmod(tmp_path / "s" / "config", 0o644)
    (tmp_path / "s" / "config").write_text('{"format": 9, "hash": "md5"}')
    with pytest.raises(StoreError, match="unsupported store format"):
        Store.open(tmp_path / "s")


def test_canonical_json_is_order_independent_and_rejects_nan():
    assert canonical_json({"b": 1, "a": [1, 2]}) == b'{"a":[1,2],"b":1}'
    assert hash_json({"x": 1, "y": 2}) == hash_json({"y": 2, "x": 1})
    with pytest.raises(ValueError):
        canonical_json({"x": float("nan")})


@pytest.mark.parametrize("size", [0, 1, 4096, 5 * 1024 * 1024 + 3, 33 * 1024 * 1024 + 5])  # last: pipelined copy
def test_file_hash_and_one_pass_copy_match_blake3(tmp_path, size):
    data = os.urandom(size)
    src = tmp_path / "f"
    src.write_bytes(data)
    expected = blake3.blake3(data).hexdigest()
    assert hash_file(src) == (expected, size)
    fd = os.open(tmp_path / "copy", os.O_WRONLY | os.O_CREAT)
    with open(src, "rb", buffering=0) as f:
        assert copy_hashing(f, fd, size) == (expected, size)
    os.close(fd)
    assert (tmp_path / "copy").read_bytes() == data


def test_objects_are_write_once_read_only_and_under_fanout(store, tmp_path):
    oid = store.put_bytes(b"hello")
    path = store.object_path(oid)
    assert path == store.root / "objects" / "blake3" / oid[:2] / oid[2:]
    assert oid == blake3.blake3(b"hello").hexdigest()
    assert stat.S_IMODE(path.stat().st_mode) == 0o444
    inode = path.stat().st_ino
    assert store.put_bytes(b"hello") == oid and path.stat().st_ino == inode
    src = tmp_path / "ext"
    src.write_bytes(b"hello")
    assert store.ingest_file(src) == (oid, 5)
    assert path.stat().st_ino == inode
    assert list(store.tmp_dir.iterdir()) == []  # no temp file left behind


def test_tree_id_is_canonical_whatever_the_creation_order(store, tmp_path):
    files = {"b.bin": b"2", "a/z.txt": b"1", "a/b.txt": b"3"}
    t1 = put_tree(store, make_tree(tmp_path / "x", files), "copy")
    t2 = put_tree(store, make_tree(tmp_path / "y", files, order=["a/b.txt", "b.bin", "a/z.txt"]), "copy")
    assert t1 == t2 and t1["files"] == 3 and t1["size"] == 3
    assert [e["path"] for e in read_tree(store, t1["tree"])] == ["a/b.txt", "a/z.txt", "b.bin"]
    t3 = put_tree(store, make_tree(tmp_path / "z", {**files, "b.bin": b"changed"}), "copy")
    assert t3["tree"] != t1["tree"]


def test_symlinks_are_refused(store, tmp_path):
    d = make_tree(tmp_path / "d", {"a": b"1"})
    (d / "link").symlink_to(d / "a")
    with pytest.raises(StoreError, match="only regular files"):
        put_tree(store, d, "copy")


def test_artifact_manifest_records_identity_and_sizes(store, tmp_path):
    seed = publish_artifact(store, make_tree(tmp_path / "s", {"x": b"12"}), "demos", producer={"step": "add"})
    d = make_tree(tmp_path / "d", {"w.bin": b"abc", "sub/v.bin": b"defg"})
    aid = publish_artifact(
        store,
        d,
        "checkpoint",
        producer={"step": "train", "attempt": 1},
        inputs={"demos": seed},
        config={"seed": 3},
        code_version="v1",
    )
    m = read_artifact(store, aid)
    assert m["kind"] == "checkpoint" and m["layout"] == "dir" and m["size"] == 7 and m["files"] == 2
    assert m["inputs"] == {"demos": seed} and m["config"] == {"seed": 3} and m["code_version"] == "v1"
    # the attempt and the time are provenance (attempt record, audit log), not part of the id
    assert m["producer"] == {"step": "train"} and "created" not in m and m["format"] == 2
    with pytest.raises(StoreError, match="bad artifact kind"):
        publish_artifact(store, d, "Bad Kind!", producer={})


def test_adopting_files_that_already_exist_does_not_rewrite_them(store, tmp_path):
    shard = b"sealed replay shard" * 10000
    first = publish_artifact(
        store,
        make_tree(tmp_path / "c1", {"shard-0.bin": shard, "s.json": b"1"}),
        "checkpoint",
        producer={},
        how="checked",
    )
    oid = {e["path"]: e["id"] for e in read_tree(store, read_artifact(store, first)["content"])}["shard-0.bin"]
    before = store.object_path(oid).stat()
    second = publish_artifact(
        store,
        make_tree(tmp_path / "c2", {"shard-0.bin": shard, "s.json": b"2"}),
        "checkpoint",
        producer={},
        how="adopt",
    )
    after = store.object_path(oid).stat()
    assert (after.st_ino, after.st_mtime_ns) == (before.st_ino, before.st_mtime_ns)
    assert {e["path"]: e["id"] for e in read_tree(store, read_artifact(store, second)["content"])}["shard-0.bin"] == oid


def test_materialize_gives_verified_read_only_copy(store, tmp_path):
    aid = publish_artifact(store, make_tree(tmp_path / "d", {"a/b.txt": b"x" * 100}), "replay", producer={})
    out = materialize(store, aid, tmp_path / "m")
    assert (out / "a" / "b.txt").read_bytes() == b"x" * 100
    assert stat.S_IMODE((out / "a" / "b.txt").stat().st_mode) == 0o444  # (root could still write)
    assert stat.S_IMODE((out / "a").stat().st_mode) == 0o555
    fid = publish_artifact(store, tmp_path / "d" / "a" / "b.txt", "eval", producer={})
    assert materialize(store, fid, tmp_path / "unused") == store.object_path(read_artifact(store, fid)["content"])


def test_add_is_idempotent_and_indexes_content(store, tmp_path):
    d = make_tree(tmp_path / "ds", {"meta/info.json": b"{}", "data/chunk-000/file-000.parquet": b"PAR1"})
    a1, new1 = add_path(store, d, "demos", ref="demos/task1")
    a2, new2 = add_path(store, d, "demos")
    assert new1 and not new2 and a1 == a2
    assert read_ref(store, "demos/task1") == a1
    a3, new3 = add_path(store, d, "episodes")
    assert new3 and a3 != a1


def test_refs_validate_names_and_targets(store):
    oid = store.put_json({"type": "artifact"})
    with pytest.raises(StoreError, match="bad ref name"):
        set_ref(store, "../escape", oid)
    with pytest.raises(StoreError, match="no such object"):
        set_ref(store, "stage/1/handoff", "ab" * 32)
    assert set_ref(store, "stage/1/handoff", oid) is None
    other = store.put_json({"type": "artifact", "n": 2})
    assert set_ref(store, "stage/1/handoff", other) == oid
    assert list_refs(store, "stage/") == {"stage/1/handoff": other}
    with pytest.raises(StoreError, match="conflicts"):
        set_ref(store, "stage/1/handoff/deeper", oid)
    moved = [e for e in iter_events(store) if e["event"] == "ref-moved"]
    assert [(e["old"], e["new"]) for e in moved] == [(None, oid), (oid, other)]


def test_resolve_refs_full_ids_and_unambiguous_prefixes(store):
    ids = [store.put_bytes(str(i).encode()) for i in range(30)]
    target = ids[0]
    assert resolve(store, target[:10]) == target
    assert resolve(store, target.upper()) == target
    set_ref(store, "my/ref", target)
    assert resolve(store, "my/ref") == target
    with pytest.raises(StoreError, match="at least 4"):
        resolve(store, target[:3])
    with pytest.raises(StoreError, match="no object or ref"):
        resolve(store, next(p for p in ("ffff", "fffe", "fffd") if not any(i.startswith(p) for i in ids)))


def test_ambiguous_prefix_is_refused(store):
    from artifacts.hashing import hash_bytes

    seen: dict[str, bytes] = {}
    for i in range(100_000):  # find two contents whose ids share 4 hex digits (birthday bound)
        data = str(i).encode()
        prefix = hash_bytes(data)[:4]
        if prefix in seen:
            break
        seen[prefix] = data
    a, b = store.put_bytes(seen[prefix]), store.put_bytes(data)
    with pytest.raises(StoreError, match="ambiguous"):
        resolve(store, prefix)
    assert resolve(store, a[:8]) == a and resolve(store, b[:8]) == b or a[:8] == b[:8]


def test_audit_log_is_hash_chained_and_tampering_is_seen(store):
    for i in range(5):
        append_event(store, "test", n=i)
    n, problems = check_chain(store)
    assert n == 5 and problems == []
    events = list(iter_events(store))
    assert [e["seq"] for e in events] == list(range(5))
    assert events[0]["prev"] == "0" * 64
    lines = store.log_path.read_bytes().splitlines(keepends=True)
    lines[2] = lines[2].replace(b'"n":2', b'"n":9')
    store.log_path.write_bytes(b"".join(lines))
    n, problems = check_chain(store)
    assert any("line 4" in p and "chain broken" in p for p in problems)
    del lines[2]
    lines[2:3] = lines[2:3]
    store.log_path.write_bytes(b"".join(lines))
    assert check_chain(store)[1]


def test_verify_artifact_detects_missing_and_corrupt_objects(store, tmp_path):
    aid = publish_artifact(store, make_tree(tmp_path / "d", {"a": b"a" * 50, "b": b"b" * 50}), "replay", producer={})
    verify_artifact(store, aid)
    entry = read_tree(store, read_artifact(store, aid)["content"])[1]
    path = store.object_path(entry["id"])
    os.chmod(path, 0o644)
    path.write_bytes(b"b" * 49 + b"X")
    with pytest.raises(StoreError, match="corrupt"):
        verify_artifact(store, aid)
    verify_artifact(store, aid, full=False)  # same size: the quick check cannot see it
    path.unlink()
    with pytest.raises(StoreError, match="missing"):
        verify_artifact(store, aid, full=False)
