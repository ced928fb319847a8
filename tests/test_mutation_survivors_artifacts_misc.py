"""Tests written to kill mutants of artifacts/ (gc, the writer lock, the pipelined copy, and the remote
commands prune, status, verify, log and the partial clone's fetch) that survived mutmut's fourth
sweep (docs/MUTATION.md, "The fourth sweep"). Each docstring names the mutmut ids it kills. What they
pin: gc is a dry run unless told, counts what it keeps, leaves young objects and live writers' files
alone, logs what it is about to delete, and says in one line why it cannot run; gc polls a busy store
at most every 0.1 s and gives up at its deadline; a copy of more than 128 MiB keeps its bytes and id,
and a failed write is raised as itself; `remote prune` is a dry run with a one-day grace, refuses when
it cannot tell what is reachable, and stops when a ref moves meanwhile; status asks the remote, not
the last fetch; the JSON of `remote verify` and `log --remote`. Everything runs in a temporary
directory, with directory remotes (no network).

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
import threading
import time
import warnings
from pathlib import Path

import blake3
import pytest

import artifacts.gc
import artifacts.remotes.prune
import artifacts.writers
from artifacts.auditlog import append_event, iter_events
from artifacts.errors import StoreError
from artifacts.gc import collect_garbage
from artifacts.hashing import CHUNK_SIZE, copy_hashing, hash_bytes, hash_file
from artifacts.ingest import add_path
from artifacts.locks import store_lock
from artifacts.remotes.backends import object_key
from artifacts.remotes.check import verify_remote
from artifacts.remotes.config import add_remote, set_promisor
from artifacts.remotes.lazy import fetch_promised
from artifacts.remotes.logchain import remote_log_chains
from artifacts.remotes.prune import prune_remote
from artifacts.remotes.pull import fetch
from artifacts.remotes.push import push
from artifacts.remotes.status import ref_status
from artifacts.store import Store
from artifacts.writers import LOCK_NAME, exclusive

sys.path.insert(0, str(Path(__file__).resolve().parent))
from auditlog_support import write_old_log  # noqa: E402
from reliability_support import remount, small_fs  # noqa: E402

DAY = 86400.0
REPAIR_HINT = "`accrue verify` shows the damage, `accrue verify --repair` seals it"  # ends each damaged-log line


@pytest.fixture
def store(tmp_path: Path) -> Store:
    s, _ = Store.init(tmp_path / "store")
    yield s
    s.close()


def artifact(store: Store, tmp_path: Path, data: bytes, ref: str) -> str:
    src = tmp_path / f"{ref.replace('/', '-')}.bin"
    src.write_bytes(data)
    return add_path(store, src, "replay", ref=ref)[0]


def set_age(path: Path, age_s: float) -> None:
    """Last modified age_s seconds ago (negative: in the future, as from a clock that runs ahead)."""
    t = time.time() - age_s
    os.utime(path, (t, t), follow_symlinks=False)


# ----------------------------------------------------------------------------- gc
def test_gc_without_yes_is_a_dry_run_that_counts_kept_young_and_removable_objects(store, tmp_path):
    """gc.collect_garbage 1 (the default deletes), _collect 2 (dry_run not reported), 13, 15 (kept
    miscounted), 24, 26 (young miscounted), 27 (the first young object stops the sweep: the old one
    after it is kept)."""
    aid = artifact(store, tmp_path, b"replay" * 100, "team/replay")
    loose = sorted((hash_bytes(d), d) for d in (b"loose 1", b"loose 2", b"loose 3"))
    for oid, data in loose:
        assert store.put_bytes(data) == oid
    (young_a, _), (young_b, _), (old, old_data) = loose  # ids in sweep order: two young ones first
    for oid in (young_a, young_b):
        set_age(store.object_path(oid), -3600)

    dry = collect_garbage(store, grace_s=0)
    assert dry.dry_run is True
    assert (dry.kept, dry.young, dry.removed) == (2, 2, [(old, len(old_data))])
    assert all(store.has_object(o) for o, _ in loose)

    done = collect_garbage(store, dry_run=False, grace_s=0)
    assert done.dry_run is False
    assert (done.kept, done.young, done.removed) == (2, 2, [(old, len(old_data))])
    assert not store.has_object(old) and store.has_object(young_a) and store.has_object(young_b)
    assert store.has_object(aid)


def test_gc_logs_what_it_is_about_to_remove_and_then_what_it_removed(store, tmp_path):
    """gc._collect 66–68, 71–73 (the gc-started event's removing / bytes / tmp_removing), 90–92, 95–97
    (the gc event's removed / bytes / tmp_removed)."""
    artifact(store, tmp_path, b"kept", "team/kept")
    store.put_bytes(b"a" * 10)
    store.put_bytes(b"b" * 32)
    (store.tmp_dir / "attempt-dead-999999999-abcd").mkdir()
    collect_garbage(store, dry_run=False, grace_s=0)
    started, finished = [e for e in iter_events(store) if e["event"] in ("gc-started", "gc")]
    assert [started.get(k) for k in ("event", "removing", "bytes", "tmp_removing")] == ["gc-started", 2, 42, 1]
    assert [finished.get(k) for k in ("event", "removed", "bytes", "tmp_removed")] == ["gc", 2, 42, 1]


def test_gc_leaves_a_live_writers_temp_file_under_refs_alone(store, tmp_path):
    """gc._collect 49 (`and` → `or`: a live writer's old temp file of a ref update is swept)."""
    artifact(store, tmp_path, b"kept", "team/kept")
    live = store.refs_dir / f".tmp-{os.getpid()}-00ff"
    dead = store.refs_dir / ".tmp-999999999-00ff"
    for path in (live, dead):
        path.write_text("a ref update in flight")
    report = collect_garbage(store, dry_run=False, grace_s=0)
    assert report.tmp_removed == ["refs/.tmp-999999999-00ff"]
    assert live.exists() and not dead.exists()


def test_gc_of_a_store_copied_without_its_empty_tmp_directory(store, tmp_path):
    """gc._collect 31 (tmp/ listed even when it is missing: a traceback-free 'gc could not finish'
    instead of a sweep)."""
    artifact(store, tmp_path, b"kept", "team/kept")
    loose = store.put_bytes(b"loose")
    store.tmp_dir.rmdir()
    report = collect_garbage(store, dry_run=False, grace_s=0)
    assert [o for o, _ in report.removed] == [loose] and report.tmp_removed == []


def test_what_vanishes_between_gcs_listing_and_its_sweep_is_not_an_error(store, tmp_path, monkeypatch):
    """gc._collect 76, 78 (an object already gone fails the unlink), 84, 85 (a temp file already gone
    fails it too). Both are removed right after gc logs what it is about to delete, as a `verify`
    moving a damaged object aside, or a user cleaning tmp/ by hand, would."""
    artifact(store, tmp_path, b"kept", "team/kept")
    loose = store.put_bytes(b"loose")
    stray = store.tmp_dir / "upload-999999999-abcd"
    stray.write_bytes(b"half a file")
    real_append = artifacts.gc.append_event

    def append_then_lose_them(s, event, **fields):
        real_append(s, event, **fields)
        if event == "gc-started":
            os.unlink(store.object_path(loose))
            os.unlink(stray)

    monkeypatch.setattr(artifacts.gc, "append_event", append_then_lose_them)
    report = collect_garbage(store, dry_run=False, grace_s=0)
    assert [o for o, _ in report.removed] == [loose] and report.tmp_removed == [stray.name]
    assert [e["event"] for e in iter_events(store)][-1] == "gc"


def test_gc_on_a_read_only_store_only_reports(tmp_path):
    """gc.collect_garbage 8 (the dry run refused, --yes let through), 9 (the refusal's text), 10–16
    (the report of a read-only store: its store, dry_run and grace passed on, nothing deleted)."""
    with small_fs(tmp_path / "ro") as fs:
        s, _ = Store.init(fs / "store")
        artifact(s, tmp_path, b"kept", "team/kept")
        loose = s.put_bytes(b"nobody refers to me")
        s.close()
        remount(fs, read_only=True)
        try:
            ro = Store.open(fs / "store")
            with pytest.raises(StoreError) as exc:
                collect_garbage(ro, dry_run=False, grace_s=0)
            assert str(exc.value) == f"the store at {ro.root} cannot be written: gc can only report (drop --yes)"
            report = collect_garbage(ro, grace_s=0)
            assert report.dry_run is True and report.removed == [(loose, 19)] and report.kept == 2
            assert ro.has_object(loose)
            ro.close()
        finally:
            remount(fs, read_only=False)


def test_gc_refuses_at_once_while_another_gc_holds_the_store(store):
    """gc.collect_garbage 19, 30, 31 (the refusal names 'the store (gc)'), 32 (it waits a second first)."""
    with store_lock(store.locks_dir, "gc"):
        started = time.monotonic()
        with pytest.raises(StoreError) as exc:
            collect_garbage(store)
        waited = time.monotonic() - started
    assert str(exc.value) == "the store (gc) is locked by another accrue process; try again when it finishes"
    assert waited < 0.9


def test_gc_that_cannot_open_its_lock_file_says_so_in_one_line(store):
    """gc.collect_garbage 33–38: `gc cannot lock the store: PATH: REASON`."""
    (store.locks_dir / "gc.lock").mkdir(parents=True)
    with pytest.raises(StoreError) as exc:
        collect_garbage(store)
    line = str(exc.value)  # the path is shortened past QUOTE_LIMIT characters: match its ends
    assert line.startswith("gc cannot lock the store: ") and line.endswith("gc.lock: Is a directory")


def test_gc_that_fails_midway_says_so_in_one_line(store, tmp_path):
    """gc.collect_garbage 49–54: an OSError during the sweep is `gc could not finish: PATH: REASON` (here
    an object file that is a dangling link, e.g. a store copied with links to a disk that is gone)."""
    artifact(store, tmp_path, b"kept", "team/kept")
    oid = hash_bytes(b"on the other disk")
    path = store.object_path(oid)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.symlink_to(tmp_path / "gone" / "object")
    with pytest.raises(StoreError) as exc:
        collect_garbage(store, grace_s=0)
    line = str(exc.value)
    assert line.startswith("gc could not finish: ") and line.endswith(f"{oid[2:]}: No such file or directory")


# ----------------------------------------------------------------------------- writers._acquire_exclusive
HOLD = """
import fcntl, os, sys
fd = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT, 0o644)
fcntl.lockf(fd, fcntl.LOCK_SH)
print("held", flush=True)
sys.stdin.read()
"""


@pytest.fixture
def writer_elsewhere(store):
    """Another process holding the store's writer lock as a writer does (shared), until the test ends."""
    proc = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(store.locks_dir / LOCK_NAME)], stdin=subprocess.PIPE, stdout=subprocess.PIPE
    )
    assert proc.stdout.readline() == b"held\n"
    yield proc.pid
    proc.stdin.close()
    proc.wait(timeout=10)


class FakeClock:
    """Stands in for the time module of the writer lock: sleeps only advance its clock."""

    def __init__(self) -> None:
        self.now, self.slept = 1000.0, []

    def monotonic(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.slept.append(seconds)
        self.now += seconds


def test_gc_polls_a_busy_store_at_most_every_tenth_of_a_second_until_its_deadline(store, writer_elsewhere, monkeypatch):
    """writers._acquire_exclusive 29 (polls every 1.1 s), 34, 35 (sleeps 0.1 s even past the deadline);
    gc.collect_garbage 2 (without --wait, gc waits a second before giving up); writers._acquire_exclusive
    11 (`>` the deadline: without --wait, on a clock that has not moved, gc sleeps once more)."""
    clock = FakeClock()
    monkeypatch.setattr(artifacts.writers, "time", clock)
    with pytest.raises(StoreError, match="is using it"):
        collect_garbage(store)
    assert clock.slept == []
    with pytest.raises(StoreError, match="is using it"):
        collect_garbage(store, wait_s=0.25)
    assert max(clock.slept) <= 0.1
    assert 0.25 - 1e-9 <= sum(clock.slept) <= 0.25 + 0.01 + 1e-9


def test_gc_that_cannot_tell_who_holds_the_store_says_another_process(store, writer_elsewhere, monkeypatch):
    """writers._acquire_exclusive 16–18: with no pid to name (a filesystem whose F_GETLK fails), the
    message says 'another process', not 'pid None'."""

    def no_getlk(*_args):
        raise OSError(errno.EINVAL, "Invalid argument")

    monkeypatch.setattr(artifacts.writers.fcntl, "fcntl", no_getlk)
    with pytest.raises(StoreError) as exc:
        with exclusive(store, wait_s=0):
            pass
    assert str(exc.value) == (
        "gc needs the store to itself, but an accrue process (another process) is using it; "
        "run gc when it finishes, or pass --wait SECONDS"
    )


def test_gc_whose_writer_lock_cannot_be_taken_names_the_lock_and_the_reason(tmp_path):
    """writers._acquire_exclusive 10: a lock that fails for another reason than a holder is
    `PATH: cannot lock (REASON)` (here the lock file is a directory, which opens only read-only)."""
    s, _ = Store.init(tmp_path / "store")
    s.close()
    lock = tmp_path / "store" / "locks" / LOCK_NAME
    lock.unlink(missing_ok=True)
    lock.mkdir()
    fresh = Store.open(tmp_path / "store")
    with pytest.raises(StoreError) as exc:
        collect_garbage(fresh)
    assert str(exc.value) == f"{lock}: cannot lock (Bad file descriptor)"
    fresh.close()


# ----------------------------------------------------------------------------- hashing._copy_hashing_pipelined
class Pattern:
    """A readable source of `size` bytes that repeats one chunk (no memory for the whole copy)."""

    def __init__(self, size: int) -> None:
        self.left = size
        self.chunk = (bytes(range(256)) * (CHUNK_SIZE // 256 + 1))[:CHUNK_SIZE]

    def readinto(self, buffer: bytearray) -> int:
        n = min(len(buffer), self.left, CHUNK_SIZE)
        buffer[:n] = self.chunk[:n]
        self.left -= n
        return n

    def expected_id(self, size: int) -> str:
        h, left = blake3.blake3(), size
        while left:
            n = min(left, CHUNK_SIZE)
            h.update(self.chunk[:n])
            left -= n
        return h.hexdigest()


def copy_within(source: Pattern, fd: int, size: int, seconds: float = 20.0) -> tuple | BaseException:
    """copy_hashing's result (or the error it raised), failing the test instead of hanging when the copy
    does not end within `seconds` (a writer thread that dies or never starts leaves the reader waiting)."""
    outcome: list[BaseException | tuple] = []

    def run() -> None:
        try:
            outcome.append(copy_hashing(source, fd, size))
        except BaseException as exc:  # noqa: BLE001 - inspected by the caller
            outcome.append(exc)

    worker = threading.Thread(target=run, daemon=True)
    worker.start()
    worker.join(timeout=seconds)
    assert not worker.is_alive(), "the copy hung"
    return outcome[0]


def test_a_copy_of_more_than_128_mib_keeps_its_bytes_and_id(tmp_path):
    """hashing._copy_hashing_pipelined 21 (the early writeback is given no descriptor), 22 (its
    counter reset to None): a copy past 128 MiB fails instead of finishing. 10, 11, 27, 30, 51 (the writer
    never runs, ends at once, or is handed what it cannot unpack): the copy hangs, and fails here after
    20 s instead of hanging the suite."""
    size = 17 * CHUNK_SIZE + 123
    source = Pattern(size)
    dst = tmp_path / "copy.bin"
    fd = os.open(dst, os.O_WRONLY | os.O_CREAT, 0o644)
    try:
        got = copy_within(source, fd, size)
    finally:
        os.close(fd)
    assert got == (source.expected_id(size), size)
    assert hash_file(dst) == got


def test_a_copy_whose_write_fails_raises_that_error_and_does_not_hang(tmp_path):
    """hashing._copy_hashing_pipelined 7 (no failure list: the copy waits forever for a buffer), 24
    (`raise None`), 52 (`failure[1]`): the destination's own OSError comes back."""
    size = 6 * CHUNK_SIZE
    dst = tmp_path / "copy.bin"
    dst.write_bytes(b"")
    fd = os.open(dst, os.O_RDONLY)  # a destination that refuses every write
    try:
        exc = copy_within(Pattern(size), fd, size)
    finally:
        os.close(fd)
    assert isinstance(exc, OSError) and exc.errno == errno.EBADF


# ----------------------------------------------------------------------------- remotes (a directory remote)
def pushed(tmp_path: Path) -> tuple[Store, str, Path]:
    """A store that pushed one file artifact (ref team/replay) to a new directory remote `origin`:
    (the store, the artifact's id, the remote's directory)."""
    a, _ = Store.init(tmp_path / "a")
    aid = artifact(a, tmp_path, b"replay" * 100, "team/replay")
    (tmp_path / "nas" / "accrue").mkdir(parents=True)  # the remote's directory (`remote init` makes one)
    remote = tmp_path / "nas" / "accrue"
    add_remote(a, "origin", str(remote))
    push(a, "origin")
    return a, aid, remote


def another_store(tmp_path: Path, remote: Path, name: str = "b") -> Store:
    s, _ = Store.init(tmp_path / name)
    add_remote(s, "origin", str(remote))
    return s


def remote_objects(remote: Path) -> set[str]:
    return {p.relative_to(remote).as_posix() for p in (remote / "objects").rglob("*") if p.is_file()}


def leftover(remote: Path, data: bytes, age_s: float) -> str:
    """An object on the remote that nothing reaches (what `push --force` leaves), age_s seconds old."""
    oid = hash_bytes(data)
    path = remote / object_key(oid)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    set_age(path, age_s)
    return oid


def unfinished_upload(remote: Path, name: str, age_s: float) -> str:
    path = remote / "tmp" / name
    path.parent.mkdir(exist_ok=True)
    path.write_bytes(b"half an object")
    set_age(path, age_s)
    return f"tmp/{name}"


def test_remote_prune_is_a_dry_run_with_a_one_day_grace_by_default(tmp_path):
    """remotes.prune.prune_remote 1 (the default deletes), 2 (a grace of a day and a second), 13 (the
    report's remote), 32 (its reachable count), 59 (young miscounted), 62 (a young unfinished upload
    counted as abandoned)."""
    a, _, remote = pushed(tmp_path)
    reachable = len(remote_objects(remote))
    old = leftover(remote, b"two days old", 2 * DAY)
    edge = leftover(remote, b"a day and a quarter second old", DAY + 0.25)
    young = [leftover(remote, b"just sent", 0), leftover(remote, b"a minute old", 60)]
    dead = unfinished_upload(remote, "obj-dead", 2 * DAY)
    unfinished_upload(remote, "obj-live", 0)
    before = remote_objects(remote)
    report = prune_remote(a, "origin")
    assert report.as_dict() == {
        "remote": "origin",
        "dry_run": True,
        "reachable": reachable,
        "removed": sorted([old, edge]),
        "bytes": len(b"two days old") + len(b"a day and a quarter second old"),
        "young": 2,
        "uploads": [dead],
        "leases_taken_over": [],
    }
    assert remote_objects(remote) == before and len(list((remote / "tmp").iterdir())) == 2
    assert not set(young) & set(report.removed)


def test_remote_prune_deletes_old_unreachable_objects_when_there_is_no_upload_to_drop(tmp_path):
    """remotes.prune.prune_remote 71 (`doomed or uploads` → `and`: nothing deleted without an
    unfinished upload)."""
    a, _, remote = pushed(tmp_path)
    reached = remote_objects(remote)
    old = leftover(remote, b"two days old", 2 * DAY)
    report = prune_remote(a, "origin", dry_run=False)
    assert report.removed == [old] and report.uploads == []
    assert remote_objects(remote) == reached
    assert verify_remote(a, "origin").ok


def test_remote_prune_goes_on_past_missing_or_short_objects(tmp_path):
    """remotes.prune.prune_remote 23–29: a remote that lacks an object, or holds one of the wrong
    size, still tells what is reachable (repair re-sends those); prune is not refused."""
    a, aid, remote = pushed(tmp_path)
    old = leftover(remote, b"two days old", 2 * DAY)
    content = remote / object_key(a.read_json(aid)["content"])
    os.chmod(content, 0o644)
    content.write_bytes(b"short")
    assert any("has size 5" in p for p in verify_remote(a, "origin").problems)
    assert prune_remote(a, "origin").removed == [old]
    content.unlink()
    assert any("lacks object" in p for p in verify_remote(a, "origin").problems)
    assert prune_remote(a, "origin").removed == [old]


def test_remote_prune_refuses_when_a_manifest_on_the_remote_cannot_be_read(tmp_path):
    """remotes.prune.prune_remote 22 (not refused), 30 (no message), 31 (`unreadable[1]`: a traceback)."""
    _, aid, remote = pushed(tmp_path)
    b = another_store(tmp_path, remote)  # has no manifest of its own: reads them from the remote
    manifest = remote / object_key(aid)
    os.chmod(manifest, 0o644)
    manifest.write_bytes(b'{"type": "artifact", "damaged": true}')
    [problem] = verify_remote(b, "origin").problems
    with pytest.raises(StoreError) as exc:
        prune_remote(b, "origin", dry_run=False, grace_s=0)
    assert str(exc.value) == (
        f"remote origin: cannot tell what is reachable ({problem}); run `accrue remote repair origin` first"
    )


def test_remote_prune_deletes_nothing_when_a_ref_moves_while_it_looks(tmp_path, monkeypatch):
    """remotes.prune.prune_remote 103: the exact line when a push moves a ref between prune's walk
    and its deletion (here the push runs when prune checks for leases)."""
    a, _, remote = pushed(tmp_path)
    old = leftover(remote, b"two days old", 2 * DAY)
    real_leases = artifacts.remotes.prune.read_leases

    def a_push_lands_meanwhile(backend):
        artifact(a, tmp_path, b"newer replay", "team/replay")
        push(a, "origin")
        return real_leases(backend)

    monkeypatch.setattr(artifacts.remotes.prune, "read_leases", a_push_lands_meanwhile)
    with pytest.raises(StoreError) as exc:
        prune_remote(a, "origin", dry_run=False)
    assert str(exc.value) == "remote origin: its refs moved while prune looked; nothing was deleted — run it again"
    assert (remote / object_key(old)).exists()


def test_status_asks_the_remote_unless_told_offline(tmp_path):
    """remotes.status.ref_status 1 (offline by default: the last fetch's view, here nothing)."""
    _, aid, remote = pushed(tmp_path)
    b = another_store(tmp_path, remote)
    rows = {r.ref: (r.local, r.remote, r.state) for r in ref_status(b, "origin")}
    assert rows["team/replay"] == (None, aid, "remote-only")
    assert ref_status(b, "origin", offline=True) == []


def test_status_against_an_empty_remote_directory_refuses_and_creates_nothing(tmp_path):
    """remotes.status.ref_status 18 (status would make the directory a remote)."""
    (tmp_path / "nas" / "accrue").mkdir(parents=True)
    remote = tmp_path / "nas" / "accrue"
    b = another_store(tmp_path, remote)
    with pytest.raises(StoreError) as exc:
        ref_status(b, "origin")
    assert str(exc.value) == f"remote origin ({remote}) holds no accrue store yet (push to it first)"
    assert list(remote.iterdir()) == []


def test_remote_verify_json_is_its_counts_and_problems_without_the_walk(tmp_path):
    """remotes.check.RemoteVerifyReport.as_dict 1, 2 (the `ok` key), 4–9 (a set of the walk left in:
    the JSON cannot be written)."""
    a, _, remote = pushed(tmp_path)
    report = verify_remote(a, "origin")
    shown = json.loads(json.dumps(report.as_dict()))
    assert shown == {
        "ok": True,
        "remote": "origin",
        "full": False,
        "refs": 3,
        "reachable": len(remote_objects(remote)),
        "bytes_hashed": 0,
        "problems": [],
        "damaged": [],
        "heal": None,
        "lacking_here": [],
    }


def test_log_remote_summarises_each_store_by_its_id_host_and_first_and_last_event(tmp_path):
    """remotes.logchain.LogChain.summary 1–4 (`store_id`, `host`), 9–16 (`first`: the first event's
    time), 17–25 (`last`: the last event's), 12, 20 (a chain with no events: None, not a traceback)."""
    a, _ = Store.init(tmp_path / "a")
    append_event(a, "note", n=1)
    time.sleep(0.005)  # events a few milliseconds apart: each has its own time stamp
    artifact(a, tmp_path, b"replay", "team/replay")
    time.sleep(0.005)
    append_event(a, "note", n=2)
    time.sleep(0.005)
    append_event(a, "note", n=3)
    (tmp_path / "nas" / "accrue").mkdir(parents=True)
    add_remote(a, "origin", str(tmp_path / "nas" / "accrue"))
    push(a, "origin")
    b = another_store(tmp_path, tmp_path / "nas" / "accrue")
    fetch(b, "origin")
    [chain] = remote_log_chains(b, "origin")
    lines = [json.loads(line) for line in a.log_path.read_text().splitlines()]
    summary = chain.summary()
    assert lines[-1]["event"] == "pushed" and (lines[-2]["event"], lines[-2]["n"]) == ("note", 3)
    assert summary == {
        "store_id": a.read_config()["store_id"],
        "host": socket.gethostname(),
        "segments": 1,
        "events": len(lines) - 1,
        "first": lines[0]["ts"],
        "last": lines[-2]["ts"],
        "ok": True,
        "problems": [],
    }
    segment = b.object_path(chain_head(b))
    os.chmod(segment, 0o644)
    segment.unlink()
    [lost] = remote_log_chains(b, "origin")
    assert (lost.summary()["first"], lost.summary()["last"], lost.summary()["events"]) == (None, None, 0)


def chain_head(store: Store) -> str:
    from artifacts.remotes import LOG_TRACKING
    from artifacts.remotes.pointers import tracking_refs

    [head] = tracking_refs(store, "origin", LOG_TRACKING).values()
    return head


def test_a_partial_clone_fetches_promised_objects_and_says_whether_all_came(tmp_path):
    """remotes.lazy.fetch_promised 15 (the ids left instead of whether none are), _fetch_from 22 (the
    fetched ones returned as missing)."""
    a, aid, remote = pushed(tmp_path)
    content = a.read_json(aid)["content"]
    b = another_store(tmp_path, remote)
    set_promisor(b, "origin")
    assert fetch_promised(b, [content]) is True
    assert b.read_bytes(content) == b"replay" * 100
    assert fetch_promised(b, [hash_bytes(b"never pushed")]) is False


def test_a_partial_clones_fetch_shows_a_progress_bar_naming_the_remote_on_a_terminal(tmp_path, capsys, monkeypatch):
    """remotes.lazy.fetch_promised 8 (the bar says 'fetching from None'), _fetch_from 3 (no bar), 8 (a
    total of 1 byte where the size is unknown until the objects arrive)."""
    import re

    a, aid, remote = pushed(tmp_path)
    content = a.read_json(aid)["content"]
    b = another_store(tmp_path, remote)
    set_promisor(b, "origin")
    capsys.readouterr()
    for name, value in {"TTY_COMPATIBLE": "1", "TTY_INTERACTIVE": "1", "COLUMNS": "120"}.items():
        monkeypatch.setenv(name, value)  # stderr counts as a terminal for rich
    assert fetch_promised(b, [content]) is True
    drawn = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", capsys.readouterr().err)
    assert "fetching from origin" in drawn and "600/? bytes" in drawn and "1/1 objects" in drawn


# ----------------------------------------------------------------------------- round 6 (TASK-52)
def test_os_error_text_joins_two_paths_with_an_arrow_and_falls_back_to_the_message_or_the_class():
    """errors.os_error_text 10 (the two paths of a rename joined by 'XX -> XX'), 2 (an OSError with a
    message but no strerror shown as its class name), 4 (shown as 'None')."""
    from artifacts.errors import os_error_text

    renamed = OSError(errno.EXDEV, "Invalid cross-device link", "/a/src", None, "/b/dest")
    assert os_error_text(renamed) == "/a/src -> /b/dest: Invalid cross-device link"
    assert os_error_text(OSError("the disk went away")) == "the disk went away"
    assert os_error_text(PermissionError()) == "PermissionError"


def accrue_main(monkeypatch, capsys, *args: str) -> tuple[int, str]:
    """(exit code, stdout) of the console entry `accrue ARGS`, in-process."""
    from cli.main import main

    capsys.readouterr()
    monkeypatch.setattr(sys, "argv", ["accrue", *args])
    with pytest.raises(SystemExit) as done:
        main()
    return done.value.code, capsys.readouterr().out


def test_gc_json_names_every_count(store, tmp_path, capsys, monkeypatch):
    """gc.GcReport.as_dict 3–6 (`kept`, `young`), 9, 10 (`bytes`), 11, 12 (`tmp_removed`), 13, 14
    (`problems`): the keys of `accrue gc --json`."""
    artifact(store, tmp_path, b"kept", "team/kept")
    old = store.put_bytes(b"o" * 10)
    young = store.put_bytes(b"young")
    set_age(store.object_path(young), -3600)
    (store.tmp_dir / "attempt-dead-999999999-abcd").mkdir()
    rc, out = accrue_main(monkeypatch, capsys, "gc", "--grace", "0", "--json", "--store", str(store.root))
    assert rc == 0
    assert json.loads(out) == {
        "dry_run": True,
        "kept": 2,
        "young": 1,
        "removed": [old],
        "bytes": 10,
        "tmp_removed": ["attempt-dead-999999999-abcd"],
        "problems": [],
    }


def test_verify_json_names_every_count(store, tmp_path, capsys, monkeypatch):
    """verify.VerifyReport.as_dict 1, 2 (`ok`), 3, 4 (`full`), 5, 6 (`objects_checked`), 7, 8
    (`bytes_hashed`), 9, 10 (`reachable`), 11, 12 (`log_events`), 15, 16 (`problems`), 17, 18 (`notes`),
    19, 20 (`repaired`): the keys of `accrue verify --json`."""
    artifact(store, tmp_path, b"replay" * 100, "team/replay")
    rc, out = accrue_main(monkeypatch, capsys, "verify", "--json", "--store", str(store.root))
    assert rc == 0
    assert json.loads(out) == {
        "ok": True,
        "full": False,
        "objects_checked": 2,  # the artifact's manifest and its content
        "bytes_hashed": 0,
        "reachable": 2,
        "log_events": 3,
        "quarantined": [],
        "problems": [],
        "notes": [],
        "repaired": None,
    }


def test_the_default_store_is_accrue_store_else_dot_accrue_in_the_working_directory(tmp_path, monkeypatch):
    """store.default_store_path 1 (ACCRUE_STORE ignored), 3 (likewise), 5 (Path(None): a TypeError)."""
    from artifacts import default_store_path

    elsewhere, cwd = tmp_path / "elsewhere", tmp_path / "cwd"
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    monkeypatch.setenv("ACCRUE_STORE", str(elsewhere))
    assert default_store_path() == elsewhere
    s, created = Store.init()
    assert created and s.root == elsewhere and not (cwd / ".accrue").exists()
    s.close()
    monkeypatch.setenv("ACCRUE_STORE", "")
    assert default_store_path() == cwd / ".accrue"
    monkeypatch.delenv("ACCRUE_STORE")
    assert default_store_path() == cwd / ".accrue"


def test_a_quarantined_object_is_named_by_its_id_pid_and_a_24_bit_random_number(store):
    """store.Store.quarantine 10 (a 32-bit random number: of 8 names, all stay below 2**24 only once in
    2**64 runs)."""
    for i in range(8):
        oid = store.put_bytes(b"damaged %d" % i)
        dest = store.quarantine(oid)
        assert dest.parent == store.quarantine_dir and not store.has_object(oid)
        head, _, number = dest.name.rpartition("-")
        assert head == f"{oid}.{os.getpid()}"
        assert 0 <= int(number) < 2**24
        assert dest.read_bytes() == b"damaged %d" % i


HOLD_RANGE = """
import fcntl, os, sys
fd = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT, 0o644)
fcntl.lockf(fd, fcntl.LOCK_SH, int(sys.argv[2]), int(sys.argv[3]))
print("held", flush=True)
sys.stdin.read()
"""


@pytest.mark.parametrize(("length", "start"), [(1, 0), (0, 1)], ids=["first-byte", "past-the-first-byte"])
def test_gc_names_the_pid_of_a_process_that_locks_only_part_of_the_writer_lock(store, length, start):
    """writers._holder_pid 16 (asks who locks from byte 1 on: a lock of byte 0 alone is not seen, and the
    message says 'another process'), 17 (asks who locks byte 0: a lock from byte 1 on is not seen). Any
    lock on the file blocks gc's, so gc names its holder whatever range it covers."""
    proc = subprocess.Popen(
        [sys.executable, "-c", HOLD_RANGE, str(store.locks_dir / LOCK_NAME), str(length), str(start)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
    )
    try:
        assert proc.stdout.readline() == b"held\n"
        with pytest.raises(StoreError) as exc:
            collect_garbage(store)
        assert str(exc.value) == (
            f"gc needs the store to itself, but an accrue process (pid {proc.pid}) is using it; "
            "run gc when it finishes, or pass --wait SECONDS"
        )
    finally:
        proc.stdin.close()
        proc.wait(timeout=10)


# ----------------------------------------------------------------------------- round 7 batch I
def test_push_delete_refuses_in_one_line_without_names_or_where_the_remote_holds_no_store(tmp_path):
    """remotes.unshare.delete_remote_refs 3 (the message when no ref is named), 16 (create=True: a
    delete against a remote directory with no store in it writes a config there and then says the ref
    is missing, instead of refusing and leaving the directory as it was)."""
    from artifacts.remotes.unshare import delete_remote_refs

    empty = tmp_path / "nas"
    empty.mkdir()
    b = another_store(tmp_path, empty)
    try:
        with pytest.raises(StoreError) as exc:
            delete_remote_refs(b, "origin", [])
        assert str(exc.value) == "push --delete: name the ref(s) to remove from the remote"
        with pytest.raises(StoreError) as exc:
            delete_remote_refs(b, "origin", ["team/replay"])
        assert str(exc.value) == f"remote origin ({empty}) holds no accrue store yet (push to it first)"
        assert list(empty.iterdir()) == []
    finally:
        b.close()


def test_push_delete_deletes_what_this_store_saw_refuses_the_rest_and_logs_one_event(tmp_path, monkeypatch):
    """remotes.unshare.delete_remote_refs 42 (the report's remote), 47 (the remote's id in a refusal
    shown as 'nothing'), 48, 49 (the id this store last saw shown as 'nothing'), 50 (a stale ref stops
    the refs after it), 57 (a ref moved meanwhile stops the refs after it), 63, 64 (the tracking ref's
    removal logged as a ref-deleted event of its own), 74, 81, 82 (the event's name), 75, 79 (its
    remote), 76, 80 (its refs)."""
    from artifacts.refs import list_refs, set_ref
    from artifacts.remotes.directory import DirBackend
    from artifacts.remotes.unshare import delete_remote_refs

    a, _, remote = pushed(tmp_path)
    b = another_store(tmp_path, remote)
    try:
        ids = {n: artifact(a, tmp_path, n.encode() * 50, f"team/{n}") for n in ("b", "c", "d", "e")}
        push(a, "origin")
        fetch(b, "origin")
        newer = artifact(a, tmp_path, b"the robot's newer replay", "team/b")
        push(a, "origin", ["team/b"])  # b has not seen this one
        real_delete = DirBackend.delete

        def delete(self, key, expect):
            if key == "refs/team/c":  # the robot moves team/c after b read it, before b deletes it
                set_ref(a, "team/c", newer)
                push(a, "origin", ["team/c"])
            return real_delete(self, key, expect)

        monkeypatch.setattr(DirBackend, "delete", delete)
        before = len(list(iter_events(b)))
        report = delete_remote_refs(b, "origin", ["team/b", "team/c", "team/d"])
        assert report.as_dict() == {
            "remote": "origin",
            "deleted": {"team/d": ids["d"]},
            "conflicts": [
                f"ref team/b: remote origin has {newer[:12]}, this store last saw {ids['b'][:12]} there; "
                "`accrue fetch origin` first, so nothing you have not seen is deleted",
                "ref team/c: remote origin moved it meanwhile; fetch and try again",
            ],
        }
        assert set(list_refs(b, "remotes/origin/team/")) == {
            "remotes/origin/team/replay",
            "remotes/origin/team/b",
            "remotes/origin/team/c",
            "remotes/origin/team/e",
        }
        events = list(iter_events(b))[before:]
        assert [(e["event"], e.get("remote"), e.get("refs")) for e in events] == [
            ("remote-refs-deleted", "origin", {"team/d": ids["d"]})
        ]
    finally:
        a.close()
        b.close()


# ----------------------------------------------------------------------------- auditlog: log/head against the log
def three_events(store: Store) -> list[bytes]:
    """A log of three events (seq 0-2) with its head; the log's lines, each with its newline."""
    for n in range(3):
        append_event(store, "custom", note=f"event {n}")
    return store.log_path.read_bytes().splitlines(keepends=True)


def log_problems(store: Store) -> list[tuple[str, int | None]]:
    from artifacts.auditlog import check_log

    return [(p.text, p.line) for p in check_log(store).problems]


def test_a_head_beside_an_empty_or_missing_log_says_whether_the_log_was_cut_or_deleted(store):
    """auditlog._head_problems 3, 5-7 (empty / missing), 9-14 (cut / deleted); _read_lines 43, 49 (an
    empty file is present: "empty ... cut", not "missing ... deleted")."""
    three_events(store)
    store.log_path.write_bytes(b"")
    cut = "the audit log is empty, but log/head says it ended at seq 2: it was cut"
    assert log_problems(store) == [(cut, None)]
    store.log_path.unlink()
    deleted = "the audit log is missing, but log/head says it ended at seq 2: it was deleted"
    assert log_problems(store) == [(deleted, None)]


def test_a_cut_tail_names_the_last_whole_event_and_both_byte_offsets(store):
    """auditlog._head_problems 19, 21, 22 (which line is the last), 24, 26, 28, 29 (its seq), 31, 32
    (its end); 25, 27, 30: a last line that is half a line has no seq, shown as "?"."""
    lines = three_events(store)
    kept = b"".join(lines[:2])
    store.log_path.write_bytes(kept)
    assert log_problems(store) == [
        (
            f"the log ends at seq 1 (byte {len(kept)}), but log/head says it ended at seq 2 "
            f"(byte {len(b''.join(lines))}): its tail was cut",
            None,
        )
    ]
    half = kept + lines[2][:10]
    store.log_path.write_bytes(half)
    problems = log_problems(store)
    assert problems[-1] == (
        f"the log ends at seq ? (byte {len(half)}), but log/head says it ended at seq 2 "
        f"(byte {len(b''.join(lines))}): its tail was cut",
        None,
    )


@pytest.mark.parametrize("events", [1, 3])
def test_a_last_line_edited_to_another_length_is_named_by_where_it_starts(store, events):
    """auditlog._head_problems 34 (the first line starts at byte 0: a one-line log), 45 (the line
    number counts from 1), 65, 67 (the problem carries its line)."""
    lines = three_events(store) if events == 3 else None
    if lines is None:
        append_event(store, "custom", note="event 0")
        lines = store.log_path.read_bytes().splitlines(keepends=True)
    longer = lines[-1].replace(b'"note":"event', b'"note":"the event')
    assert longer != lines[-1]
    store.log_path.write_bytes(b"".join(lines[:-1]) + longer)
    seq = events - 1
    assert log_problems(store) == [
        (f"log line {events} (seq {seq}) is not the line log/head recorded: it was edited", events)
    ]


def test_an_edit_of_the_same_length_names_the_line_and_its_seq(store):
    """auditlog._head_problems 68-70 (the edited event's seq), 65, 67 (its line)."""
    lines = three_events(store)
    edited = lines[2].replace(b"event 2", b"event 9")
    store.log_path.write_bytes(b"".join(lines[:2]) + edited)
    assert log_problems(store) == [("log line 3 (seq 2) is not the line log/head recorded: it was edited", 3)]


def test_a_log_whose_lines_all_moved_was_rewritten(store):
    """auditlog._head_problems 49: no line starts or ends where log/head says the last one did."""
    lines = three_events(store)
    first = lines[0].replace(b'"note":"event', b'"note":"an event')
    store.log_path.write_bytes(first + b"".join(lines[1:]))
    problems = log_problems(store)
    end = len(b"".join(lines))
    assert (f"no log line ends at byte {end}, where log/head says seq 2 ends: the log was rewritten", None) in problems


def test_a_cut_off_log_whose_events_hold_spaces_is_split_at_newlines_only(store):
    """auditlog._read_lines 23: a log whose last write was cut off is still split at newlines, not at
    every space."""
    for n in range(2):
        append_event(store, "custom", note=f"a note with spaces {n}")
    data = store.log_path.read_bytes()
    store.log_path.write_bytes(data + b'{"seq":2,"note":"half ')
    assert log_problems(store) == [("log line 3: incomplete (a write was cut off)", 3)]


def test_an_unreadable_log_is_one_line_naming_it_and_why(store):
    """auditlog._read_lines 12, 13."""
    from artifacts.auditlog import check_log

    store.log_path.parent.mkdir(exist_ok=True)
    store.log_path.mkdir()
    with pytest.raises(StoreError) as exc:
        check_log(store)
    assert str(exc.value) == f"cannot read the audit log: {store.log_path}: Is a directory"


def test_the_log_on_its_own_does_not_call_a_new_store_without_a_log_damaged(store):
    """auditlog.check_log 1 (has_history defaults to True): a store that never wrote an event has no log
    and no head, and check_chain, which sees no refs or records, finds nothing wrong."""
    from artifacts.auditlog import check_chain

    assert not store.log_path.exists()
    assert check_chain(store) == (0, [])


def test_a_garbled_line_inside_the_log_is_not_json_and_breaks_the_chain_after_it(store):
    """auditlog.check_log 21 (every damaged line called cut off), 26-28 (the words), 40, 42 (the broken
    chain's line), 43-47 (its seq and words)."""
    lines = three_events(store)
    store.log_path.write_bytes(lines[0] + b"garbage\n" + lines[2])
    kept, end = len(lines[0] + b"garbage\n" + lines[2]), len(b"".join(lines))
    assert log_problems(store) == [
        ("log line 2: not valid JSON", 2),
        ("log line 3 (seq 2): hash chain broken — a line before it was changed or removed", 3),
        (
            f"the log ends at seq 2 (byte {kept}), but log/head says it ended at seq 2 (byte {end}): its tail was cut",
            None,
        ),
    ]


def test_a_whole_last_line_that_is_not_json_was_not_cut_off(store):
    """auditlog.check_log 24: only a last line without its newline is a cut-off write."""
    lines = three_events(store)
    store.log_path.write_bytes(b"".join(lines) + b"garbage\n")
    assert log_problems(store) == [("log line 4: not valid JSON", 4)]


def test_a_removed_line_breaks_the_chain_and_puts_the_next_seq_out_of_order(store):
    """auditlog.check_log 55, 56, 58-61 (the out-of-order line: its seq, its words, its line)."""
    lines = three_events(store)
    store.log_path.write_bytes(lines[0] + lines[2])
    kept = len(lines[0] + lines[2])
    assert log_problems(store) == [
        ("log line 2 (seq 2): hash chain broken — a line before it was changed or removed", 2),
        ("log line 2: seq 2 out of order", 2),
        (
            f"the log ends at seq 2 (byte {kept}), but log/head says it ended at seq 2 "
            f"(byte {len(b''.join(lines))}): its tail was cut",
            None,
        ),
    ]


def test_each_repair_in_the_log_is_summarised_by_its_seq_time_and_first_three_problems(store):
    """auditlog.check_log 95-99 (the problems it names, "?" when it names none), 101-108 (its seq and time, to
    the second), 110-115 (three problems at most, joined by "; ", "…" only when there were more)."""
    from artifacts.auditlog import check_log

    four = append_event(store, "log-repaired", problems=["a", "b", "c", "d"])
    three = append_event(store, "log-repaired", problems=["a", "b", "c"])
    none = append_event(store, "log-repaired")
    assert len(four["ts"]) > 19
    assert check_log(store).sealed == [
        f"log-repaired at seq 0 ({four['ts'][:19]}) sealed 4 problem(s): a; b; c…",
        f"log-repaired at seq 1 ({three['ts'][:19]}) sealed 3 problem(s): a; b; c",
        f"log-repaired at seq 2 ({none['ts'][:19]}) sealed 1 problem(s): ?",
    ]


def test_every_repair_keeps_the_anchors_it_sealed_when_a_later_one_seals_others(store):
    """auditlog.check_log 88 (each repair's sealed anchors replaced those of the repairs before it)."""
    from artifacts.auditlog import check_log

    lost_a, lost_b = ("record a", {"seq": 5, "hash": "a" * 64}), ("record b", {"seq": 6, "hash": "b" * 64})
    append_event(store, "log-repaired", problems=["record a …"], sealed_anchors=[[5, "a" * 64]])
    assert [p.anchor for p in check_log(store, [lost_a, lost_b]).problems] == [(6, "b" * 64)]
    append_event(store, "log-repaired", problems=["record b …"], sealed_anchors=[[6, "b" * 64]])
    assert check_log(store, [lost_a, lost_b]).problems == []


def test_a_line_whose_log_format_is_not_a_number_counts_as_the_first_format(store):
    """auditlog.check_log 68 (a log_format that is no integer compared with one: a TypeError): a hand-edited
    format is read as 1, a log from before log/head existed, so a missing head is not a problem."""
    from artifacts.auditlog import head_path

    append_event(store, "custom", note="event 0")
    edited = store.log_path.read_bytes().replace(b'"log_format":2', b'"log_format":"2"')
    store.log_path.write_bytes(edited)
    head_path(store).unlink()
    assert log_problems(store) == []


def test_a_damaged_head_is_one_problem_naming_it(store):
    """auditlog.check_log 123-126 (the head's error lost, or a traceback)."""
    from artifacts.auditlog import head_path

    three_events(store)
    head_path(store).write_text("not a head")
    assert log_problems(store) == [(f"{head_path(store)} is damaged (not a log head); {REPAIR_HINT}", None)]


def test_a_lost_head_beside_a_log_that_had_one_is_named(store):
    """auditlog.check_log 142."""
    from artifacts.auditlog import head_path

    three_events(store)
    head_path(store).unlink()
    assert log_problems(store) == [("log/head is missing (it was deleted; the log's tail cannot be trusted)", None)]


def test_an_anchor_just_past_the_log_is_not_held_and_a_malformed_one_anchors_nothing(store):
    """auditlog.check_log 169, 171-173 (seq == the number of lines is past the end: "does not hold it", not an
    IndexError), 158 (a seq that is text or negative anchors nothing, and is no TypeError)."""
    from artifacts.auditlog import check_log

    three_events(store)
    past = ("record p", {"seq": 3, "hash": "c" * 64})
    odd = [("record t", {"seq": "1", "hash": "c" * 64}), ("record n", {"seq": -1, "hash": "c" * 64})]
    assert [p.text for p in check_log(store, [past, *odd]).problems] == [
        "record p was written after log event seq 3, but the log does not hold it: it was cut or rewritten"
    ]


# ----------------------------------------------------------------------------- auditlog: the next append's tail
def damaged(reason: str, store: Store) -> str:
    return f"audit log {store.log_path}: {reason}; nothing was written ({REPAIR_HINT})"


def spaced_events(store: Store, count: int) -> list[bytes]:
    """`count` events whose notes hold spaces (a split at whitespace breaks them); the log's lines, each with
    its newline."""
    for n in range(count):
        append_event(store, "custom", note=f"a note with spaces {n}")
    return store.log_path.read_bytes().splitlines(keepends=True)


def anchor_head_at(store: Store, lines: list[bytes], seq: int) -> None:
    """log/head as an append of line `seq` left it, so the lines after it are unanchored (a crash between
    a line and its head)."""
    from artifacts.auditlog import head_path
    from artifacts.hashing import canonical_json

    start = len(b"".join(lines[:seq]))
    head = {"seq": seq, "hash": hash_bytes(lines[seq][:-1]), "start": start, "end": start + len(lines[seq])}
    head_path(store).unlink()
    head_path(store).write_bytes(canonical_json(head) + b"\n")


def refused(store: Store, reason: str) -> None:
    """The next append (and the check before one) are refused in one line naming `reason`; the log is left."""
    from artifacts.auditlog import _tail, ensure_appendable

    before = store.log_path.read_bytes() if store.log_path.exists() else None
    for attempt in (lambda: _tail(store), lambda: ensure_appendable(store), lambda: append_event(store, "x")):
        with pytest.raises(StoreError) as exc:
            attempt()
        assert str(exc.value) == damaged(reason, store)
    assert (store.log_path.read_bytes() if store.log_path.exists() else None) == before


def test_the_first_append_starts_the_chain_whether_the_log_is_missing_or_empty(store):
    """auditlog._tail 3-5 (a missing log's size), 13, 14 (seq 0, size 0), 6, 7 (the empty-log branch)."""
    from artifacts.auditlog import GENESIS, _tail

    assert not store.log_path.exists()
    assert _tail(store) == (0, GENESIS, 0)
    store.log_path.parent.mkdir(exist_ok=True)
    store.log_path.write_bytes(b"")
    assert _tail(store) == (0, GENESIS, 0)
    assert append_event(store, "custom")["seq"] == 0


def test_an_empty_log_beside_a_head_is_refused_naming_the_heads_seq(store):
    """auditlog._tail 1, 2, 8-12 (the head not read, or the words lost)."""
    spaced_events(store, 3)
    store.log_path.write_bytes(b"")
    refused(store, "the log is missing or empty, but log/head says it ended at seq 2")
    store.log_path.unlink()
    refused(store, "the log is missing or empty, but log/head says it ended at seq 2")


def test_the_tail_of_a_log_with_its_head_is_the_anchored_lines(store):
    """auditlog._tail 58-68, 71-74, 78-83, 85-89, 94 (the anchored line read and checked), 134, 135 (the next
    seq)."""
    from artifacts.auditlog import _tail

    lines = spaced_events(store, 3)
    size = len(b"".join(lines))
    assert _tail(store) == (3, hash_bytes(lines[2][:-1]), size)


@pytest.mark.parametrize("anchored", [0, 1, 2])
def test_lines_a_crash_left_after_the_head_are_chained_on(store, anchored):
    """auditlog._tail 69, 70 (the anchored line's span when it does not start the log), 105-112 (the
    unanchored lines: read, split at newlines only, parsed), 116-125 (each checked), 130-133 (the chain
    walked), 134, 135."""
    from artifacts.auditlog import _tail

    lines = spaced_events(store, 4)
    anchor_head_at(store, lines, anchored)
    assert _tail(store) == (4, hash_bytes(lines[3][:-1]), len(b"".join(lines)))
    assert append_event(store, "custom")["seq"] == 4


def test_a_log_shorter_than_its_head_says_names_both_lengths(store):
    """auditlog._tail 53 (a log exactly as long as the head says is whole), 54-57 (the words)."""
    lines = spaced_events(store, 3)
    cut = b"".join(lines)[:-5]
    store.log_path.write_bytes(cut)
    refused(
        store,
        f"it is {len(cut)} bytes long, but log/head says its seq 2 ends at byte {len(b''.join(lines))}: "
        "its tail was cut",
    )


@pytest.mark.parametrize("how", ["same-length-edit", "seq-in-the-head", "head-inside-the-line"])
def test_an_anchored_line_that_is_not_the_one_the_head_recorded_is_refused(store, how):
    """auditlog._tail 75-77 (each disagreement alone is enough), 84, 89, 90-93 (the words)."""
    from artifacts.auditlog import head_path
    from artifacts.hashing import canonical_json

    lines = spaced_events(store, 3)
    head = json.loads(head_path(store).read_bytes())
    if how == "same-length-edit":
        store.log_path.write_bytes(b"".join(lines[:2]) + lines[2].replace(b"spaces 2", b"spaces 9"))
    else:
        # the hash matches the line, but the head names another seq / ends the line one byte early
        head |= {"seq": 7} if how == "seq-in-the-head" else {"end": head["end"] - 1}
        head_path(store).unlink()
        head_path(store).write_bytes(canonical_json(head) + b"\n")
    seq = 7 if how == "seq-in-the-head" else 2
    refused(store, f"its line of seq {seq} is not the one log/head recorded: it was edited")


def test_a_half_written_line_after_the_head_is_refused(store):
    """auditlog._tail 95-104."""
    lines = spaced_events(store, 2)
    store.log_path.write_bytes(b"".join(lines) + b'{"seq":2,"note":"half')
    refused(store, "its last line is incomplete")


@pytest.mark.parametrize("how", ["not-json", "a-json-list", "wrong-prev", "wrong-seq"])
def test_an_unanchored_line_that_does_not_chain_on_is_refused_naming_the_seq_before_it(store, how):
    """auditlog._tail 111-129; _parse 3, 4 (a JSON value that is not an object is no event)."""
    lines = spaced_events(store, 4)
    anchor_head_at(store, lines, 1)
    event = json.loads(lines[2])
    bad = {
        "not-json": b"not an event",
        "a-json-list": b"[1, 2]",
        "wrong-prev": json.dumps(event | {"prev": "e" * 64}).encode(),
        "wrong-seq": json.dumps(event | {"seq": 3}).encode(),
    }[how]
    store.log_path.write_bytes(b"".join(lines[:2]) + bad + b"\n" + lines[3])
    refused(store, "the line after seq 1 is damaged")


def test_an_old_log_without_a_head_continues_from_its_last_line(store):
    """auditlog._tail 15-22 (the old log's last line read), 40 (an event without log_format is format 1),
    48-52 (the next seq and prev)."""
    from artifacts.auditlog import _tail

    last = write_old_log(store, [{"note": "a first event"}, {"note": "the last event"}])
    assert _tail(store) == (2, hash_bytes(last), store.log_path.stat().st_size)


@pytest.mark.parametrize("log_format", [2, 3])
def test_a_log_of_the_head_format_without_its_head_is_refused(store, log_format):
    """auditlog._tail 34-39, 41 (format 2 and later need log/head), 42-47 (the words)."""
    write_old_log(store, [{"note": "one"}, {"note": "two", "log_format": log_format}])
    refused(store, "log/head is missing")


@pytest.mark.parametrize(
    "last",
    [b"garbage", b"[1, 2]", b'{"seq": "1", "note": "seq as text"}', b""],
    ids=["not-json", "a-json-list", "text-seq", "empty"],
)
def test_an_old_log_whose_last_line_is_no_event_is_refused(store, last):
    """auditlog._tail 23-33; _parse 3, 4: a last line that is not JSON, not an object, has no integer seq,
    or is empty."""
    write_old_log(store, [{"note": "one"}])
    store.log_path.write_bytes(store.log_path.read_bytes() + last + b"\n")
    refused(store, "its last line is damaged")


def test_an_append_writes_its_line_and_then_a_head_that_anchors_it(store):
    """auditlog.append_event 4-42 (the record's fields, its line, the head's seq, hash and byte span),
    _write_head 1-16 (log/head's exact bytes), head_path 1-3, read_head 8-28 (the head read back),
    _append_line 4, 7, 10 (the log's mode)."""
    from artifacts.auditlog import LOG_FORMAT, Head, head_path, read_head
    from artifacts.hashing import canonical_json

    first = append_event(store, "custom", note="one")
    second = append_event(store, "other", note="two", count=2)
    lines = store.log_path.read_bytes().splitlines(keepends=True)
    assert [json.loads(line) for line in lines] == [first, second]
    assert set(second) == {"seq", "ts", "event", "pid", "host", "note", "count", "prev", "log_format"}
    assert (second["seq"], second["event"], second["pid"], second["host"]) == (
        1,
        "other",
        os.getpid(),
        socket.gethostname(),
    )
    assert (second["prev"], second["log_format"]) == (hash_bytes(lines[0][:-1]), LOG_FORMAT)
    assert lines[1] == canonical_json(second) + b"\n"
    start, end = len(lines[0]), len(lines[0]) + len(lines[1])
    head = {"seq": 1, "hash": hash_bytes(lines[1][:-1]), "start": start, "end": end}
    assert head_path(store) == store.log_path.parent / "head"
    assert head_path(store).read_bytes() == canonical_json(head) + b"\n"
    assert read_head(store) == Head(1, head["hash"], start, end)
    umask = os.umask(0)
    os.umask(umask)
    assert store.log_path.stat().st_mode & 0o777 == 0o644 & ~umask


def test_an_append_takes_the_stores_log_lock(store):
    """auditlog._log_lock 3-8, append_event 1: an append waits while another holds locks/log.lock."""
    done = threading.Event()
    with store_lock(store.locks_dir, "log"):
        worker = threading.Thread(target=lambda: (append_event(store, "custom"), done.set()))
        worker.start()
        assert not done.wait(0.5)
    worker.join(10)
    assert done.is_set()
    assert [e["event"] for e in iter_events(store)] == ["custom"]


def test_an_append_into_a_store_whose_log_folder_is_a_file_says_so_in_one_line(store):
    """auditlog._log_lock 1, 2 (the log's folder may exist already), 9, 10 (the words)."""
    append_event(store, "custom")
    append_event(store, "custom")  # the log folder exists now: still appendable
    shutil.rmtree(store.log_path.parent)
    store.log_path.parent.write_bytes(b"not a folder")
    with pytest.raises(StoreError) as exc:
        append_event(store, "custom")
    assert str(exc.value) == f"cannot write the audit log: {store.log_path.parent}: File exists"


def test_a_short_write_takes_back_its_partial_line_and_says_the_disk_is_full(store, monkeypatch):
    """auditlog._append_line 11-26 (the short write noticed and named), 28-31 (the partial line taken back),
    append_event 25, 43, 44 (the size it takes back to; the words)."""
    import artifacts.auditlog

    append_event(store, "custom", note="kept")
    before = store.log_path.read_bytes()
    real_write = os.write

    def short_write(fd, data):
        return real_write(fd, data[:10])

    monkeypatch.setattr(artifacts.auditlog.os, "write", short_write)
    with pytest.raises(StoreError) as exc:
        append_event(store, "custom", note="lost")
    monkeypatch.undo()
    assert str(exc.value) == (f"cannot write the audit log: {store.log_path}: No space left on device (short write)")
    assert store.log_path.read_bytes() == before
    assert append_event(store, "custom")["seq"] == 1


def test_a_log_that_cannot_be_read_is_not_appendable_in_one_line(store):
    """auditlog.ensure_appendable 1-4: an OSError reading the log (here: it is a folder) is one line."""
    from artifacts.auditlog import ensure_appendable

    store.log_path.parent.mkdir(exist_ok=True)
    store.log_path.mkdir()
    (store.log_path / "x").write_bytes(b"x" * 10)
    with pytest.raises(StoreError) as exc:
        ensure_appendable(store)
    assert str(exc.value) == f"cannot write the audit log: {store.log_path}: Is a directory"


def test_a_head_that_is_unreadable_or_damaged_is_named_in_one_line(store):
    """auditlog.read_head 1-7, 29, 40 (the words), 30-39 (each check alone refuses: the hash, the byte span
    with start == end or negative, a negative seq; seq 0 and start 0 are fine)."""
    from artifacts.auditlog import Head, head_path, read_head
    from artifacts.hashing import canonical_json

    assert read_head(store) is None
    append_event(store, "custom")
    good = json.loads(head_path(store).read_bytes())
    assert read_head(store) == Head(0, good["hash"], 0, good["end"])
    path = head_path(store)
    for change in ({"hash": "abc"}, {"start": 5, "end": 5}, {"start": -1}, {"seq": -1}, {"end": None}, {}):
        head = good | change if change else {"seq": 0}
        path.unlink()
        path.write_bytes(canonical_json(head) + b"\n")
        with pytest.raises(StoreError) as exc:
            read_head(store)
        assert str(exc.value) == f"{path} is damaged (not a log head); {REPAIR_HINT}", change
    path.unlink()
    path.mkdir()
    with pytest.raises(StoreError) as exc:
        read_head(store)
    assert str(exc.value) == f"cannot read the audit log's head: {path}: Is a directory"


# ----------------------------------------------------------------------------- hashing
def test_canonical_json_is_one_byte_form_sorted_compact_utf8_and_without_nan():
    """hashing.canonical_json 1-18."""
    from artifacts.hashing import canonical_json

    value = {"b": [1, 2.5, None, True], "a": {"é": "ü", "z": 0}}
    assert canonical_json(value) == '{"a":{"z":0,"é":"ü"},"b":[1,2.5,null,true]}'.encode()
    with pytest.raises(ValueError):
        canonical_json({"x": float("nan")})


@pytest.mark.parametrize("size", [0, 1000, CHUNK_SIZE + 5], ids=["empty", "small", "over-a-chunk"])
def test_a_files_id_and_size_are_its_blake3_and_length_read_in_chunks(tmp_path, size):
    """hashing.hash_file 1-23, hash_bytes; the file is opened without a warning (hash_file 9 asked for line
    buffering, which a binary file refuses with a RuntimeWarning on every hash)."""
    data = bytes(range(256)) * (size // 256) + b"x" * (size % 256)
    path = tmp_path / "f.bin"
    path.write_bytes(data)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert hash_file(path) == (blake3.blake3(data).hexdigest(), size)
    assert hash_bytes(data) == blake3.blake3(data).hexdigest()


@pytest.mark.parametrize("size", [0, 3000, CHUNK_SIZE + 3000], ids=["empty", "small", "over-a-chunk"])
def test_a_copy_under_the_pipeline_size_writes_every_byte_even_in_short_writes(tmp_path, monkeypatch, size):
    """hashing.copy_hashing 1-12 (below 32 MiB the serial copy), _copy_hashing_serial 1-16, _write_all 1-9 (a
    write that takes only part of a chunk is continued where it stopped)."""
    import io

    import artifacts.hashing

    data = os.urandom(size)
    real_write = os.write
    calls = []

    def short_write(fd, chunk):
        calls.append(len(chunk))
        return real_write(fd, bytes(chunk[:1000]))

    monkeypatch.setattr(artifacts.hashing.os, "write", short_write)
    out = tmp_path / "copy.bin"
    fd = os.open(out, os.O_WRONLY | os.O_CREAT, 0o644)
    try:
        got = copy_hashing(io.BytesIO(data), fd, size_hint=size)
    finally:
        os.close(fd)
    monkeypatch.undo()
    assert got == (blake3.blake3(data).hexdigest(), size)
    assert out.read_bytes() == data
    assert all(n <= CHUNK_SIZE for n in calls)


def test_large_inputs_are_hashed_on_all_cores_and_small_ones_on_one(monkeypatch):
    """hashing._hasher 1-6: from 4 MiB on, blake3 may use every core; below it threads cost more than they
    gain."""
    import artifacts.hashing

    asked = []
    real = blake3.blake3

    class Recording:
        AUTO = real.AUTO

        def __new__(cls, *args, max_threads=1, **kwargs):
            asked.append(max_threads)
            return real(*args, max_threads=max_threads, **kwargs)

    monkeypatch.setattr(artifacts.hashing.blake3, "blake3", Recording)
    artifacts.hashing._hasher(4 * 1024 * 1024 - 1)
    artifacts.hashing._hasher(4 * 1024 * 1024)
    artifacts.hashing._hasher()
    assert asked == [1, real.AUTO, 1]


def test_a_full_id_is_exactly_64_lowercase_hex_digits():
    """hashing.is_full_id 1-6 (5: a letter added to the digits allowed)."""
    from artifacts.hashing import is_full_id

    assert is_full_id("0123456789abcdef" * 4)
    for text in ("0123456789abcdef" * 4 + "0", ("0123456789abcdef" * 4)[:-1], "A" * 64, "X" * 64, "g" * 64, ""):
        assert not is_full_id(text)
