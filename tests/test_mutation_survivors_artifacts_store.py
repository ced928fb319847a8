"""Tests written to kill mutants of artifacts/ that survived round 3 of mutmut's fourth sweep (the
store, its audit log and quarantine; docs/MUTATION.md, "The fourth sweep"). Each docstring names the
mutmut ids it kills. What they pin: the log-repaired event a repair appends (its fields, its bounded
problem list), that a repair which cannot write leaves the log as it was with a one-line reason, the
quarantined event a damaged object leaves behind, and how a checkpoint copy handles a damaged object
or a file still being written, how a message quotes what the user gave, and what a full verify reports,
counts, moves aside and logs (also on a store it cannot write). Everything runs in a temporary directory.

The tests of round 13 (docs/MUTATION.md) were written ahead of the sweep, per function: their docstrings name
the mutants they were written against; the sweep's verdicts, not the docstrings, are the measurement.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import socket
import subprocess
import sys
import warnings
from datetime import datetime
from pathlib import Path

import pytest

import artifacts.store
import artifacts.verify
from artifacts.auditlog import (
    LOG_FORMAT,
    LogCheck,
    LogProblem,
    append_event,
    check_log,
    head_path,
    iter_events,
    repair_log,
)
from artifacts.errors import QUOTE_LIMIT, StoreError, quote
from artifacts.hashing import hash_bytes
from artifacts.ingest import add_path
from artifacts.manifests import content_objects, read_artifact, verify_artifact
from artifacts.records import write_attempt
from artifacts.store import Store
from artifacts.verify import verify_store
from artifacts.writers import _holder_pid, _lock_path, exclusive


@pytest.fixture
def store(tmp_path: Path) -> Store:
    s, _ = Store.init(tmp_path / "store")
    yield s
    s.close()


# ----------------------------------------------------------------------------- auditlog.repair_log
def test_a_repair_seals_with_a_full_log_repaired_event_and_bounds_its_problem_list(store):
    """auditlog.repair_log 33, 34 (ts), 39, 40 (pid), 41, 42 (host), 57, 58 (log_format), 45, 46 (at
    most 50 problems, each cut to 300 characters)."""
    append_event(store, "custom", note="before")
    problems = [LogProblem(f"problem {i:02d} " + "x" * 400) for i in range(60)]
    record = repair_log(store, LogCheck(events=1, problems=problems))
    assert record["event"] == "log-repaired"
    assert datetime.fromisoformat(record["ts"]).tzinfo is not None
    assert (record["pid"], record["host"], record["log_format"]) == (os.getpid(), socket.gethostname(), LOG_FORMAT)
    assert record["problems"] == [p.text[:300] for p in problems[:50]]
    assert len(record["problems"][0]) == 300
    assert list(iter_events(store))[-1] == record
    assert check_log(store).problems == []


@pytest.fixture
def full_disk(store, monkeypatch):
    """Writes to the audit log stop halfway (a full disk: a short write), as long as `on` is set."""
    real_write = os.write
    state = {"on": False}

    def write(fd, data):
        if state["on"] and os.path.realpath(f"/proc/self/fd/{fd}") == os.path.realpath(store.log_path):
            return real_write(fd, data[: len(data) // 2])
        return real_write(fd, data)

    monkeypatch.setattr(os, "write", write)
    return state


@pytest.mark.parametrize("cut_off", [False, True], ids=["seal-line", "completing-newline"])
def test_a_repair_that_cannot_write_leaves_the_log_as_it_was_and_says_why(store, full_disk, cut_off):
    """auditlog.repair_log 65 (the seal line), 15 (the newline that completes a cut-off line): a failed
    write is taken back to the log's old size; 83, 84: the one-line reason names the log and the
    error."""
    append_event(store, "custom", note="before")
    if cut_off:
        with open(store.log_path, "ab") as f:
            f.write(b'{"seq": 1, "half a li')
    else:
        head_path(store).unlink()  # a problem to seal, with a log that ends with a whole line
    check = check_log(store)
    assert check.problems
    before = store.log_path.read_bytes()
    full_disk["on"] = True
    with pytest.raises(StoreError) as exc:
        repair_log(store, check)
    full_disk["on"] = False
    assert str(exc.value) == f"cannot repair the audit log: {store.log_path}: No space left on device (short write)"
    assert store.log_path.read_bytes() == before


# ----------------------------------------------------------------------------- manifests._quarantine
def test_a_damaged_object_moved_aside_leaves_a_quarantined_event_naming_it(store, tmp_path):
    """manifests._quarantine 3–5, 8–13: the audit log says what was moved aside and why."""
    src = tmp_path / "demos"
    src.mkdir()
    (src / "a.bin").write_bytes(b"x" * 100)
    aid, _ = add_path(store, src, "demos")
    [(oid, _, _)] = content_objects(store, read_artifact(store, aid))
    path = store.object_path(oid)
    _overwrite(path, b"y" * 100)
    with pytest.raises(StoreError, match="is corrupt"):
        verify_artifact(store, aid, quarantine=True)
    event = list(iter_events(store))[-1]
    assert {k: event.get(k) for k in ("event", "object", "reason")} == {
        "event": "quarantined",
        "object": oid,
        "reason": "hash mismatch found on use",
    }


# ----------------------------------------------------------------------------- store.copy_in_checked
def test_a_checkpoint_copied_over_a_damaged_object_replaces_it_and_keeps_the_damaged_one(store, tmp_path):
    """Store.copy_in_checked 6: the damaged object with the file's id is quarantined, then the file is
    stored whole under that id."""
    ckpt = tmp_path / "model.pt"
    ckpt.write_bytes(b"weights" * 100)
    oid = hash_bytes(ckpt.read_bytes())
    store.object_path(oid).parent.mkdir(parents=True, exist_ok=True)
    store.object_path(oid).write_bytes(b"cut short")  # a damaged copy of the same object
    assert store.copy_in_checked(ckpt) == (oid, 700)
    assert store.read_bytes(oid) == ckpt.read_bytes()
    assert [p.read_bytes() for p in store.quarantine_dir.iterdir()] == [b"cut short"]


def test_a_checkpoint_that_changes_while_it_is_copied_is_refused_by_name(store, tmp_path, monkeypatch):
    """Store.copy_in_checked 10: the exact one-line refusal naming the file."""
    ckpt = tmp_path / "model.pt"
    ckpt.write_bytes(b"weights" * 100)
    real_hash_file = artifacts.store.hash_file

    def hash_then_the_trainer_writes_more(path):
        out = real_hash_file(path)
        with open(path, "ab") as f:
            f.write(b"more")
        return out

    monkeypatch.setattr(artifacts.store, "hash_file", hash_then_the_trainer_writes_more)
    with pytest.raises(StoreError) as exc:
        store.copy_in_checked(ckpt)
    assert str(exc.value) == f"{ckpt}: file changed while it was being stored"


# ----------------------------------------------------------------------------- writers._holder_pid
HOLD = """
import fcntl, os, sys
fd = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT, 0o644)
fcntl.lockf(fd, fcntl.LOCK_EX if sys.argv[2] == "gc" else fcntl.LOCK_SH)
print("held", flush=True)
sys.stdin.read()
"""


@pytest.fixture
def other_process(store):
    """Start another process holding the store's writer lock as a writer (shared) or as gc (exclusive)."""
    started: list[subprocess.Popen] = []

    def hold(role: str) -> int:
        proc = subprocess.Popen(
            [sys.executable, "-c", HOLD, _lock_path(store), role], stdin=subprocess.PIPE, stdout=subprocess.PIPE
        )
        started.append(proc)
        assert proc.stdout.readline() == b"held\n"
        return proc.pid

    yield hold
    for proc in started:
        proc.stdin.close()
        proc.wait(timeout=10)


def test_gc_names_the_pid_of_the_writer_that_keeps_it_waiting(store, other_process):
    """writers._holder_pid 3–7, 9–15, 24, 25, 31, 33 (the lock query built or read wrongly: no pid, or
    a traceback): the message names the writer's pid and says it is a writer, not a gc."""
    pid = other_process("writer")
    with pytest.raises(StoreError) as exc:
        with exclusive(store, wait_s=0):
            pass
    assert str(exc.value) == (
        f"gc needs the store to itself, but an accrue process (pid {pid}) is using it; "
        "run gc when it finishes, or pass --wait SECONDS"
    )


def test_gc_names_the_pid_of_another_gc(store, other_process):
    """writers._holder_pid 3–7, 9–15, 24, 25, 31, 33: an exclusive holder is named as a gc, with its pid."""
    pid = other_process("gc")
    with pytest.raises(StoreError) as exc:
        with exclusive(store, wait_s=0):
            pass
    assert str(exc.value) == (
        f"the store (gc) is locked by another accrue process (pid {pid}); try again when it finishes"
    )


def test_a_lock_with_no_other_holder_or_that_cannot_be_queried_names_no_gc(store, monkeypatch):
    """writers._holder_pid 34 (the holder left before the query: no pid, not a gc), 32 (the query
    fails, e.g. a filesystem without F_GETLK: the same)."""
    fd = os.open(_lock_path(store), os.O_RDWR | os.O_CREAT, 0o644)
    try:
        assert _holder_pid(fd) == (None, False)

        def no_getlk(*_args):
            raise OSError(22, "Invalid argument")

        monkeypatch.setattr("artifacts.writers.fcntl.fcntl", no_getlk)
        assert _holder_pid(fd) == (None, False)
    finally:
        os.close(fd)


# ----------------------------------------------------------------------------- errors.quote
def test_a_value_quoted_in_a_message_is_its_repr_bounded_in_depth_items_and_length():
    """errors.quote 8 (the value's repr), 4 (three levels of nesting), 6 (eight items), 9–11 (a repr of
    exactly QUOTE_LIMIT characters is kept whole, a longer one cut), 13–15 (cut to QUOTE_LIMIT − 1
    characters and one '…')."""
    assert quote("workflow/a") == "'workflow/a'"
    assert quote([[[["deep"]]]]) == "[[[[...]]]]"
    assert quote({"a": {"b": {"c": {"d": 1}}}}) == "{'a': {'b': {'c': {...}}}}"
    assert quote(list(range(9))) == "[0, 1, 2, 3, 4, 5, 6, 7, ...]"
    exact = "x" * (QUOTE_LIMIT - 2)
    assert quote(exact) == repr(exact) and len(repr(exact)) == QUOTE_LIMIT
    long = ["y" * 100] * 3
    assert quote(long) == repr(long)[: QUOTE_LIMIT - 1] + "…"


# ----------------------------------------------------------------------------- lineage (round 6, batch C)
def _artifact(store: Store, tmp_path: Path, name: str, kind: str, **kw) -> str:
    from artifacts.manifests import publish_artifact

    src = tmp_path / name
    src.write_bytes(name.encode())
    return publish_artifact(store, src, kind, producer={"step": name}, **kw)


def test_a_seed_nested_in_a_config_is_named_by_its_dotted_path():
    """lineage.seed_like 13 (a nested dict not walked), 14 (its prefix None), 15 (the prefix walked
    as the config), 16 (no prefix), 18 (a wrong separator)."""
    from artifacts.lineage import seed_like

    config = {"seed": 1, "env": {"seed": 3, "name": "cart"}, "opt": {"inner": {"Seed_b": 5}}, "lr": 0.1}
    assert seed_like(config) == {"seed": 1, "env.seed": 3, "opt.inner.Seed_b": 5}


def test_lineage_gives_a_node_met_twice_once_in_full_then_as_a_repeat(store, tmp_path):
    """lineage.lineage 2 (the nodes already given forgotten on the way down: the shared demos in full
    twice), 11–14 (the repeat's keys); its seeds come through seed_like's dotted names."""
    from artifacts.lineage import lineage

    demos = _artifact(store, tmp_path, "demos.bin", "demos")
    left = _artifact(store, tmp_path, "left.bin", "handoff", inputs={"demos": demos})
    right = _artifact(store, tmp_path, "right.bin", "handoff", inputs={"demos": demos})
    top = _artifact(store, tmp_path, "top.bin", "handoff", inputs={"a": left, "b": right}, config={"env": {"seed": 7}})
    node = lineage(store, top)
    assert node["seeds"] == {"env.seed": 7}
    assert node["inputs"]["a"]["id"] == left and node["inputs"]["b"]["id"] == right
    first = node["inputs"]["a"]["inputs"]["demos"]
    assert first["id"] == demos and first["kind"] == "demos" and first["inputs"] == {}
    assert node["inputs"]["b"]["inputs"]["demos"] == {"id": demos, "repeat": True}


# ----------------------------------------------------------------------------- refs.delete_ref
def _two_refs(store: Store, tmp_path: Path, *names: str) -> str:
    from artifacts.refs import set_ref

    oid = _artifact(store, tmp_path, "thing.bin", "demos")
    for name in names:
        set_ref(store, name, oid)
    return oid


def test_deleting_a_ref_returns_its_id_and_logs_a_ref_deleted_event(store, tmp_path):
    """refs.delete_ref 1 (not logged by default), 19, 27, 31, 32 (a traceback), 28, 29, 30, 33–36 (the
    event's name and fields), 25 (a top-level ref: nothing returned, nothing logged)."""
    from artifacts.refs import delete_ref, read_ref

    oid = _two_refs(store, tmp_path, "x")
    assert delete_ref(store, "x") == oid
    assert read_ref(store, "x") is None
    event = list(iter_events(store))[-1]
    assert {k: event.get(k) for k in ("event", "ref", "old")} == {"event": "ref-deleted", "ref": "x", "old": oid}
    assert delete_ref(store, "x") is None
    assert list(iter_events(store))[-1] == event


def test_deleting_a_nested_ref_drops_only_the_directories_it_leaves_empty(store, tmp_path):
    """refs.delete_ref 26 (a directory still holding a sibling ref: nothing returned, nothing logged),
    24 (the emptied directory kept, so a ref of its name then conflicts)."""
    from artifacts.refs import delete_ref, list_refs, set_ref

    oid = _two_refs(store, tmp_path, "team/a", "team/b")
    assert delete_ref(store, "team/a") == oid
    assert list(iter_events(store))[-1]["ref"] == "team/a"
    assert {n for n in list_refs(store) if n.startswith("team")} == {"team/b"}
    assert delete_ref(store, "team/b") == oid
    assert list(iter_events(store))[-1]["ref"] == "team/b"
    assert not (store.refs_dir / "team").exists()
    set_ref(store, "team", oid)  # the name is free again
    assert list_refs(store)["team"] == oid


def test_a_ref_that_cannot_be_removed_is_a_one_line_error_and_stays(store, tmp_path, monkeypatch):
    """refs.delete_ref 20, 22, 23 (a traceback), 21 (the message's 'cannot remove ref NAME')."""
    import errno

    from artifacts.errors import path_text
    from artifacts.refs import delete_ref, read_ref

    oid = _two_refs(store, tmp_path, "team/a")
    target = store.refs_dir / "team" / "a"
    real_unlink = Path.unlink

    def unlink(self, *args, **kwargs):
        if self == target:
            raise OSError(errno.EROFS, "Read-only file system", str(self))
        return real_unlink(self, *args, **kwargs)

    monkeypatch.setattr(Path, "unlink", unlink)
    before = list(iter_events(store))
    with pytest.raises(StoreError) as exc:
        delete_ref(store, "team/a")
    assert str(exc.value) == f"cannot remove ref team/a: {path_text(str(target))}: Read-only file system"
    assert read_ref(store, "team/a") == oid
    assert list(iter_events(store)) == before


def test_a_ref_is_deleted_under_the_refs_lock(store, tmp_path, monkeypatch):
    """refs.delete_ref 8, 11, 12 (another lock file: a ref move by another process could interleave)."""
    import artifacts.refs
    from artifacts.locks import store_lock, try_lock

    oid = _two_refs(store, tmp_path, "team/a")
    real_read_ref = artifacts.refs.read_ref
    held: list[bool] = []

    def read_ref_while_checking_the_lock(s, name):
        try:
            try_lock(store_lock(s.locks_dir, "refs"), "refs", timeout=0).release()
            held.append(False)
        except StoreError:
            held.append(True)
        return real_read_ref(s, name)

    monkeypatch.setattr(artifacts.refs, "read_ref", read_ref_while_checking_the_lock)
    assert artifacts.refs.delete_ref(store, "team/a") == oid
    assert held == [True]


# ----------------------------------------------------------------------------- remotes.status.ref_status
def test_status_says_a_ref_deleted_on_the_remote_since_the_last_push_is_gone_there(tmp_path):
    """remotes.status.ref_status 52, 54, 55 (gone-there), 76 (the row's local id)."""
    from artifacts.refs import set_ref
    from artifacts.remotes.config import add_remote
    from artifacts.remotes.pull import fetch
    from artifacts.remotes.push import push
    from artifacts.remotes.status import RefStatus, ref_status
    from artifacts.remotes.unshare import delete_remote_refs

    url = str(tmp_path / "nas")
    (tmp_path / "nas").mkdir()
    a, _ = Store.init(tmp_path / "a")
    b, _ = Store.init(tmp_path / "b")
    try:
        oid = _artifact(a, tmp_path, "thing.bin", "demos")
        set_ref(a, "team/gone", oid)
        set_ref(a, "team/kept", oid)
        add_remote(a, "nas", url)
        push(a, "nas")
        add_remote(b, "nas", url)
        fetch(b, "nas")
        assert delete_remote_refs(b, "nas", ["team/gone"]).deleted == {"team/gone": oid}
        rows = {r.ref: r for r in ref_status(a, "nas") if r.ref.startswith("team/")}
        assert rows == {
            "team/gone": RefStatus("team/gone", oid, None, "gone-there"),
            "team/kept": RefStatus("team/kept", oid, oid, "up-to-date"),
        }
    finally:
        a.close()
        b.close()


# ----------------------------------------------------------------------------- verify._rehash
# The mutant ids below are those of _rehash at ae7ad85; 6118c4f's two FileNotFoundError branches renumbered
# them (the equivalent `writable = None`, 21 here, is 23 since: benchmarks/results/mutation/triage/round8-batch-U.tsv).
def _loose(store: Store, *blobs: bytes) -> list[str]:
    """Store each blob as a loose object; their ids in the order a full verify walks them."""
    return sorted(store.put_bytes(b) for b in blobs)


def _overwrite(path: Path, data: bytes) -> None:
    """Put other bytes in a read-only file of the store (an object, a record, the config)."""
    os.chmod(path, 0o644)
    path.write_bytes(data)


def _damage(store: Store, oid: str) -> None:
    _overwrite(store.object_path(oid), b"not what was stored")


def test_a_full_verify_names_an_unreadable_object_then_hashes_the_rest(store):
    """verify._rehash 7, 8, 9 (the unreadable object's line), 10 (the objects after it are still
    hashed), 14, 15 (bytes_hashed sums every object's size)."""
    ids = _loose(store, b"a" * 10, b"b" * 200, b"c" * 3000)
    unreadable = "0" * 64  # walked first; a directory where its file should be
    assert ids[0] > unreadable
    store.object_path(unreadable).mkdir(parents=True)
    seen: list[int] = []
    report = verify_store(store, full=True, progress=seen.append)
    assert report.problems == [
        f"object {unreadable[:12]} cannot be read: {store.object_path(unreadable)}: Is a directory"
    ]
    assert (report.objects_checked, report.bytes_hashed) == (3, 3210)
    assert sorted(seen) == [10, 200, 3000] and report.quarantined == [] and report.notes == []


def test_a_full_verify_quarantines_every_corrupt_object_and_logs_each(store):
    """verify._rehash 26, 27 (the 'moved to' line), 43 (the objects after a quarantined one are still
    checked), 30, 31, 32, 35, 36, 37, 38, 39, 40 (the quarantined event: its name, object and reason)."""
    first, second, good = _loose(store, b"one" * 50, b"two" * 50, b"three" * 50)
    _damage(store, first)
    _damage(store, second)
    report = verify_store(store, full=True)
    assert report.quarantined == [first, second]
    moved = {p.name.split(".")[0]: p.name for p in store.quarantine_dir.iterdir()}
    assert report.problems == [
        f"object {first[:12]} is corrupt: moved to quarantine/{moved[first]}",
        f"object {second[:12]} is corrupt: moved to quarantine/{moved[second]}",
    ]
    assert not store.has_object(first) and not store.has_object(second) and store.has_object(good)
    events = [{k: e.get(k) for k in ("event", "object", "reason")} for e in iter_events(store)]
    assert events == [
        {"event": "quarantined", "object": first, "reason": "hash mismatch"},
        {"event": "quarantined", "object": second, "reason": "hash mismatch"},
    ]
    assert report.notes == [] and report.objects_checked == 3


def test_a_quarantine_the_log_cannot_record_is_still_done_and_noted(store, full_disk):
    """verify._rehash 41, 42: the object is moved aside; a note says its event was not logged, and why."""
    [oid] = _loose(store, b"payload" * 30)
    _damage(store, oid)
    full_disk["on"] = True
    report = verify_store(store, full=True)
    full_disk["on"] = False
    assert report.quarantined == [oid] and not store.has_object(oid)
    assert report.notes == [
        f"quarantine of {oid[:12]} not logged: cannot write the audit log: "
        f"{store.log_path}: No space left on device (short write)"
    ]
    assert list(iter_events(store)) == []


def test_on_a_store_it_cannot_write_a_full_verify_says_so_once_and_reports_the_corrupt(store, monkeypatch):
    """verify._rehash 22 (one note, one attempt to move), 23, 24 (the note names the error), 44, 45
    (each corrupt object's line)."""
    first, second = _loose(store, b"left" * 40, b"right" * 40)
    _damage(store, first)
    _damage(store, second)
    real_rename = os.rename
    tries: list[str] = []

    def rename(src, dst, *a, **kw):
        if Path(src).parent.parent == store.objects_dir:
            tries.append(Path(src).name)
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(src))
        return real_rename(src, dst, *a, **kw)

    monkeypatch.setattr(os, "rename", rename)
    report = verify_store(store, full=True)
    assert report.notes == [
        f"the store cannot be written ({store.object_path(first)}: Read-only file system): "
        "corrupt objects are reported, not quarantined"
    ]
    assert report.problems == [
        f"object {first[:12]} is corrupt (its bytes no longer match its id)",
        f"object {second[:12]} is corrupt (its bytes no longer match its id)",
    ]
    assert tries == [first[2:]] and report.quarantined == []
    assert store.has_object(first) and store.has_object(second) and list(iter_events(store)) == []


def test_an_object_removed_while_a_full_verify_runs_is_no_problem_and_stops_no_quarantine(store, monkeypatch):
    """A gc beside `accrue verify --full` removes objects it has listed: one gone before it is hashed and one
    gone before its quarantine are skipped, not reported as unreadable, and do not turn quarantining off
    for the corrupt objects after them (it used to note "the store cannot be written (… No such file …)")."""
    gone_first, corrupt_then_gone, corrupt = _loose(store, b"one", b"two", b"three")  # in the order walked
    for oid in (corrupt_then_gone, corrupt):
        _damage(store, oid)
    real_hash_file = artifacts.verify.hash_file
    real_quarantine = Store.quarantine

    def hash_file(path):
        if path == store.object_path(gone_first):
            path.unlink()
        return real_hash_file(path)

    def quarantine(self, oid):
        if oid == corrupt_then_gone:
            self.object_path(oid).unlink()
        return real_quarantine(self, oid)

    monkeypatch.setattr(artifacts.verify, "hash_file", hash_file)
    monkeypatch.setattr(Store, "quarantine", quarantine)
    report = verify_store(store, full=True)
    assert report.quarantined == [corrupt] and report.notes == []
    (moved,) = store.quarantine_dir.iterdir()
    assert report.problems == [f"object {corrupt[:12]} is corrupt: moved to quarantine/{moved.name}"]
    assert report.objects_checked == 2


# ----------------------------------------------------------------------------- verify.verify_store
def _missing_log_problem(store: Store) -> str:
    return f"the audit log {store.log_path} is missing or empty, but the store has refs and records: it was deleted"


def _attempt(key: str, number: int, state: str, pid: int) -> dict:
    return {"cache_key": key, "attempt": number, "step": "train", "state": state, "pid": pid, "inputs": {}}


def test_verify_says_a_store_with_refs_but_no_attempts_lost_its_audit_log(store, tmp_path):
    """verify.verify_store 34, 35 (refs alone are history), 39, 40 (a ref file in a folder under refs/),
    44, 47 (check_log is told of that history)."""
    _two_refs(store, tmp_path, "team/demos")
    store.log_path.unlink()
    head_path(store).unlink()
    report = verify_store(store)
    assert report.problems == [_missing_log_problem(store)]
    assert report.log_events == 0 and report.notes == []


def test_verify_says_a_store_with_attempt_records_but_no_refs_lost_its_audit_log(store):
    """verify.verify_store 35, 36 (attempt records alone are history): a record written before any event
    has no anchor, so only the missing log is reported."""
    write_attempt(store, _attempt("ab" * 32, 1, "committed", 4242))
    assert not store.log_path.exists() and not any(store.refs_dir.rglob("*"))
    assert verify_store(store).problems == [_missing_log_problem(store)]


def test_verify_notes_each_running_attempt_with_its_key_number_step_and_pid(store):
    """verify.verify_store 71, 72, 73 (only the running attempt is noted), 74, 77 (its 12-character key),
    82, 83, 84 (the pid it is marked running by)."""
    append_event(store, "custom", note="before")
    write_attempt(store, _attempt("ab" * 32, 1, "committed", 1111))
    write_attempt(store, _attempt("ab" * 32, 2, "running", 2222))
    report = verify_store(store)
    assert report.problems == []
    assert report.notes == ["attempt abababababab/0002 (train) is marked running by pid 2222"]


def test_a_record_whose_log_anchor_has_no_hash_anchors_nothing_and_repair_still_runs(store):
    """A found bug (round 9): two records anchored at the same seq, one with a null hash, made `verify
    --repair` a TypeError (sorting (0, None) against (0, "zz")). An anchor without a hash holds the log
    to nothing, like one without a seq; the other is sealed as before."""
    from artifacts.records import attempt_path

    append_event(store, "custom", note="before")
    for number, digest in ((1, None), (2, "zz")):
        write_attempt(store, _attempt("ab" * 32, number, "failed", 1111))
        path = attempt_path(store, "ab" * 32, number)
        record = json.loads(path.read_bytes())
        path.write_text(json.dumps({**record, "log_anchor": {"seq": 0, "hash": digest}}))
    damaged = (
        "attempt abababababab/0002 (train) was written after log event seq 0, but the log holds a different "
        "line there: it was cut or rewritten"
    )
    assert verify_store(store).problems == [damaged]
    repaired = verify_store(store, repair=True)
    assert repaired.problems == []
    assert verify_store(store).problems == []


def test_the_gc_roots_are_refs_committed_records_and_what_unfinished_attempts_still_need(store, tmp_path):
    """reachability.roots 13 (12 characters of the key), 33, 34 (a committed attempt without a record is no
    root: its checkpoints were for a run that finished), 35 (an unfinished attempt's checkpoints replace the
    roots before them instead of joining them)."""
    from artifacts.reachability import roots

    oid = _two_refs(store, tmp_path, "team/demos")
    key, ids = "ab" * 32, [hash_bytes(bytes([n])) for n in range(5)]
    write_attempt(store, _attempt(key, 1, "committed", 1) | {"record_id": ids[0]})
    write_attempt(store, _attempt(key, 2, "committed", 2) | {"checkpoints": [{"id": ids[1]}]})
    write_attempt(store, _attempt(key, 3, "running", 3) | {"checkpoints": [{"id": ids[2]}], "inputs": {"d": ids[3]}})
    assert sorted(roots(store)) == sorted(
        [
            (oid, "ref team/demos"),
            (ids[0], "attempt abababababab/0001 (train)"),
            (ids[2], "attempt abababababab/0003 (train) checkpoint"),
            (ids[3], "attempt abababababab/0003 (train) input d"),
        ]
    )


def test_an_unfinished_attempt_recorded_without_inputs_still_roots_its_checkpoints(store, tmp_path):
    """reachability.roots 52, 54 (no default for a record without "inputs": gc and verify crash with an
    AttributeError). The runner always writes inputs, but a record is a file a person can edit: one that
    lacks them names no input, and its checkpoints stay roots."""
    from artifacts.reachability import roots

    key, ckpt = "cd" * 32, hash_bytes(b"checkpoint")
    record = _attempt(key, 1, "running", 1) | {"checkpoints": [{"id": ckpt}]}
    del record["inputs"]
    write_attempt(store, record)
    assert roots(store) == [(ckpt, "attempt cdcdcdcdcdcd/0001 (train) checkpoint")]
    missing = f"missing object {ckpt[:12]} (named by attempt cdcdcdcdcdcd/0001 (train) checkpoint)"
    assert missing in verify_store(store).problems


def test_the_store_lists_only_objects_under_two_character_fan_directories(store):
    """store.Store.iter_object_ids 4 (a two-character file, or a folder of another length, taken for a fan:
    a NotADirectoryError, or an id made of a stray folder's name), 8 (the first stray entry, e.g. a Finder
    `.DS_Store` that sorts before every fan, ends the listing: verify --full and gc would see no objects)."""
    ids = sorted(store.put_bytes(bytes([n]) * 10) for n in range(3))
    (store.objects_dir / ".DS_Store").write_bytes(b"finder")
    (store.objects_dir / "zz").write_bytes(b"a file with a fan's name")
    stray = store.objects_dir / "abc"  # three characters: no fan, though its name + a file's make 64 hex digits
    stray.mkdir()
    (stray / ("d" * 61)).write_bytes(b"x")
    assert list(store.iter_object_ids()) == ids


def test_a_store_whose_objects_folder_is_gone_lists_no_objects(store):
    """store.Store.iter_object_ids 2 (listing a missing objects/ folder: FileNotFoundError)."""
    store.put_bytes(b"one")
    shutil.rmtree(store.objects_dir)
    assert list(store.iter_object_ids()) == []


# ----------------------------------------------------------------------------- atomic: new directories (round 11)
def test_a_new_directory_is_synced_into_its_parent_and_an_old_one_is_not_synced_again(tmp_path, monkeypatch):
    """make_dirs_durable: each directory it makes is synced into its parent, top first; one that exists is
    left alone. Without this a crash after an object or ref was written into a new directory can lose the
    directory's name, and the object or ref with it."""
    import artifacts.atomic as atomic

    synced: list[Path] = []
    monkeypatch.setattr(atomic, "fsync_dir", synced.append)
    atomic.make_dirs_durable(tmp_path / "refs" / "team" / "x")
    assert synced == [tmp_path, tmp_path / "refs", tmp_path / "refs" / "team"]
    assert (tmp_path / "refs" / "team" / "x").is_dir()
    atomic.make_dirs_durable(tmp_path / "refs" / "team" / "x")
    atomic.make_dirs_durable(tmp_path / "refs" / "team" / "y")
    assert synced[3:] == [tmp_path / "refs" / "team"]


def test_an_object_in_a_new_fan_out_directory_and_a_ref_in_a_new_folder_reach_disk_with_their_names(
    tmp_path, monkeypatch
):
    """The store's own writes (link_into_place for objects, write_replace for refs) sync the directory above
    any fan-out directory or ref folder they make, as a pull does."""
    import artifacts.atomic as atomic
    from artifacts.refs import set_ref

    store, _ = Store.init(tmp_path / "store")
    synced: list[Path] = []
    monkeypatch.setattr(atomic, "fsync_dir", synced.append)
    oid = store.put_bytes(b"an object")
    assert synced[:2] == [store.objects_dir, store.objects_dir / oid[:2]]
    synced.clear()
    set_ref(store, "team/deep/handoff", oid, log=False)
    refs = store.root / "refs"
    assert synced[:2] == [refs, refs / "team"] and synced[-1] == refs / "team" / "deep"
    store.close()


# ----------------------------------------------------------------------------- manifests.materialize (round 12)
def _damaged_file_artifact(store: Store, tmp_path: Path) -> tuple[str, str]:
    """A file artifact whose object now holds other bytes of the same size (only a re-hash sees it)."""
    src = tmp_path / "policy.bin"
    src.write_bytes(b"x" * 100)
    aid, _ = add_path(store, src, "demos")
    oid = read_artifact(store, aid)["content"]
    _overwrite(store.object_path(oid), b"y" * 100)
    return aid, oid


def test_a_file_artifact_is_rehashed_when_used_and_left_in_place_unless_asked_to_quarantine(store, tmp_path):
    """manifests.materialize 1 (quarantine off by default), 14 (a file artifact is re-hashed, not only
    sized)."""
    from artifacts.manifests import materialize

    aid, oid = _damaged_file_artifact(store, tmp_path)
    with pytest.raises(StoreError, match=f"object {oid[:12]} .* is corrupt"):
        materialize(store, aid, tmp_path / "view")
    assert store.object_path(oid).exists()  # not moved aside: the caller did not ask
    assert not store.quarantine_dir.exists() or not any(store.quarantine_dir.iterdir())


def test_a_damaged_file_artifact_materialized_with_quarantine_is_moved_aside(store, tmp_path):
    """manifests.materialize 15, 19: quarantine=True reaches the check of a file artifact."""
    from artifacts.manifests import materialize

    aid, oid = _damaged_file_artifact(store, tmp_path)
    with pytest.raises(StoreError, match="is corrupt"):
        materialize(store, aid, tmp_path / "view", quarantine=True)
    assert not store.object_path(oid).exists()
    assert [p.name.split(".")[0] for p in store.quarantine_dir.iterdir()] == [oid]


def test_a_directory_artifact_is_copied_with_its_nested_folders_and_never_into_an_existing_folder(store, tmp_path):
    """manifests.materialize 37, 39, 41 (a file two folders deep, whose upper folder holds no file, gets
    both folders), 29 (a folder already there is refused, so no stale file is mixed into the view), 53 (line
    buffering asked of a binary file, which Python refuses with a RuntimeWarning on every file);
    _make_read_only 14, 19 (files r--r--r--, folders r-xr-xr-x)."""
    from artifacts.manifests import materialize

    src = tmp_path / "demos"
    (src / "episodes" / "0001").mkdir(parents=True)
    (src / "episodes" / "0001" / "frames.bin").write_bytes(b"f" * 64)
    aid, _ = add_path(store, src, "demos")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        view = materialize(store, aid, tmp_path / "view")
    assert (view / "episodes" / "0001" / "frames.bin").read_bytes() == b"f" * 64
    modes = {str(p.relative_to(view)): p.stat().st_mode & 0o777 for p in [view, *view.rglob("*")]}
    assert modes == {".": 0o555, "episodes": 0o555, "episodes/0001": 0o555, "episodes/0001/frames.bin": 0o444}
    stale = tmp_path / "stale"
    stale.mkdir()
    with pytest.raises(FileExistsError):
        materialize(store, aid, stale)
    assert list(stale.iterdir()) == []


def _two_file_demos(store: Store, tmp_path: Path) -> tuple[str, dict[str, str]]:
    """A directory artifact of a.bin and b.bin; returns its id and each file's object id."""
    src = tmp_path / "two"
    src.mkdir()
    (src / "a.bin").write_bytes(b"a" * 50)
    (src / "b.bin").write_bytes(b"b" * 50)
    aid, _ = add_path(store, src, "demos")
    return aid, {rel: oid for oid, _, rel in content_objects(store, read_artifact(store, aid))}


def test_a_missing_object_of_a_directory_artifact_is_named_in_one_line(store, tmp_path):
    """manifests.materialize 54, 55, 56: the artifact's and the object's 12-digit ids, and the file."""
    from artifacts.manifests import materialize

    aid, oids = _two_file_demos(store, tmp_path)
    os.unlink(store.object_path(oids["b.bin"]))
    with pytest.raises(StoreError) as exc:
        materialize(store, aid, tmp_path / "view")
    assert str(exc.value) == f"artifact {aid[:12]}: object {oids['b.bin'][:12]} (b.bin) is missing"


def test_a_same_size_damaged_object_stops_the_copy_is_moved_aside_and_leaves_plain_files(store, tmp_path):
    """manifests.materialize 75 (a hash mismatch alone is corruption), 78–81 (quarantine=True moves
    that object aside), 82–84 (the line names it), 63, 66 (files copied before it are rw-r--r--, never
    executable)."""
    from artifacts.manifests import materialize

    aid, oids = _two_file_demos(store, tmp_path)
    damaged = store.object_path(oids["b.bin"])
    _overwrite(damaged, b"x" * 50)
    old_umask = os.umask(0o022)
    try:
        with pytest.raises(StoreError) as exc:
            materialize(store, aid, tmp_path / "view", quarantine=True)
    finally:
        os.umask(old_umask)
    assert str(exc.value) == f"artifact {aid[:12]}: object {oids['b.bin'][:12]} (b.bin) is corrupt"
    assert not damaged.exists()
    assert [p.name.split(".")[0] for p in store.quarantine_dir.iterdir()] == [oids["b.bin"]]
    assert (tmp_path / "view" / "a.bin").stat().st_mode & 0o777 == 0o644


def test_a_file_artifact_names_its_file_when_its_object_is_missing(store, tmp_path):
    """manifests.content_objects 10, 12, 14, 15: a file artifact's one object is known by the file's name."""
    aid, oid = _damaged_file_artifact(store, tmp_path)
    os.unlink(store.object_path(oid))
    assert content_objects(store, read_artifact(store, aid)) == [(oid, 100, "policy.bin")]
    with pytest.raises(StoreError) as exc:
        verify_artifact(store, aid)
    assert str(exc.value) == f"artifact {aid[:12]}: object {oid[:12]} (policy.bin) is missing"


def test_an_object_of_another_type_is_refused_as_an_artifact_or_a_tree_in_one_exact_line(store, tmp_path):
    """manifests.read_artifact, read_tree, check_kind: the lines name the object's 12-digit id and what it is,
    or the kinds a name should look like (ids in the triage files of round 12)."""
    from artifacts.manifests import check_kind, read_tree

    aid, oids = _two_file_demos(store, tmp_path)
    tree = read_artifact(store, aid)["content"]
    untyped = store.put_json({"entries": []})
    with pytest.raises(StoreError) as exc:
        read_artifact(store, tree)
    assert str(exc.value) == f"{tree[:12]} is a tree object, not an artifact"
    with pytest.raises(StoreError) as exc:
        read_artifact(store, untyped)
    assert str(exc.value) == f"{untyped[:12]} is a raw object, not an artifact"
    with pytest.raises(StoreError) as exc:
        read_tree(store, aid)
    assert str(exc.value) == f"object {aid[:12]} is not a tree"
    assert [e["path"] for e in read_tree(store, tree)] == ["a.bin", "b.bin"]
    with pytest.raises(StoreError) as exc:
        check_kind("Demos")
    assert str(exc.value) == (
        "bad artifact kind 'Demos': use lowercase letters, digits and '-' (e.g. base-policy, replay, "
        "teacher-targets, checkpoint, eval, handoff, demos, episodes)"
    )
    assert check_kind("d" + "x" * 39) == "d" + "x" * 39


def test_a_published_artifact_s_manifest_holds_exactly_its_identity(store, tmp_path):
    """manifests.write_manifest and publish_artifact: every field, with the defaults and with each argument
    given, and only the producer's step (ids in the triage files of round 12)."""
    from artifacts.manifests import ARTIFACT_FORMAT, publish_artifact, write_manifest

    src = tmp_path / "policy.bin"
    src.write_bytes(b"p" * 10)
    content = {"layout": "file", "content": hash_bytes(b"p" * 10), "size": 10, "files": 1, "name": "policy.bin"}
    base = {"type": "artifact", "format": ARTIFACT_FORMAT, "kind": "base-policy", "producer": {"step": "finetune-base"}}
    bare = publish_artifact(store, src, "base-policy", producer={"step": "finetune-base", "attempt": 3})
    assert read_artifact(store, bare) == {**base, "inputs": {}, "config": {}, "code_version": "", "meta": {}, **content}
    assert write_manifest(store, content, "base-policy", producer={"step": "finetune-base"}) == bare
    given = {"inputs": {"demos": "d" * 64}, "config": {"lr": 0.1}, "code_version": "abc123", "meta": {"epochs": 2}}
    full = publish_artifact(store, src, "base-policy", producer={"step": "finetune-base", "cache_key": "k"}, **given)
    assert read_artifact(store, full) == {**base, **given, **content}
    assert write_manifest(store, content, "base-policy", producer={"step": "finetune-base"}, **given) == full
    assert read_artifact(store, publish_artifact(store, src, "base-policy", producer={}))["producer"] == {}


def test_a_file_name_that_is_not_utf8_is_refused_in_one_exact_line():
    """manifests.utf8_name 4, 5."""
    from artifacts.errors import path_text
    from artifacts.manifests import utf8_name

    odd = Path("/data") / "caf\udce9.bin"
    with pytest.raises(StoreError) as exc:
        utf8_name(odd.name, odd)
    assert str(exc.value) == f"{path_text(odd)}: file name is not valid UTF-8; rename it to store it"
    assert utf8_name("café.bin", Path("café.bin")) == "café.bin"


def test_publishing_with_adopt_links_the_staged_file_in_instead_of_copying_it(store):
    """manifests.publish_artifact 11: `how` reaches store_content."""
    from artifacts.manifests import publish_artifact

    staged = store.new_tmp_dir("stage") / "replay.bin"
    staged.write_bytes(b"r" * 40)
    aid = publish_artifact(store, staged, "replay", producer={"step": "warmup"}, how="adopt")
    oid = read_artifact(store, aid)["content"]
    assert os.stat(store.object_path(oid)).st_ino == os.stat(staged).st_ino


def test_an_adopted_file_replaces_a_damaged_object_of_its_id_and_becomes_read_only(store):
    """Store.adopt_file 6 (the damaged copy is moved aside by id), 18 (the new object is r--r--r--)."""
    oid = store.put_bytes(b"r" * 40)
    path = store.object_path(oid)
    _overwrite(path, b"r" * 39)  # damaged: another size
    staged = store.new_tmp_dir("stage") / "replay.bin"
    staged.write_bytes(b"r" * 40)
    assert store.adopt_file(staged) == (oid, 40)
    assert path.read_bytes() == b"r" * 40
    assert path.stat().st_mode & 0o777 == 0o444
    assert [p.name.split(".")[0] for p in store.quarantine_dir.iterdir()] == [oid]


def test_a_scratch_folder_is_made_even_when_the_tmp_area_was_removed(store):
    """Store.new_tmp_dir 5: the tmp area itself is made again."""
    shutil.rmtree(store.tmp_dir)
    scratch = store.new_tmp_dir("stage")
    assert scratch.is_dir() and scratch.parent == store.tmp_dir
    assert scratch.name.startswith(f"stage-{os.getpid()}-")


def _blobs_sharing_a_prefix(count: int) -> list[bytes]:
    """`count` small blobs whose ids share their first four hex digits (found by hashing, not stored)."""
    by_prefix: dict[str, list[bytes]] = {}
    i = 0
    while True:
        blob = f"blob {i}".encode()
        group = by_prefix.setdefault(hash_bytes(blob)[:4], [])
        group.append(blob)
        if len(group) == count:
            return group
        i += 1


def test_an_id_prefix_resolves_when_unambiguous_and_each_refusal_is_one_exact_line(store, tmp_path):
    """Store.resolve_prefix: case, the 4-digit minimum, hex only, no match, and an ambiguous prefix listing
    four of its matches (ids in the triage files of round 12)."""
    blobs = _blobs_sharing_a_prefix(5)
    oids = sorted(store.put_bytes(b) for b in blobs)
    prefix = oids[0][:4]
    lone = store.put_bytes(b"lone")
    assert store.resolve_prefix(lone.upper()) == lone
    assert store.resolve_prefix(lone[:8].upper()) == lone
    for bad in ("abc", "ab-d", "wxyz"):
        with pytest.raises(StoreError) as exc:
            store.resolve_prefix(bad)
        assert str(exc.value) == f"{bad!r} is neither a ref nor an id (ids are hex, at least 4 digits)"
    absent = next(p for p in (f"{n:02x}00" for n in range(256)) if not (store.objects_dir / p[:2]).is_dir())
    stored = list(store.iter_object_ids())
    near = next(
        f"{prefix[:2]}{n:02x}" for n in range(256) if not any(o.startswith(f"{prefix[:2]}{n:02x}") for o in stored)
    )
    for unknown in (absent, near.upper()):
        with pytest.raises(StoreError) as exc:
            store.resolve_prefix(unknown)
        assert str(exc.value) == f"no object or ref matches {unknown!r}"
    with pytest.raises(StoreError) as exc:
        store.resolve_prefix(prefix.upper())
    shown = ", ".join(o[:12] for o in oids[:4])
    assert str(exc.value) == f"id prefix {prefix.upper()!r} is ambiguous (5 objects: {shown}…); give more digits"
    pair, _ = Store.init(tmp_path / "pair")
    two = sorted(pair.put_bytes(b) for b in _blobs_sharing_a_prefix(2))
    with pytest.raises(StoreError, match=r"is ambiguous \(2 objects"):
        pair.resolve_prefix(two[0][:4])
    pair.close()


def test_fetch_missing_says_whether_every_object_is_here(store):
    """Store.fetch_missing 5: objects already here need no remote (read_bytes then reads an object another
    writer put in place after its first read missed it)."""
    here = store.put_bytes(b"here")
    assert store.fetch_missing(here) is True
    assert store.fetch_missing() is True
    assert store.fetch_missing(here, hash_bytes(b"elsewhere")) is False  # no promisor remote to ask


# ----------------------------------------------------------------------------- store.Store.init / open (round 12)
def test_a_new_store_has_its_layout_and_config_and_a_second_init_opens_it(tmp_path, monkeypatch):
    """Store.__init__, init: every folder of the layout, the config's bytes, created or not; the default
    place is $ACCRUE_STORE (ids in the triage files of round 12)."""
    root = tmp_path / "deep" / "store"
    store, created = Store.init(root)
    assert created is True and store.root == root
    assert sorted(p.name for p in root.iterdir()) == sorted(
        ["config", "objects", "refs", "records", "log", "locks", "tmp", "quarantine"]
    )
    assert (root / "config").read_bytes() == b'{"format":1,"hash":"blake3"}\n'
    assert [p.name for p in (root / "objects").iterdir()] == ["blake3"]
    paths = (store.objects_dir, store.refs_dir, store.records_dir, store.log_path, store.locks_dir)
    assert paths == (
        root / "objects/blake3",
        root / "refs",
        root / "records",
        root / "log/events.jsonl",
        root / "locks",
    )
    assert (store.tmp_dir, store.quarantine_dir) == (root / "tmp", root / "quarantine")
    assert all(p.is_dir() for p in (store.objects_dir, store.refs_dir, store.records_dir, store.locks_dir))
    again, created = Store.init(root)
    assert created is False and again.root == root
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("ACCRUE_STORE", "deep/store")
    assert Store.open().root == root and Store.init()[1] is False
    monkeypatch.delenv("ACCRUE_STORE")
    fresh, created = Store.init()
    assert created is True and fresh.root == tmp_path / ".accrue"
    for handle in (store, again, fresh):
        handle.close()


def test_a_store_cannot_be_made_on_a_file_or_where_a_folder_cannot_be_made(tmp_path):
    """Store.init: both refusals, word for word."""
    (tmp_path / "plain").write_text("x")
    with pytest.raises(StoreError) as exc:
        Store.init(tmp_path / "plain")
    assert str(exc.value) == f"{tmp_path / 'plain'}: exists and is not a directory"
    (tmp_path / "st").mkdir()
    (tmp_path / "st" / "refs").write_text("not a folder")
    with pytest.raises(StoreError) as exc:
        Store.init(tmp_path / "st")
    assert str(exc.value) == f"cannot create a store at {tmp_path / 'st'}: {tmp_path / 'st' / 'refs'}: File exists"


def test_opening_a_store_refuses_each_kind_of_bad_config_in_one_exact_line(tmp_path):
    """Store.open: no store, config not JSON, not an object, another format or hash, a folder in its place."""
    root = tmp_path / "store"
    with pytest.raises(StoreError) as exc:
        Store.open(root)
    assert str(exc.value) == f"no accrue store at {root} (run `accrue init` or pass --store PATH)"
    Store.init(root)[0].close()
    config = root / "config"
    for text, line in [
        (b"{not json", f"{config}: not valid JSON"),
        (b"\xff\xfe", f"{config}: not valid JSON"),
        (b"[1, 2]", f"{config}: not a store config (expected a JSON object, got list)"),
        (
            b'{"format": 2, "hash": "blake3"}',
            f"{config}: unsupported store format 2 / hash 'blake3' (this accrue reads format 1, blake3)",
        ),
        (
            b'{"format": 1, "hash": "sha256"}',
            f"{config}: unsupported store format 1 / hash 'sha256' (this accrue reads format 1, blake3)",
        ),
        (b"{}", f"{config}: unsupported store format None / hash None (this accrue reads format 1, blake3)"),
    ]:
        _overwrite(config, text)
        with pytest.raises(StoreError) as exc:
            Store.open(root)
        assert str(exc.value) == line
    config.unlink()
    config.mkdir()
    with pytest.raises(StoreError, match="no accrue store"):
        Store.open(root)


def test_opening_a_store_whose_empty_folders_were_lost_makes_them_again(tmp_path, monkeypatch):
    """Store.open: a store copied without its empty folders opens whole; one that cannot be written
    still opens for reading."""
    root = tmp_path / "store"
    Store.init(root)[0].close()
    for sub in ("refs", "records", "log", "locks", "tmp", "quarantine"):
        os.rmdir(root / sub)
    shutil.rmtree(root / "objects")
    store = Store.open(root)
    assert all((root / sub).is_dir() for sub in ("objects", "refs", "records", "log", "locks", "tmp", "quarantine"))
    assert store.objects_dir.is_dir()
    store.close()
    shutil.rmtree(root / "tmp")

    def read_only(self, *args, **kwargs):
        raise PermissionError(13, "Permission denied", str(self))

    monkeypatch.setattr(Path, "mkdir", read_only)
    assert Store.open(root).root == root


def test_an_interrupted_init_is_finished_by_the_next_and_open_remakes_each_lost_folder(tmp_path):
    """Store.init 16, 18, 21, 22, 27: folders an interrupted init left (no config yet) are kept; Store.open
    38, 40: open makes every lost folder, whichever others are still there."""
    root = tmp_path / "store"
    for sub in ("objects/blake3", "refs", "tmp"):
        (root / sub).mkdir(parents=True)
    store, created = Store.init(root)
    assert created is True and (root / "config").is_file()
    store.close()
    os.rmdir(root / "quarantine")
    os.rmdir(root / "objects" / "blake3")
    Store.open(root).close()
    assert (root / "quarantine").is_dir() and (root / "objects" / "blake3").is_dir()


def test_an_unreadable_config_is_one_line_naming_why(tmp_path, monkeypatch):
    """Store.open 15, 16."""
    root = tmp_path / "store"
    Store.init(root)[0].close()
    real = Path.read_bytes

    def read_bytes(self):
        if self.name == "config":
            raise PermissionError(errno.EACCES, "Permission denied", str(self))
        return real(self)

    monkeypatch.setattr(Path, "read_bytes", read_bytes)
    with pytest.raises(StoreError) as exc:
        Store.open(root)
    assert str(exc.value) == f"cannot read the store's config: {root / 'config'}: Permission denied"


def test_a_failed_write_names_the_store(store, monkeypatch):
    """_WriteErrors.__init__ 1: the line says which store could not be written."""

    def full(tmp, data):
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp))

    monkeypatch.setattr(artifacts.store, "write_new_fsynced", full)
    with pytest.raises(StoreError) as exc:
        store.put_bytes(b"new bytes")
    assert str(exc.value).startswith(f"cannot write to the store at {store.root}: {store.tmp_dir}/.obj-tmp-")
    assert str(exc.value).endswith(": No space left on device")


def test_objects_a_partial_pull_left_on_a_remote_are_known_as_promised(store):
    """Store.__init__ 35: the promised list is read on first use."""
    (store.root / "remotes" / "nas").mkdir(parents=True)
    (store.root / "remotes" / "nas" / "promised").write_text(f"{'a' * 64}\n")
    assert store.is_promised("a" * 64) is True
    assert store.is_promised("b" * 64) is False


def test_removing_a_work_folder_is_best_effort_and_never_raises(tmp_path, monkeypatch):
    """store.remove_tree 3, 5, 6: a file that cannot be removed (a step's leftover on a read-only mount) is
    left behind without an error, so the cleanup in a step's `finally` cannot turn a committed step into a
    failed one; a read-only view is made removable first."""
    from artifacts.store import remove_tree

    work = tmp_path / "work"
    (work / "inputs" / "view").mkdir(parents=True)
    (work / "inputs" / "view" / "a.bin").write_bytes(b"a")
    (work / "stuck.bin").write_bytes(b"s")
    os.chmod(work / "inputs" / "view", 0o555)
    real_unlink = os.unlink

    def unlink(path, *args, **kwargs):
        if os.fspath(path).endswith("stuck.bin"):
            raise PermissionError(errno.EPERM, "Operation not permitted", os.fspath(path))
        return real_unlink(path, *args, **kwargs)

    monkeypatch.setattr(os, "unlink", unlink)
    remove_tree(work)
    assert sorted(p.name for p in work.rglob("*")) == ["stuck.bin"]
    remove_tree(tmp_path / "never-made")  # nothing there: nothing to do


# ----------------------------------------------------------------------------- records (round 12)
def test_an_attempt_record_is_its_fields_and_the_log_s_head_in_canonical_bytes(store):
    """records.write_attempt and attempt_path: records/<key>/NNNN.json, canonical JSON and a newline, the
    log anchor taken at the write; a state outside the four is refused; a write that fails is one line
    (ids in the triage files of round 12)."""
    from artifacts.auditlog import current_anchor
    from artifacts.hashing import canonical_json
    from artifacts.records import attempt_path

    key = "ab" * 32
    assert attempt_path(store, key, 7) == store.records_dir / key / "0007.json"
    append_event(store, "custom", note="anchor")
    attempt = _attempt(key, 7, "running", 4242)
    write_attempt(store, attempt)
    anchor = current_anchor(store)
    assert anchor is not None and anchor["seq"] == 0
    path = store.records_dir / key / "0007.json"
    assert path.read_bytes() == canonical_json({**attempt, "log_anchor": anchor}) + b"\n"
    for state in ("committed", "failed", "abandoned"):
        write_attempt(store, {**attempt, "state": state})
        assert json.loads(path.read_bytes())["state"] == state
    with pytest.raises(ValueError) as exc:
        write_attempt(store, {**attempt, "state": "paused"})
    assert str(exc.value) == "bad attempt state paused"
    shutil.rmtree(store.records_dir / key)
    (store.records_dir / key).write_text("a file where the key's folder goes")
    with pytest.raises(StoreError) as exc:
        write_attempt(store, attempt)
    assert str(exc.value).startswith(f"cannot write attempt record {path}: ")


def test_attempts_are_listed_per_key_oldest_first_and_damaged_ones_reported_or_raised(store):
    """records.list_attempts: one key or every key (only folders named by a full id, sorted), only
    NNNN.json files; a damaged file raises, or goes to `problems` and is skipped."""
    from artifacts.records import list_attempts

    one, two = "ab" * 32, "cd" * 32
    for key, number in [(two, 2), (one, 1), (two, 1), (two, 10)]:
        write_attempt(store, _attempt(key, number, "committed", number))
    (store.records_dir / two / "notes.json").write_text("{}")
    (store.records_dir / "not-a-key").mkdir()
    (store.records_dir / "not-a-key" / "0001.json").write_text(json.dumps(_attempt("not-a-key", 1, "failed", 1)))
    (store.records_dir / ("ef" * 32)).write_text("a file, not a key folder")
    listed = [(a["cache_key"], a["attempt"]) for a in list_attempts(store)]
    assert listed == [(one, 1), (two, 1), (two, 2), (two, 10)]
    assert [a["attempt"] for a in list_attempts(store, two)] == [1, 2, 10]
    assert list_attempts(store, "12" * 32) == []
    damaged = store.records_dir / two / "0002.json"
    _overwrite(damaged, b"{half")
    with pytest.raises(StoreError) as exc:
        list_attempts(store, two)
    assert str(exc.value) == f"{damaged}: damaged attempt record (JSONDecodeError)"
    problems: list[str] = []
    assert [a["attempt"] for a in list_attempts(store, problems=problems)] == [1, 1, 10]
    assert problems == [f"{damaged}: damaged attempt record (JSONDecodeError)"]
    shutil.rmtree(store.records_dir)
    assert list_attempts(store) == []


# ----------------------------------------------------------------------------- store objects (round 12)
def test_a_stored_object_is_read_back_verified_and_a_damaged_or_missing_one_is_one_line(store):
    """Store.put_bytes, put_json, read_bytes, read_json, object_path, has_object, object_size, _publish_tmp:
    the fan-out path, read-only objects, the temp file gone, each refusal word for word (ids in the triage
    files of round 12)."""
    oid = store.put_json({"b": 1, "a": [1, 2]})
    assert oid == hash_bytes(b'{"a":[1,2],"b":1}')
    path = store.object_path(oid)
    assert path == store.objects_dir / oid[:2] / oid[2:]
    assert store.has_object(oid) and store.object_size(oid) == 17 and path.stat().st_mode & 0o777 == 0o444
    assert list(store.tmp_dir.iterdir()) == []
    assert store.put_bytes(b'{"a":[1,2],"b":1}') == oid and list(store.tmp_dir.iterdir()) == []
    assert store.read_bytes(oid) == b'{"a":[1,2],"b":1}' and store.read_json(oid) == {"a": [1, 2], "b": 1}
    listed, text = store.put_json([1, 2]), store.put_bytes(b"not json")
    for bad in (listed, text):
        with pytest.raises(StoreError) as exc:
            store.read_json(bad)
        assert str(exc.value) == f"object {bad[:12]} is not a JSON manifest"
    _overwrite(path, b'{"a":[1,2],"b":2}')
    with pytest.raises(StoreError) as exc:
        store.read_bytes(oid)
    assert str(exc.value) == (
        f"object {oid[:12]} is corrupt (its bytes no longer match its id); run `accrue verify --full`"
    )
    assert store.read_bytes(oid, verify=False) == b'{"a":[1,2],"b":2}'
    path.unlink()
    assert not store.has_object(oid) and store.object_size(oid) is None
    with pytest.raises(StoreError) as exc:
        store.read_bytes(oid)
    assert str(exc.value) == f"object {oid[:12]} is missing from the store"
    path.mkdir()
    assert not store.has_object(oid)  # a folder in an object's place is not the object


def test_the_config_is_changed_under_its_lock_and_keeps_keys_it_does_not_know(store, monkeypatch):
    """Store.read_config, update_config."""
    import artifacts.locks

    held = []
    real_lock = artifacts.locks.store_lock

    def store_lock(where, name, *args, **kwargs):
        held.append((where, name))
        return real_lock(where, name, *args, **kwargs)

    monkeypatch.setattr(artifacts.locks, "store_lock", store_lock)
    config = store.root / "config"
    _overwrite(config, b'{"format":1,"hash":"blake3","future":{"x":1}}\n')
    assert store.read_config() == {"format": 1, "hash": "blake3", "future": {"x": 1}}

    def change(cfg):
        cfg["remotes"] = {"nas": {"url": "/nas"}}

    after = store.update_config(change)
    assert after == {"format": 1, "hash": "blake3", "future": {"x": 1}, "remotes": {"nas": {"url": "/nas"}}}
    assert config.read_bytes() == b'{"format":1,"future":{"x":1},"hash":"blake3","remotes":{"nas":{"url":"/nas"}}}\n'
    assert held == [(store.locks_dir, "config")]


def test_an_object_a_partial_pull_left_on_a_promisor_is_fetched_when_read(store, monkeypatch):
    """Store.read_bytes 9: after a fetcher brings the object in, its bytes are read and verified."""
    blob = b"left on the remote"
    oid = hash_bytes(blob)
    asked = []

    def fetch(into, missing):
        asked.append(list(missing))
        tmp = into.tmp_dir / "fetched"
        tmp.write_bytes(blob)
        into._publish_tmp(tmp, oid)
        return True

    monkeypatch.setattr(artifacts.store, "_MISSING_FETCHERS", [fetch])
    with pytest.raises(StoreError, match="is missing from the store"):
        store.read_bytes(oid)  # no promisor remote: nobody is asked
    assert asked == []
    store.update_config(lambda cfg: cfg.setdefault("remotes", {}).update({"nas": {"url": "/nas", "promisor": True}}))
    assert store.read_bytes(oid) == blob
    assert asked == [[oid]]


def test_ingesting_a_file_copies_it_in_once_and_refuses_an_unreadable_or_changing_one(store, tmp_path, monkeypatch):
    """Store.ingest_file: the object read-only with the file's bytes, fsynced, no temp file left; an
    unreadable source and one that changes size are one line each and store nothing (ids in the triage
    files of round 12). The source is opened without a warning (ingest_file 10 asked for line buffering,
    which a binary file refuses with a RuntimeWarning on every add)."""
    src = tmp_path / "demo.bin"
    src.write_bytes(b"d" * 1000)
    synced = []
    real_fsync = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: synced.append(os.readlink(f"/proc/self/fd/{fd}")) or real_fsync(fd))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        oid, size = store.ingest_file(src)
    assert (oid, size) == (hash_bytes(b"d" * 1000), 1000)
    path = store.object_path(oid)
    assert path.read_bytes() == b"d" * 1000 and path.stat().st_mode & 0o777 == 0o444
    assert any(os.path.basename(p).startswith(".obj-tmp-") for p in synced)  # the copy reached disk first
    assert list(store.tmp_dir.iterdir()) == []
    with pytest.raises(StoreError) as exc:
        store.ingest_file(tmp_path / "absent.bin")
    assert str(exc.value) == f"cannot read {tmp_path / 'absent.bin'}: No such file or directory"
    real_copy = artifacts.store.copy_hashing

    def growing(f, fd, size_hint):
        got = real_copy(f, fd, size_hint)
        with open(src, "ab") as more:
            more.write(b"+" * 24)
        return got

    monkeypatch.setattr(artifacts.store, "copy_hashing", growing)
    src.write_bytes(b"e" * 1000)
    with pytest.raises(StoreError) as exc:
        store.ingest_file(src)
    assert str(exc.value) == f"{src}: changed size while it was being stored (1000 -> 1024 bytes); nothing was stored"
    assert list(store.tmp_dir.iterdir()) == [] and not store.has_object(hash_bytes(b"e" * 1000))


# ----------------------------------------------------------------------------- writers.hold / _open (round 12)
def _other_process_can_lock(path: Path, exclusive_lock: bool) -> bool:
    """Whether another process gets the lock on path now (without waiting)."""
    how = "LOCK_EX" if exclusive_lock else "LOCK_SH"
    mode = "O_RDWR" if exclusive_lock else "O_RDONLY"
    code = (
        "import fcntl, os, sys\n"
        f"fd = os.open({str(path)!r}, os.{mode})\n"
        f"try:\n    fcntl.lockf(fd, fcntl.{how} | fcntl.LOCK_NB)\nexcept OSError:\n    sys.exit(1)\n"
    )
    return subprocess.run([sys.executable, "-c", code]).returncode == 0


def test_a_writer_holds_a_shared_lock_on_a_file_it_makes_and_gives_it_back(store):
    """writers.hold and _open: locks/writers.lock made (rw-r--r--, its folder too), shared with other
    writers, exclusive to nobody until the handle is closed (ids in the triage files of round 12)."""
    import artifacts.writers as writers

    shutil.rmtree(store.locks_dir)
    old_umask = os.umask(0o022)
    try:
        writers.hold(store)
    finally:
        os.umask(old_umask)
    lock = store.locks_dir / "writers.lock"
    assert lock.stat().st_mode & 0o777 == 0o644
    assert writers._held[str(lock)].users == 1
    writers.hold(store)
    assert writers._held[str(lock)].users == 1  # a handle holds once
    assert _other_process_can_lock(lock, exclusive_lock=False)
    assert not _other_process_can_lock(lock, exclusive_lock=True)
    other = Store.open(store.root)
    writers.hold(other)
    assert writers._held[str(lock)].users == 2  # one descriptor, counted per handle
    store.close()
    assert writers._held[str(lock)].users == 1
    assert not _other_process_can_lock(lock, exclusive_lock=True)
    other.close()
    assert str(lock) not in writers._held
    assert _other_process_can_lock(lock, exclusive_lock=True)


def test_a_store_whose_lock_cannot_be_made_or_taken_is_still_written_without_one(store, monkeypatch):
    """writers._open: a lock file that cannot be opened for writing is opened read-only (a shared lock
    needs no more); neither: no lock. writers.hold: a filesystem without POSIX locks holds nothing."""
    import artifacts.writers as writers

    lock = str(store.locks_dir / "writers.lock")
    real_open = os.open
    opened = []

    def open_(path, flags, *mode):
        if os.fspath(path) == lock:
            opened.append(flags)
            if flags & os.O_CREAT:
                raise PermissionError(errno.EACCES, "Permission denied", path)
        return real_open(path, flags, *mode)

    Path(lock).touch()
    monkeypatch.setattr(os, "open", open_)
    fd = writers._open(lock)
    assert fd is not None and opened == [os.O_RDWR | os.O_CREAT, os.O_RDONLY]
    assert os.stat(lock).st_ino == os.fstat(fd).st_ino
    with pytest.raises(OSError):
        os.write(fd, b"x")  # read-only
    os.close(fd)
    os.unlink(lock)
    assert writers._open(lock) is None
    store.put_bytes(b"written without a lock")
    assert lock not in writers._held and not getattr(store, "_writer_held", False)
    monkeypatch.setattr(os, "open", real_open)

    def no_posix_locks(fd, how):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(writers.fcntl, "lockf", no_posix_locks)
    store.put_bytes(b"also without")
    assert lock not in writers._held and not getattr(store, "_writer_held", False)


# ----------------------------------------------------------------------------- refs (round 12)
def test_ref_names_are_slash_separated_parts_of_a_safe_alphabet():
    """refs.check_ref_name: each part starts with a letter or digit and is at most 100 characters."""
    from artifacts.refs import check_ref_name

    for good in ("a", "team/A9/x_y.z+1-2", "9" * 100, "a/" + "b" * 100):
        assert check_ref_name(good) == good
    for bad in ("", "a//b", "/a", "a/", ".hidden", "a/-x", "a b", "a/" + "b" * 101, "café"):
        with pytest.raises(StoreError) as exc:
            check_ref_name(bad)
        assert str(exc.value) == (
            f"bad ref name {bad!r}: use '/'-separated parts of letters, digits, '.', '_', '-', '+'"
        )


def test_a_ref_file_holding_anything_but_an_id_is_named_and_never_read_whole(store, monkeypatch):
    """refs.read_ref, _read_ref_file: an id with surrounding whitespace is read; a missing ref, or a folder
    in its place, is none; damaged and unreadable files are one line each; at most 128 bytes are read."""
    from artifacts.refs import read_ref

    oid = store.put_bytes(b"x")
    ref = store.refs_dir / "team" / "a"
    ref.parent.mkdir()
    ref.write_text(f"  {oid}\n\n")
    assert read_ref(store, "team/a") == oid
    assert read_ref(store, "team/none") is None and read_ref(store, "team") is None
    assert read_ref(store, "team/a/deeper") is None  # under a file: not a directory
    ref.write_bytes(b"\x00\xffnot an id" + b"z" * 10_000)
    import artifacts.refs

    reads = []

    class CountingFile:
        def __init__(self, path, mode):
            self.f = open(path, mode)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.f.close()

        def read(self, n=-1):
            reads.append(n)
            return self.f.read(n)

    monkeypatch.setattr(artifacts.refs, "open", CountingFile, raising=False)
    with pytest.raises(StoreError) as exc:
        read_ref(store, "team/a")
    assert reads == [128]
    shown = repr(b"\x00\xffnot an id" + b"z" * 9)
    assert str(exc.value) == (
        f"ref team/a is damaged (holds {shown}, not an id): not written by accrue? move {ref} out of the store"
    )

    def unreadable(path, mode):
        raise PermissionError(errno.EACCES, "Permission denied", str(path))

    monkeypatch.setattr(artifacts.refs, "open", unreadable, raising=False)
    with pytest.raises(StoreError) as exc:
        read_ref(store, "team/a")
    assert str(exc.value) == "ref team/a cannot be read (Permission denied)"


def test_moving_a_ref_writes_its_id_logs_the_move_and_refuses_what_would_break_the_tree(store, monkeypatch):
    """refs.set_ref, _move: only an id the store holds; the old target returned and logged (not when
    unchanged, nor with log=False); a ref cannot sit where a ref folder is or under a ref; under the refs
    lock; an OS error is one line (ids in the triage files of round 12)."""
    import artifacts.refs
    from artifacts.refs import read_ref, set_ref

    a, b = store.put_bytes(b"a"), store.put_bytes(b"b")
    for target in ("nothing", hash_bytes(b"not stored")):
        with pytest.raises(StoreError) as exc:
            set_ref(store, "team/a", target)
        assert str(exc.value) == f"refusing to point ref team/a at {target[:12]}: no such object in the store"
    locks = []
    real_lock = artifacts.refs.store_lock
    monkeypatch.setattr(artifacts.refs, "store_lock", lambda where, name: locks.append(name) or real_lock(where, name))
    assert set_ref(store, "team/a", a) is None
    assert (store.refs_dir / "team" / "a").read_bytes() == f"{a}\n".encode() and locks == ["refs"]
    assert set_ref(store, "team/a", b) == a
    assert set_ref(store, "team/a", b) == b  # unchanged: not logged again
    assert set_ref(store, "quiet", a, log=False) is None
    moves = [(e["ref"], e["old"], e["new"]) for e in iter_events(store) if e["event"] == "ref-moved"]
    assert moves == [("team/a", None, a), ("team/a", a, b)]
    with pytest.raises(StoreError) as exc:
        set_ref(store, "team/a/deeper", a)
    assert str(exc.value) == "ref team/a/deeper conflicts with existing ref team/a"
    with pytest.raises(StoreError) as exc:
        set_ref(store, "team", a)
    assert str(exc.value) == "ref team conflicts with existing refs under team/"
    assert read_ref(store, "team/a") == b and not (store.refs_dir / "team" / "a").is_dir()

    def full(path, data, tmp_dir=None):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(artifacts.refs, "write_replace", full)
    with pytest.raises(StoreError) as exc:
        set_ref(store, "team/c", a)
    assert str(exc.value) == f"cannot move ref team/c: {store.refs_dir / 'team' / 'c'}: No space left on device"


def test_refs_are_listed_by_prefix_skipping_temp_files_and_reporting_or_raising_on_damaged_ones(store):
    """refs.list_refs: sorted names under a prefix; dot files (a ref update's temp file) and folders are
    not refs; a damaged file or one whose name is not a ref raises, or goes to `problems` and is skipped
    (ids in the triage files of round 12)."""
    from artifacts.refs import list_refs, set_ref

    a, b = store.put_bytes(b"a"), store.put_bytes(b"b")
    set_ref(store, "team/b", b)
    set_ref(store, "team/a", a)
    set_ref(store, "teams", a)
    set_ref(store, "solo", b)
    (store.refs_dir / "team" / ".tmp-1-ab").write_text("half")
    assert list(list_refs(store)) == ["solo", "team/a", "team/b", "teams"]
    assert list_refs(store, "team/") == {"team/a": a, "team/b": b}
    assert list_refs(store, "team") == {"team/a": a, "team/b": b, "teams": a}
    (store.refs_dir / "team" / "broken").write_text("junk")
    with pytest.raises(StoreError, match="ref team/broken is damaged"):
        list_refs(store)
    (store.refs_dir / "team" / "broken").unlink()
    (store.refs_dir / "team" / "bad name").write_text(a)
    problems: list[str] = []
    assert list_refs(store, problems=problems) == {"solo": b, "team/a": a, "team/b": b, "teams": a}
    assert problems == ["bad ref name 'team/bad name': use '/'-separated parts of letters, digits, '.', '_', '-', '+'"]
    shutil.rmtree(store.refs_dir)
    assert list_refs(store) == {}


# ----------------------------------------------------------------------------- resolve (round 12)
def test_what_a_user_types_resolves_to_a_ref_s_id_an_id_or_a_step_output_and_each_miss_is_one_line(store):
    """resolve.resolve: a ref (before a prefix of the same letters), a full id or a prefix, `X:role` of a step
    record; a role of something that is not a step record, or one the step lacks, word for word; the
    handle holds the writer lock from the lookup on (ids in the triage files of round 12)."""
    import artifacts.writers as writers
    from artifacts.refs import set_ref
    from artifacts.resolve import resolve

    data = store.put_bytes(b"data")
    other = store.put_bytes(b"other")
    record = store.put_json({"type": "step-record", "step": "train", "outputs": {"ckpt": data, "replay": other}})
    empty = store.put_json({"type": "step-record", "step": "eval", "outputs": {}})
    set_ref(store, "team/run", record)
    set_ref(store, data[:6], other)  # a ref whose name is also a prefix of an id: the ref wins
    store.close()
    assert resolve(store, "team/run") == record
    assert str(store.locks_dir / "writers.lock") in writers._held
    assert resolve(store, data[:6]) == other
    assert resolve(store, data) == data and resolve(store, other[:8]) == other
    assert resolve(store, "team/run:ckpt") == data and resolve(store, f"{record[:10]}:replay") == other
    tree = store.put_json({"type": "tree", "entries": []})
    for text, line in [
        (f"{tree}:ckpt", f"{tree!r}: not a step record, so it has no output 'ckpt'"),
        (f"{data[:8]}:ckpt", f"object {data[:12]} is not a JSON manifest"),
        ("team/run:eval", "'team/run': step train has no output 'eval' (it has: ckpt, replay)"),
        (f"{empty}:x", f"{empty!r}: step eval has no output 'x' (it has: none)"),
    ]:
        with pytest.raises(StoreError) as exc:
            resolve(store, text)
        assert str(exc.value) == line
    posing = store.put_json({"type": "note", "outputs": {"ckpt": data}})
    with pytest.raises(StoreError) as exc:
        resolve(store, f"{posing}:ckpt")
    assert str(exc.value) == f"{posing!r}: not a step record, so it has no output 'ckpt'"
    for text in ("", "a b", "a b:ckpt"):
        with pytest.raises(StoreError) as exc:
            resolve(store, text)
        assert (
            str(exc.value) == f"{text.partition(':')[0]!r} is neither a ref nor an id (ids are hex, at least 4 digits)"
        )
    with pytest.raises(StoreError, match="no object or ref matches 'fffff0'"):
        resolve(store, "fffff0")


# ----------------------------------------------------------------------------- manifests.put_tree / store_content
def demo_folder(root: Path) -> dict[str, bytes]:
    """A folder with nested folders, an empty file and an executable one; returns path -> bytes."""
    files = {"b.txt": b"bee", "a/z.bin": b"zed" * 10, "a/deeper/empty": b"", "run.sh": b"#!/bin/sh\n"}
    for rel, data in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(data)
    (root / "run.sh").chmod(0o755)
    return files


@pytest.mark.parametrize("how", ["copy", "adopt", "checked"])
def test_a_folders_content_is_a_sorted_tree_of_its_files_stored_the_way_asked(store, tmp_path, how):
    """manifests.put_tree 1-75 (each file stored by the way asked, its entry's path, id, size and exec bit,
    the entries sorted by path, the totals), store_content 1-58 (a folder's and a file's content fields)."""
    from artifacts.manifests import MANIFEST_FORMAT, store_content

    folder = tmp_path / "folder"
    files = demo_folder(folder)
    source_inode = (folder / "b.txt").stat().st_ino
    content = store_content(store, folder, how)
    entries = [
        {"path": rel, "id": hash_bytes(files[rel]), "size": len(files[rel]), "exec": rel == "run.sh"}
        for rel in sorted(files)
    ]
    assert store.read_json(content["content"]) == {"type": "tree", "format": MANIFEST_FORMAT, "entries": entries}
    assert content == {"layout": "dir", "content": content["content"], "size": 43, "files": 4}
    linked = store.object_path(hash_bytes(b"bee")).stat().st_ino == source_inode
    assert linked == (how == "adopt")

    single = tmp_path / "single.bin"
    single.write_bytes(b"one file")
    single_inode = single.stat().st_ino
    assert store_content(store, single, how) == {
        "layout": "file",
        "content": hash_bytes(b"one file"),
        "size": 8,
        "files": 1,
        "name": "single.bin",
    }
    assert (store.object_path(hash_bytes(b"one file")).stat().st_ino == single_inode) == (how == "adopt")


def test_content_that_is_not_regular_files_and_folders_is_refused_in_one_line(store, tmp_path):
    """store_content 3-30 (a symlink, a missing path, a name that is not UTF-8), put_tree (a symlinked folder,
    a symlinked file or a FIFO inside, a file inside whose name is not UTF-8: put_tree 36 named no path),
    _walk_error (a folder that cannot be listed)."""
    from artifacts.manifests import put_tree, store_content

    target = tmp_path / "target.bin"
    target.write_bytes(b"x")
    link = tmp_path / "link.bin"
    link.symlink_to(target)
    cases = [(link, f"{link}: a symlink; only regular files and directories can be stored")]
    cases.append((tmp_path / "nowhere", f"{tmp_path / 'nowhere'}: no such file or directory"))
    bad_name = Path(os.fsdecode(str(tmp_path).encode() + b"/caf\xe9.bin"))
    bad_name.write_bytes(b"y")
    cases.append((bad_name, f"{tmp_path}/caf\\udce9.bin: file name is not valid UTF-8; rename it to store it"))
    for n, make in enumerate(
        [
            lambda d: (d / "sub").symlink_to(tmp_path, target_is_directory=True),
            lambda d: (d / "f.bin").symlink_to(target),
            lambda d: os.mkfifo(d / "pipe"),
        ]
    ):
        folder = tmp_path / f"folder{n}"
        folder.mkdir()
        (folder / "ok.txt").write_bytes(b"ok")
        make(folder)
        inside = sorted(p for p in folder.iterdir() if p.name != "ok.txt")[0]
        why = (
            "a symlink; only regular files and directories can be stored (copy the target in instead)"
            if n == 0
            else "only regular files can be stored (symlinks and devices are refused)"
        )
        cases.append((folder, f"{inside}: {why}"))
    named_inside = tmp_path / "named_inside"
    (named_inside / "sub").mkdir(parents=True)
    Path(os.fsdecode(str(named_inside).encode() + b"/sub/caf\xe9.bin")).write_bytes(b"z")
    message = f"{named_inside}/sub/caf\\udce9.bin: file name is not valid UTF-8; rename it to store it"
    cases.append((named_inside, message))
    for path, message in cases:
        with pytest.raises(StoreError) as exc:
            store_content(store, path)
        assert str(exc.value) == message
    with pytest.raises(StoreError) as exc:
        put_tree(store, tmp_path / "nowhere", "copy")
    assert str(exc.value) == f"cannot read {tmp_path / 'nowhere'}: No such file or directory"


# ----------------------------------------------------------------------------- ingest.add_path
def test_adding_a_file_writes_one_artifact_indexed_by_its_content_and_adding_it_again_reuses_it(store, tmp_path):
    """ingest.add_path 1-82: the artifact written once (its event names it, its kind and source), indexed
    under ingested/<kind>/<content>, the ref moved when one is given; the same bytes again (from anywhere)
    are the same artifact, not a new event; an index pointing at other content is written afresh."""
    from artifacts.auditlog import iter_events
    from artifacts.refs import read_ref, set_ref

    first, again = tmp_path / "first.bin", tmp_path / "elsewhere" / "again.bin"
    again.parent.mkdir()
    first.write_bytes(b"replay bytes")
    again.write_bytes(b"replay bytes")
    content = hash_bytes(b"replay bytes")
    index = f"ingested/replay/{content}"

    aid, created = add_path(store, first, "replay", ref="team/r")
    assert created is True
    manifest = store.read_json(aid)
    assert (manifest["kind"], manifest["content"], manifest["producer"]) == ("replay", content, {"step": "add"})
    events = [(e["event"], e.get("artifact"), e.get("kind"), e.get("source"), e.get("ref")) for e in iter_events(store)]
    assert events[0] == ("artifact-written", aid, "replay", str(first.absolute()), None)
    assert [e[0] for e in events] == ["artifact-written", "ref-moved", "ref-moved"]
    assert (read_ref(store, index), read_ref(store, "team/r")) == (aid, aid)

    assert add_path(store, again, "replay") == (aid, False)
    assert add_path(store, again, "replay", ref="team/s") == (aid, False)
    assert read_ref(store, "team/s") == aid
    assert sum(e["event"] == "artifact-written" for e in iter_events(store)) == 1

    other, _ = add_path(store, again, "demos")
    assert other != aid and read_ref(store, f"ingested/demos/{content}") == other

    (tmp_path / "x.bin").write_bytes(b"other bytes")
    elsewhere, _ = add_path(store, tmp_path / "x.bin", "replay")
    set_ref(store, index, elsewhere)  # an index that names an artifact of other bytes
    fresh, created = add_path(store, first, "replay")
    assert created is True and store.read_json(fresh)["content"] == content
    assert read_ref(store, index) == fresh


def test_an_add_that_cannot_be_logged_or_named_stores_nothing(store, tmp_path):
    """ingest.add_path 1-5 (the kind checked first), 6-10 (a source path that is not UTF-8), 11-12 (a damaged
    log refuses the add before anything is copied)."""
    src = tmp_path / "data.bin"
    src.write_bytes(b"data")
    with pytest.raises(StoreError, match="^bad artifact kind 'Bad Kind'"):
        add_path(store, src, "Bad Kind")
    folder = Path(os.fsdecode(str(tmp_path).encode() + b"/caf\xe9"))
    folder.mkdir()
    (folder / "data.bin").write_bytes(b"data")
    with pytest.raises(StoreError) as exc:
        add_path(store, folder / "data.bin", "replay")
    assert str(exc.value) == f"{tmp_path}/caf\\udce9/data.bin: file name is not valid UTF-8; rename it to store it"
    store.log_path.parent.mkdir(exist_ok=True)
    store.log_path.write_bytes(b"not an event\n")
    with pytest.raises(StoreError, match="its last line is damaged; nothing was written"):
        add_path(store, src, "replay")
    assert list(store.iter_object_ids()) == []


# ----------------------------------------------------------------------------- atomic: publishing a file
def test_a_directory_sync_opens_a_directory_only_and_syncs_it(tmp_path, monkeypatch):
    """atomic.fsync_dir 1-8: the directory is opened as one (a file is refused) and that descriptor synced."""
    import artifacts.atomic as atomic

    synced = []
    real_fsync = os.fsync
    monkeypatch.setattr(atomic.os, "fsync", lambda fd: synced.append(os.fstat(fd).st_ino) or real_fsync(fd))
    atomic.fsync_dir(tmp_path)
    assert synced == [tmp_path.stat().st_ino]
    (tmp_path / "file").write_bytes(b"x")
    with pytest.raises(NotADirectoryError):
        atomic.fsync_dir(tmp_path / "file")


def test_a_temp_name_is_hidden_in_the_directory_and_names_this_process(tmp_path):
    """atomic.temp_name 1-4."""
    import re

    from artifacts.atomic import temp_name

    for prefix in ("", "obj-"):
        name = temp_name(tmp_path, prefix)
        assert name.parent == tmp_path
        assert re.fullmatch(rf"\.{prefix}tmp-{os.getpid()}-[0-9a-f]{{12}}", name.name)
    assert temp_name(tmp_path) != temp_name(tmp_path)


def test_a_new_file_is_written_whole_even_in_short_writes_synced_and_never_over_another(tmp_path, monkeypatch):
    """atomic.write_new_fsynced 1-22: mode 0644 (less the umask), O_EXCL, every byte written when a write
    takes only part, synced before it returns; a failing write leaves no partial file and is raised."""
    import artifacts.atomic as atomic

    data = os.urandom(5000)
    real_write, real_fsync = os.write, os.fsync
    synced = []
    monkeypatch.setattr(atomic.os, "write", lambda fd, view: real_write(fd, bytes(view[:700])))
    monkeypatch.setattr(atomic.os, "fsync", lambda fd: synced.append(os.fstat(fd).st_size) or real_fsync(fd))
    path = tmp_path / "new.bin"
    atomic.write_new_fsynced(path, data)
    assert path.read_bytes() == data and synced == [5000]
    umask = os.umask(0)
    os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o644 & ~umask
    with pytest.raises(FileExistsError):
        atomic.write_new_fsynced(path, b"other")
    assert path.read_bytes() == data

    def full_disk(fd, view):
        if os.fstat(fd).st_size >= 1400:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_write(fd, bytes(view[:700]))

    monkeypatch.setattr(atomic.os, "write", full_disk)
    with pytest.raises(OSError, match="No space left"):
        atomic.write_new_fsynced(tmp_path / "partial.bin", data)
    assert not (tmp_path / "partial.bin").exists()


def test_a_replace_goes_through_a_temp_file_in_the_folder_or_the_one_given_and_leaves_none(tmp_path, monkeypatch):
    """atomic.write_replace 1-15: the parent made, the temp file in the target's folder (or tmp_dir), renamed
    over the target, the folder synced; a rename that fails removes its temp file and is raised."""
    import artifacts.atomic as atomic

    renamed, synced = [], []
    real_replace = os.replace
    monkeypatch.setattr(atomic.os, "replace", lambda a, b: renamed.append((Path(a).parent, b)) or real_replace(a, b))
    monkeypatch.setattr(atomic, "fsync_dir", synced.append)
    target = tmp_path / "deep" / "er" / "value.json"
    atomic.write_replace(target, b"one")
    atomic.write_replace(target, b"two")
    assert target.read_bytes() == b"two"
    assert renamed == [(target.parent, target)] * 2
    assert synced[-1] == target.parent and synced.count(target.parent) == 2
    spare = tmp_path / "spare"
    spare.mkdir()
    atomic.write_replace(target, b"three", tmp_dir=spare)
    assert renamed[-1] == (spare, target) and target.read_bytes() == b"three"

    blocked = tmp_path / "blocked"
    (blocked / "inside").mkdir(parents=True)  # a non-empty folder where the file should go
    with pytest.raises(OSError):
        atomic.write_replace(blocked, b"x")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blocked", "deep", "spare"]
    assert [p.name for p in target.parent.iterdir()] == ["value.json"] and not any(spare.iterdir())


def test_linking_into_place_publishes_once_and_never_overwrites(tmp_path, monkeypatch):
    """atomic.link_into_place 1-10: the parent made, True for a new file and False (the existing bytes kept)
    when the name is taken, the parent synced either way."""
    import artifacts.atomic as atomic

    synced = []
    monkeypatch.setattr(atomic, "fsync_dir", synced.append)
    first, second = tmp_path / "a.tmp", tmp_path / "b.tmp"
    first.write_bytes(b"first")
    second.write_bytes(b"second")
    final = tmp_path / "objects" / "ab" / "cdef"
    assert atomic.link_into_place(first, final) is True
    assert atomic.link_into_place(second, final) is False
    assert final.read_bytes() == b"first" and final.stat().st_ino == first.stat().st_ino
    assert synced[-2:] == [final.parent, final.parent]


# ----------------------------------------------------------------------------- locks, clock, the store's write errors
def test_a_stores_lock_is_a_file_in_its_locks_folder_and_timeout_comes_from_filelock(tmp_path):
    """locks.store_lock 1-9 (the folder made, the file named <name>.lock), locks.__getattr__ 1-5."""
    import filelock

    import artifacts.locks as locks

    lock = locks.store_lock(tmp_path / "a" / "locks", "gc")
    assert lock.lock_file == str(tmp_path / "a" / "locks" / "gc.lock")
    with lock:
        assert (tmp_path / "a" / "locks" / "gc.lock").exists()
    assert locks.Timeout is filelock.Timeout
    with pytest.raises(AttributeError, match="^Nope$"):
        locks.Nope  # noqa: B018


def test_timestamps_are_utc_iso_8601_to_the_millisecond():
    """clock.now_iso 1-4."""
    import re

    from artifacts.clock import now_iso

    stamp = now_iso()
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}\+00:00", stamp)
    assert abs(datetime.fromisoformat(stamp).timestamp() - datetime.now().timestamp()) < 60


def test_an_error_that_is_not_about_the_disk_passes_through_a_store_write_unchanged(tmp_path):
    """store._WriteErrors.__exit__ 5: only an OSError becomes the one-line store error."""
    with pytest.raises(ValueError, match="not a disk problem"):
        with artifacts.store._WriteErrors(tmp_path):
            raise ValueError("not a disk problem")
