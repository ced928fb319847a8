"""Issue 13, the store: gc never sweeps what a live writer has named; the audit log's tail cannot be
cut, edited or deleted unseen, and `verify --repair` seals such damage; gc logs before it deletes;
foreign files under refs/ are reported, not fatal; add refuses symlinked directories and a source
that shrinks meanwhile."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from artifacts import writers
from artifacts.auditlog import append_event, head_path, iter_events
from artifacts.errors import StoreError
from artifacts.gc import collect_garbage
from artifacts.ingest import add_path
from artifacts.manifests import read_artifact
from artifacts.records import list_attempts, write_attempt
from artifacts.refs import list_refs, read_ref, set_ref
from artifacts.store import Store
from artifacts.verify import verify_store

ROOT = Path(__file__).resolve().parents[1]
DAY = 86400


def old(store: Store, oid: str, age_s: float = 2 * DAY) -> None:
    """Age an object as if it had been written long ago (gc's grace no longer covers it)."""
    t = time.time() - age_s
    os.utime(store.object_path(oid), (t, t))


@pytest.fixture
def store(tmp_path: Path) -> Store:
    return Store.init(tmp_path / "store")[0]


def dataset(tmp_path: Path, name: str = "ds", payload: bytes = b"") -> Path:
    d = tmp_path / name
    (d / "meta").mkdir(parents=True)
    (d / "meta" / "info.json").write_text('{"fps": 10}')
    (d / "data.bin").write_bytes(payload or os.urandom(4000))
    return d


# ----------------------------------------------------------------------------- writer / gc protocol
WRITER = r"""
import sys, time
from pathlib import Path
from artifacts.manifests import store_content, write_manifest
from artifacts.refs import set_ref
from artifacts.store import Store

store = Store.open(Path(sys.argv[1]))
content = store_content(store, Path(sys.argv[2]))          # reuses objects that exist already
Path(sys.argv[3]).write_text("named")                       # the objects are named, not yet rooted
while not Path(sys.argv[4]).exists():
    time.sleep(0.02)
aid = write_manifest(store, content, "demos", producer={"step": "add", "source": sys.argv[2]})
set_ref(store, "demos/concurrent", aid)
print(aid)
"""


def test_gc_cannot_sweep_objects_a_live_writer_is_reusing(store, tmp_path):
    src = dataset(tmp_path)
    first, _ = add_path(store, src, "demos")
    content = read_artifact(store, first)
    for p in store.refs_dir.rglob("*"):  # unroot everything: the objects are now garbage…
        if p.is_file():
            p.unlink()
    for oid in store.iter_object_ids():
        old(store, oid)  # …and older than any grace period
    store.close()
    named, go = tmp_path / "named", tmp_path / "go"
    writer = subprocess.Popen(
        [sys.executable, "-c", WRITER, str(store.root), str(src), str(named), str(go)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 60
        while not named.exists():
            assert writer.poll() is None, writer.stderr.read()
            assert time.monotonic() < deadline
            time.sleep(0.02)
        gc = subprocess.run(
            [sys.executable, "-m", "cli.main", "gc", "--yes", "--grace", "0", "--store", str(store.root)],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert gc.returncode == 2 and gc.stderr.count("\n") == 1, gc.stderr
        assert "gc needs the store to itself" in gc.stderr and f"pid {writer.pid}" in gc.stderr
        assert store.has_object(content["content"])  # nothing was swept
    finally:
        go.write_text("go")
        out, err = writer.communicate(timeout=60)
    assert writer.returncode == 0, err
    assert read_ref(store, "demos/concurrent") == out.strip()
    report = verify_store(store, full=True)
    assert report.ok, report.problems
    # with the writer gone, gc runs (and keeps what the writer rooted)
    done = collect_garbage(store, dry_run=False, grace_s=0)
    assert content["content"] not in [o for o, _ in done.removed] and verify_store(store).ok


def test_gc_wait_lets_a_writer_finish_then_sweeps(store, tmp_path):
    loose = store.put_bytes(b"garbage")
    old(store, loose)
    store.close()
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time\nfrom artifacts.store import Store\n"
            "s = Store.open(sys.argv[1]); s.put_bytes(b'x'); print('held', flush=True)\n"
            "time.sleep(1.5)",
            str(store.root),
        ],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert holder.stdout.readline().strip() == "held"
    with pytest.raises(StoreError, match="gc needs the store to itself"):
        collect_garbage(store, dry_run=False, grace_s=0)
    assert store.has_object(loose)
    report = collect_garbage(store, dry_run=False, grace_s=0, wait_s=30)  # waits for the writer's exit
    holder.wait(timeout=30)
    assert loose in [o for o, _ in report.removed] and not store.has_object(loose)


def test_gc_in_a_process_that_wrote_converts_its_own_lock(store):
    loose = store.put_bytes(b"mine")  # this handle is a writer now
    old(store, loose)
    assert collect_garbage(store, dry_run=False, grace_s=0).removed
    other = Store.open(store.root)  # still a writer afterwards: gc elsewhere waits
    assert other.put_bytes(b"again")
    probe = subprocess.run(
        [sys.executable, "-m", "cli.main", "gc", "--store", str(store.root)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert probe.returncode == 2 and "gc needs the store to itself" in probe.stderr
    store.close()
    other.close()
    assert (
        subprocess.run(
            [sys.executable, "-m", "cli.main", "gc", "--store", str(store.root)],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=60,
        ).returncode
        == 0
    )


def test_writers_and_gc_racing_never_lose_a_rooted_object(store, tmp_path):
    """Many adds of reused (old) content against repeated gc --yes --grace 0: every ref stays intact."""
    src = dataset(tmp_path, payload=os.urandom(50_000))
    add_path(store, src, "demos")
    for p in store.refs_dir.rglob("*"):
        if p.is_file():
            p.unlink()
    for oid in store.iter_object_ids():
        old(store, oid)
    store.close()
    script = (
        "import sys\nfrom pathlib import Path\nfrom artifacts.ingest import add_path\n"
        "from artifacts.store import Store\ns = Store.open(Path(sys.argv[1]))\n"
        "for i in range(6):\n    add_path(s, Path(sys.argv[2]), 'demos', ref=f'r/{sys.argv[3]}-{i}')\n"
    )
    adders = [
        subprocess.Popen(
            [sys.executable, "-c", script, str(store.root), str(src), str(n)],
            cwd=ROOT,
            stderr=subprocess.PIPE,
            text=True,
        )
        for n in range(2)
    ]
    swept = 0
    while any(a.poll() is None for a in adders):
        proc = subprocess.run(
            [sys.executable, "-m", "cli.main", "gc", "--yes", "--grace", "0", "--store", str(store.root)],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert proc.returncode in (0, 2) and "Traceback" not in proc.stderr, proc.stderr
        swept += proc.returncode == 0
    for a in adders:
        assert a.wait() == 0, a.stderr.read()
    assert len(list_refs(store, "r/")) == 12
    report = verify_store(store, full=True)
    assert report.ok, report.problems


# ----------------------------------------------------------------------------- audit log anchoring
def empty_tree(store: Store, tag: str) -> str:
    return store.put_json({"type": "tree", "format": 1, "entries": [], "tag": tag})


def events_store(store: Store, n: int = 4) -> Store:
    for i in range(n):
        append_event(store, "custom", i=i)
    return store


def log_lines(store: Store) -> list[bytes]:
    return store.log_path.read_bytes().splitlines(keepends=True)


def drop_last_line(store: Store) -> None:
    store.log_path.write_bytes(b"".join(log_lines(store)[:-1]))


def edit_last_line(store: Store) -> None:
    lines = log_lines(store)
    lines[-1] = lines[-1].replace(b'"event":"', b'"event":"edited-', 1)
    store.log_path.write_bytes(b"".join(lines))


def delete_log(store: Store) -> None:
    store.log_path.unlink()


def half_write(store: Store) -> None:
    with open(store.log_path, "ab") as f:
        f.write(b'{"seq":4,"event":"cut-')


@pytest.mark.parametrize(
    "damage, pattern",
    [
        (drop_last_line, "tail was cut"),
        (edit_last_line, "edited"),
        (delete_log, "missing"),
        (half_write, "incomplete"),
    ],
)
def test_log_damage_is_seen_blocks_writes_and_repair_seals_it(store, tmp_path, damage, pattern):
    events_store(store)
    set_ref(store, "x", empty_tree(store, "x"))
    assert verify_store(store).ok
    damage(store)
    report = verify_store(store)
    assert not report.ok and any(pattern in p for p in report.problems), report.problems
    with pytest.raises(StoreError, match=r"verify --repair"):
        append_event(store, "after-damage")
    with pytest.raises(StoreError, match=r"verify --repair"):  # a ref move the log cannot record is not made
        set_ref(store, "y", empty_tree(store, "y"))
    assert read_ref(store, "y") is None
    repaired = verify_store(store, repair=True)
    assert repaired.ok and repaired.repaired["event"] == "log-repaired", repaired.problems
    assert any(pattern in p for p in repaired.repaired["problems"])
    assert any("log-repaired" in n for n in repaired.notes)
    set_ref(store, "y", empty_tree(store, "y"))  # writes go on
    after = verify_store(store, full=True)
    assert after.ok and any("sealed" in n for n in after.notes), after.problems
    assert [e["event"] for e in iter_events(store)][-2:] == ["log-repaired", "ref-moved"]


def test_attempt_records_anchor_the_log_even_without_its_head(store):
    events_store(store)
    attempt = {
        "cache_key": "ab" * 32,
        "attempt": 1,
        "step": "train",
        "state": "running",
        "inputs": {},
        "checkpoints": [],
    }
    write_attempt(store, attempt)
    events_store(store, 2)
    [saved] = list_attempts(store)
    assert saved["log_anchor"]["seq"] == 3
    lines = log_lines(store)
    store.log_path.write_bytes(b"".join(lines[:2]))  # cut back before the anchored event…
    head_path(store).unlink()  # …and remove the head as well
    problems = verify_store(store).problems
    assert any("attempt abababababab/0001 (train) was written after log event seq 3" in p for p in problems)
    assert any("log/head is missing" in p for p in problems)
    assert verify_store(store, repair=True).ok
    assert verify_store(store).ok


def test_a_crash_between_the_line_and_the_head_is_not_damage(store):
    events_store(store, 2)
    head_before = head_path(store).read_bytes()
    append_event(store, "custom", i=9)
    head_path(store).write_bytes(head_before)  # as if killed before the head was replaced
    assert verify_store(store).ok
    append_event(store, "custom", i=10)
    assert verify_store(store).ok and json.loads(head_path(store).read_bytes())["seq"] == 3


def test_a_legacy_log_without_head_still_appends(store):
    events_store(store, 2)
    lines = [json.loads(line) for line in log_lines(store)]
    head_path(store).unlink()
    from artifacts.hashing import canonical_json, hash_bytes

    prev, raw = "0" * 64, []  # rewrite as a pre-head (format 1) log
    for e in lines:
        e.pop("log_format")
        e["prev"] = prev
        line = canonical_json(e)
        raw.append(line + b"\n")
        prev = hash_bytes(line)
    store.log_path.write_bytes(b"".join(raw))
    assert verify_store(store).ok
    append_event(store, "custom", i=3)
    assert verify_store(store).ok and head_path(store).exists()


def test_gc_with_a_damaged_log_deletes_nothing(store):
    events_store(store)
    loose = store.put_bytes(b"garbage")
    old(store, loose)
    half_write(store)
    with pytest.raises(StoreError, match="verify --repair"):
        collect_garbage(store, dry_run=False, grace_s=0)
    assert store.has_object(loose)
    verify_store(store, repair=True)
    assert collect_garbage(store, dry_run=False, grace_s=0).removed
    assert [e["event"] for e in iter_events(store)][-2:] == ["gc-started", "gc"]


def test_damaged_lines_do_not_stop_the_log_reader(store):
    events_store(store, 2)
    half_write(store)
    events = list(iter_events(store))
    assert events[-1] == {"seq": None, "event": "damaged-line", "line": 3}


# ----------------------------------------------------------------------------- foreign files under refs/
def test_foreign_and_binary_files_under_refs_are_reported_and_the_rest_listed(store, tmp_path):
    aid, _ = add_path(store, dataset(tmp_path), "demos", ref="demos/good")
    foreign = store.refs_dir / "x"
    (foreign / "meta").mkdir(parents=True)
    (foreign / "meta" / "info.json").write_text('{"codebase_version": "v3.0"}')
    (store.refs_dir / "binary").write_bytes(os.urandom(300) + b"\xff\xfe")
    problems: list[str] = []
    refs = list_refs(store, problems=problems)
    assert refs["demos/good"] == aid and len(problems) == 2
    assert any("ref binary is damaged" in p for p in problems)
    assert any("ref x/meta/info.json is damaged" in p for p in problems)
    with pytest.raises(StoreError, match="ref binary is damaged"):
        read_ref(store, "binary")
    report = verify_store(store)
    assert not report.ok and len(report.problems) == 2
    with pytest.raises(StoreError, match="gc refused"):
        collect_garbage(store, dry_run=False, grace_s=0)
    assert collect_garbage(store, dry_run=True, grace_s=0).kept > 0


# ----------------------------------------------------------------------------- add
def test_add_refuses_a_symlinked_subdirectory_like_a_symlinked_file(store, tmp_path):
    src = dataset(tmp_path)
    elsewhere = dataset(tmp_path, "elsewhere")
    (src / "linked").symlink_to(elsewhere, target_is_directory=True)
    with pytest.raises(StoreError, match=r"linked: a symlink"):
        add_path(store, src, "demos")
    (src / "linked").unlink()
    (src / "file-link").symlink_to(elsewhere / "data.bin")
    with pytest.raises(StoreError, match=r"file-link: only regular files"):
        add_path(store, src, "demos")


def test_a_source_that_shrinks_during_add_is_refused_cleanly(store, tmp_path, monkeypatch):
    big = tmp_path / "big.bin"
    big.write_bytes(os.urandom(40 * 1024 * 1024))  # large enough for the pipelined copy
    import artifacts.store as store_module

    real = store_module.copy_hashing

    def shrink_then_copy(src, fd, size_hint):
        os.truncate(big, 5 * 1024 * 1024)  # another process truncates it mid-add
        return real(src, fd, size_hint)

    monkeypatch.setattr(store_module, "copy_hashing", shrink_then_copy)
    with pytest.raises(StoreError, match="changed size while it was being stored"):
        add_path(store, big, "demos")
    assert list(store.tmp_dir.iterdir()) == []
    assert list(store.iter_object_ids()) == []


def test_a_process_holds_one_writer_lock_per_store(store):
    store.put_bytes(b"a")
    other = Store.open(store.root)
    other.put_bytes(b"b")
    path = str(store.locks_dir / writers.LOCK_NAME)
    assert writers._held[path].users == 2
    store.close()
    other.close()
    assert path not in writers._held


def test_a_closed_handle_collected_later_leaves_another_handles_writer_lock_alone(store):
    """A handle closed, then garbage-collected while another handle of the same store writes: the other's
    lock must stay (it used to be dropped a second time by the first handle's finalizer, letting gc sweep what
    the live writer had named). Kills writers.release 9 (a handle that never wrote drops a count it never
    took) and 11 (a closed handle still believes it holds, so writing again takes no lock)."""
    import gc as python_gc

    closed = Store.open(store.root)  # not the fixture's handle, which pytest keeps alive
    closed.put_bytes(b"a")
    closed.close()
    writer = Store.open(store.root)
    writer.put_bytes(b"b")
    path = str(store.locks_dir / writers.LOCK_NAME)
    del closed
    python_gc.collect()
    assert writers._held[path].users == 1
    never_wrote = Store.open(writer.root)
    never_wrote.close()
    assert writers._held[path].users == 1
    writer.close()
    assert path not in writers._held
    writer.put_bytes(b"c")  # a closed handle may be used again, and holds the lock again
    assert writers._held[path].users == 1
    writer.close()
    assert path not in writers._held


# ----------------------------------------------------------------------------- issue 23, round 6 batch G
def test_put_tree_of_a_path_it_cannot_walk_names_it_in_one_store_error(store, tmp_path):
    """Kills manifests._walk_error 1, 2."""
    from artifacts.manifests import put_tree

    not_a_dir = tmp_path / "plain.txt"
    not_a_dir.write_text("x")
    with pytest.raises(StoreError) as err:
        put_tree(store, not_a_dir, "copy")
    assert str(err.value) == f"cannot read {not_a_dir}: Not a directory"


def test_store_containing_finds_the_store_a_path_lies_in_and_refuse_inside_store_says_so(store, tmp_path):
    """Kills placement._is_store 3-11, store_containing 1-4, refuse_inside_store 1-8."""
    from artifacts.placement import refuse_inside_store, store_containing

    inside = store.root / "refs" / "demos" / "new"
    assert store_containing(inside) == store.root
    assert store_containing(store.root) == store.root
    with pytest.raises(StoreError) as err:
        refuse_inside_store(inside, "--out")
    assert str(err.value) == (
        f"--out {inside} is inside the accrue store at {store.root}; "
        "write it elsewhere (use `accrue add` to bring it into the store)"
    )
    outside = tmp_path / "elsewhere" / "out.rrd"
    assert store_containing(outside) is None
    refuse_inside_store(outside, "--out")  # no store above it: nothing raised


def test_a_directory_with_only_part_of_a_store_layout_is_not_a_store(tmp_path):
    """Kills placement._is_store 1, 2."""
    from artifacts.placement import store_containing

    only_refs = tmp_path / "only-refs"
    (only_refs / "refs").mkdir(parents=True)
    assert store_containing(only_refs / "x") is None
    only_config = tmp_path / "only-config"
    only_config.mkdir()
    (only_config / "config").write_text("{}")
    assert store_containing(only_config / "x") is None
    no_refs = tmp_path / "no-refs"
    (no_refs / "objects").mkdir(parents=True)
    (no_refs / "config").write_text("{}")
    assert store_containing(no_refs / "x") is None


def test_store_containing_looks_past_a_name_too_long_to_stat(store):
    """Kills placement.store_containing 5."""
    from artifacts.placement import refuse_inside_store, store_containing

    too_long = store.root / "refs" / ("n" * 300) / "out"  # stat() of it and of its parent: ENAMETOOLONG
    assert store_containing(too_long) == store.root
    with pytest.raises(StoreError, match="is inside the accrue store"):
        refuse_inside_store(too_long, "--out")


def test_a_directory_remote_refuses_an_object_whose_bytes_do_not_match_its_id(tmp_path):
    """Kills remotes.backends.local_corrupt 1-4."""
    from artifacts.hashing import hash_bytes
    from artifacts.remotes.backends import object_key
    from artifacts.remotes.config import parse_url
    from artifacts.remotes.connect import open_backend

    backend = open_backend(parse_url("origin", str(tmp_path / "nas")))
    backend.probe(create=True)
    oid = hash_bytes(b"what the id promises")
    damaged = tmp_path / "damaged"
    damaged.write_bytes(b"what the disk now holds")
    with pytest.raises(StoreError) as err:
        backend.upload_object(oid, damaged, damaged.stat().st_size)
    assert str(err.value) == (
        f"object {oid[:12]} in this store is corrupt (its bytes no longer match its id); "
        "nothing corrupt is pushed — run `accrue verify --full`"
    )
    assert backend.head(object_key(oid)) is None  # nothing landed under the object's key
