"""Tests written to kill mutants of artifacts/ that survived mutmut's round-1 sweep of the store package
(docs/MUTATION.md, "The fourth sweep"). Each test's docstring names the mutmut ids it kills.

What they pin is what a user of the store relies on: the exact one-line messages (a mutant that swaps one
for `StoreError(None)` gives the user an empty line), file names a message tells the user to remove, the
modes of files the store publishes, and that an old audit log continues its hash chain from its real last
line however long that line is. Everything runs in a temporary directory, without a network.
"""

from __future__ import annotations

import contextlib
import os
import signal
from pathlib import Path

import pytest

from artifacts.auditlog import append_event, head_path
from artifacts.diff import METRICS_FILE_MAX, _seconds, describe
from artifacts.errors import QUOTE_LIMIT, StoreError, path_text
from artifacts.hashing import canonical_json, hash_bytes
from artifacts.ingest import add_path
from artifacts.manifests import content_objects, read_artifact, verify_artifact
from artifacts.remotes.backends import RefMoved
from artifacts.remotes.config import parse_url
from artifacts.remotes.directory import DirBackend
from artifacts.store import Store

KEY = "refs/team/handoff"


@contextlib.contextmanager
def within(seconds: float):
    """Fail (instead of hanging) when the block runs longer than `seconds`: some mutants loop forever."""

    def expire(_signum, _frame):
        raise TimeoutError(f"still running after {seconds} s")

    old = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


@pytest.fixture
def store(tmp_path: Path) -> Store:
    s, _ = Store.init(tmp_path / "store")
    yield s
    s.close()


# ----------------------------------------------------------------------------- errors.path_text
def test_a_file_name_in_a_message_is_readable_text_and_at_most_the_quote_limit():
    """path_text 2, 4–11 (bytes names decoded as UTF-8, undecodable bytes escaped), 18, 21, 22 (lone
    surrogates from os.fsdecode escaped, not an encode error), 25–32 (exactly QUOTE_LIMIT characters kept
    whole; longer names keep their last QUOTE_LIMIT − 1 characters behind one '…')."""
    assert path_text(b"runs/caf\xc3\xa9/x") == "runs/café/x"
    assert path_text(b"runs/caf\xe9/x") == "runs/caf\\xe9/x"
    assert path_text("runs/caf\udce9/x") == "runs/caf\\udce9/x"
    assert path_text(Path("a/b")) == "a/b"
    exact = "d/" + "x" * (QUOTE_LIMIT - 2)
    assert path_text(exact) == exact
    longer = "/" + "y" * QUOTE_LIMIT + "z" * (QUOTE_LIMIT - 1)
    shown = path_text(longer)
    assert shown == "…" + "z" * (QUOTE_LIMIT - 1)
    assert len(shown) == QUOTE_LIMIT


# ----------------------------------------------------------------------------- auditlog: an old log's tail
def write_old_log(store: Store, extras: list[dict]) -> bytes:
    """A log from before log/head existed (no log_format, no head file): one event per extra, chained.
    Returns the last line (without its newline)."""
    prev, raw, line = "0" * 64, [], b""
    for seq, extra in enumerate(extras):
        line = canonical_json(
            {"seq": seq, "ts": "2026-01-01T00:00:00.000+00:00", "event": "custom", **extra, "prev": prev}
        )
        raw.append(line + b"\n")
        prev = hash_bytes(line)
    store.log_path.write_bytes(b"".join(raw))
    head_path(store).unlink(missing_ok=True)
    return line


BIG = "b" * (100 * 1024)  # longer than the 64 KiB the tail reader starts with, shorter than twice that


@pytest.mark.parametrize(
    "extras",
    [
        pytest.param(
            [{"note": "first line"}, {"note": "second line"}, {"note": "a last line with spaces"}], id="short"
        ),
        pytest.param([{"note": "only line"}], id="one-line"),
        pytest.param([{"note": "short"}, {"note": BIG}], id="long-last-line"),
        pytest.param([{"note": BIG}], id="one-long-line"),
    ],
)
def test_an_old_log_continues_its_chain_from_its_real_last_line(store, extras):
    """auditlog._last_line 14, 33, 34, 37 (loop forever on a one-line log or a long last line), 23 (splits
    a line at its spaces), 31, 38 (return a cut or no line when the last one is over 64 KiB), 35 (the
    second line instead of the last)."""
    last = write_old_log(store, extras)
    with within(20):
        event = append_event(store, "custom", note="next")
    assert event["seq"] == len(extras)
    assert event["prev"] == hash_bytes(last)


def test_an_old_log_whose_last_line_has_no_newline_is_refused(store):
    """auditlog._last_line 22: a last line without its newline is not a finished line, even when the
    bytes before the newline's place happen to parse (here a trailing space)."""
    write_old_log(store, [{"note": "one"}, {"note": "two"}])
    store.log_path.write_bytes(store.log_path.read_bytes()[:-1] + b" ")
    before = store.log_path.read_bytes()
    with pytest.raises(StoreError, match="its last line is damaged; nothing was written"):
        append_event(store, "custom", note="next")
    assert store.log_path.read_bytes() == before


# ----------------------------------------------------------------------------- remotes.directory
def dir_backend(path: Path) -> DirBackend:
    return DirBackend(parse_url("nas", str(path)))


def test_a_directory_remote_names_itself_in_every_refusal(tmp_path):
    """DirBackend.__init__ 1 (the spec dropped: describe() fails), probe 1, 2 (a missing directory without
    create: the exact line; an existing one is fine), _ensure_root 3 (a missing parent), 6 (a root that
    cannot be made), get_bytes 2 (an unreadable key)."""
    missing = tmp_path / "disk" / "remote"
    b = dir_backend(missing)
    with pytest.raises(StoreError) as exc:
        b.probe(create=False)
    assert str(exc.value) == f"remote nas ({missing}): the directory does not exist (is the disk mounted?)"
    with pytest.raises(StoreError) as exc:
        b.probe(create=True)
    assert str(exc.value) == f"remote nas ({missing}): {missing.parent} does not exist (is the disk mounted?)"
    missing.parent.write_text("a file where the remote's parent should be a directory")
    with pytest.raises(StoreError) as exc:
        b.probe(create=True)
    assert str(exc.value) == f"remote nas ({missing}): {missing.parent} does not exist (is the disk mounted?)"
    missing.parent.unlink()
    missing.parent.mkdir()
    missing.write_text("a file where the remote should be")
    with pytest.raises(StoreError) as exc:
        b.probe(create=True)
    assert str(exc.value) == f"remote nas ({missing}): cannot create {missing}: File exists"
    missing.unlink()
    b.probe(create=True)
    assert missing.is_dir()
    b.probe(create=False)
    (missing / "refs" / "team" / "handoff").mkdir(parents=True)
    with pytest.raises(StoreError) as exc:
        b.get_bytes(KEY)
    assert str(exc.value) == f"remote nas ({missing}): cannot read {KEY}: Is a directory"


def test_probe_with_create_makes_a_missing_remote_directory(tmp_path):
    """DirBackend._ensure_root 1: the remote's directory is created when its parent exists."""
    b = dir_backend(tmp_path / "remote")
    b.probe(create=True)
    assert (tmp_path / "remote").is_dir()
    assert b.swap(KEY, b"one\n", None) == "one\n"
    assert (tmp_path / "remote" / KEY).read_bytes() == b"one\n"


def test_a_remote_directory_another_push_creates_meanwhile_is_not_an_error(tmp_path):
    """DirBackend._ensure_root 4, 5 (mkdir without exist_ok): two pushes to a new remote both see it
    missing and both create it; the second must not fail."""

    class LooksMissingOnce(type(Path())):
        """The root's first is_dir() says False, as if asked just before the other push made it."""

        asked = False

        def is_dir(self, *args, **kwargs):
            if self.name == "remote" and not LooksMissingOnce.asked:
                LooksMissingOnce.asked = True
                return False
            return super().is_dir(*args, **kwargs)

    root = tmp_path / "remote"
    root.mkdir()  # the other push won the race, but this one already looked
    b = dir_backend(root)
    b.root = LooksMissingOnce(root)
    b.probe(create=True)
    assert LooksMissingOnce.asked and root.is_dir()


def test_a_ref_written_to_a_directory_remote_is_an_ordinary_readable_file(tmp_path):
    """DirBackend._take_lock 23, 26: the lock file becomes the ref, so its mode is the ref's: 0644."""
    b = dir_backend(tmp_path / "remote")
    b.probe(create=True)
    old = os.umask(0o022)
    try:
        b.swap(KEY, b"one\n", None)
    finally:
        os.umask(old)
    assert (tmp_path / "remote" / KEY).stat().st_mode & 0o777 == 0o644
    assert not (tmp_path / "remote" / "locks" / (KEY + ".lock")).exists()


def test_a_ref_read_back_from_a_directory_remote_tolerates_bytes_that_are_not_utf8(tmp_path):
    """DirBackend.read_versioned 7, 8: the version of a ref holding invalid UTF-8 is its text with
    replacement characters, not a decode error."""
    b = dir_backend(tmp_path / "remote")
    b.probe(create=True)
    (tmp_path / "remote" / "refs" / "team").mkdir(parents=True)
    (tmp_path / "remote" / KEY).write_bytes(b"\xff\xfeid\n")
    assert b.read_versioned(KEY) == (b"\xff\xfeid\n", "\ufffd\ufffdid\n")


def test_a_swap_that_finds_the_ref_moved_names_the_key(tmp_path):
    """DirBackend._swap 17: RefMoved carries the key (the caller's retry names it)."""
    b = dir_backend(tmp_path / "remote")
    b.probe(create=True)
    b.swap(KEY, b"one\n", None)
    with pytest.raises(RefMoved) as exc:
        b.swap(KEY, b"two\n", None)
    assert exc.value.args == (KEY,)


def test_a_swap_that_cannot_write_names_the_remote_key_and_reason(tmp_path):
    """DirBackend.swap 7, 8: the OSError's reason (its strerror), not its repr, after the remote and key."""
    root = tmp_path / "remote"
    b = dir_backend(root)
    b.probe(create=True)
    (root / "refs").mkdir()
    (root / "refs" / "team").write_text("a file where a directory of refs should be")
    with pytest.raises(StoreError) as exc:
        b.swap(KEY, b"one\n", None)
    assert str(exc.value) == f"remote nas ({root}): cannot write {KEY}: File exists"


def hold_lock(root: Path, key: str) -> Path:
    lock = root / "locks" / (key + ".lock")
    lock.parent.mkdir(parents=True, exist_ok=True)
    lock.write_bytes(b"")
    return lock


def test_a_push_waits_for_the_ref_lock_and_proceeds_once_it_is_released(tmp_path, monkeypatch):
    """DirBackend._take_lock 15, 16 (no deadline, or one already past: refused at once), 31, 32 (the poll
    interval: short, a number), 4, 5, 7, 8 (the lock's file name: another push's lock must be seen)."""
    root = tmp_path / "remote"
    b = dir_backend(root)
    b.probe(create=True)
    lock = hold_lock(root, KEY)
    naps: list[float] = []

    def nap(seconds):
        naps.append(seconds)
        if len(naps) == 3:
            lock.unlink()  # the other push finishes

    monkeypatch.setattr("artifacts.remotes.directory.time.sleep", nap)
    assert b.swap(KEY, b"mine\n", None) == "mine\n"
    assert len(naps) == 3 and all(0 < s <= 0.1 for s in naps)
    assert (root / KEY).read_bytes() == b"mine\n"


def test_a_ref_lock_held_past_the_wait_is_one_line_naming_the_file_to_remove(tmp_path, monkeypatch):
    """DirBackend._take_lock 28–30 (the message), 4, 5, 7, 8 (the lock file it names)."""
    root = tmp_path / "remote"
    b = dir_backend(root)
    b.probe(create=True)
    lock = hold_lock(root, KEY)
    monkeypatch.setattr("artifacts.remotes.directory.time.sleep", lambda _s: None)
    b.LOCK_WAIT_S = 0.0
    with pytest.raises(StoreError) as exc:
        b.swap(KEY, b"mine\n", None)
    assert str(exc.value) == (
        f"remote nas ({root}): {KEY} is locked by another push ({lock}); remove that file if no push is running"
    )
    assert lock.exists() and not (root / KEY).exists()


# ----------------------------------------------------------------------------- manifests.verify_artifact
def _one_file_artifact(store: Store, tmp_path: Path) -> tuple[str, str]:
    src = tmp_path / "demos"
    src.mkdir()
    (src / "a.bin").write_bytes(b"x" * 1000)
    aid, _ = add_path(store, src, "demos")
    [(oid, _, _)] = content_objects(store, read_artifact(store, aid))
    path = store.object_path(oid)
    os.chmod(path, 0o644)
    os.chmod(path.parent, 0o755)
    return aid, oid


def _refusal(store: Store, aid: str, **kwargs) -> str:
    with pytest.raises(StoreError) as exc:
        verify_artifact(store, aid, **kwargs)
    return str(exc.value)


def test_an_artifact_whose_object_is_gone_names_artifact_object_and_file(store, tmp_path):
    """verify_artifact 17, 18 (the artifact's and the object's 12-character ids in the message)."""
    aid, oid = _one_file_artifact(store, tmp_path)
    store.object_path(oid).unlink()
    assert _refusal(store, aid) == f"artifact {aid[:12]}: object {oid[:12]} (a.bin) is missing"


def test_a_damaged_object_is_named_corrupt_or_by_its_size_and_quarantined_on_request(store, tmp_path):
    """verify_artifact 26–29 (quarantine moves the damaged object aside instead of crashing), 32, 33
    (same size: 'is corrupt'; another size: both sizes), 37, 38 (the 12-character ids)."""
    aid, oid = _one_file_artifact(store, tmp_path)
    path = store.object_path(oid)
    path.write_bytes(b"y" * 1000)
    assert _refusal(store, aid) == f"artifact {aid[:12]}: object {oid[:12]} (a.bin) is corrupt"
    assert _refusal(store, aid, quarantine=True) == f"artifact {aid[:12]}: object {oid[:12]} (a.bin) is corrupt"
    assert not store.has_object(oid)
    assert [p.name.split(".")[0] for p in store.quarantine_dir.iterdir()] == [oid]
    path.write_bytes(b"x" * 1001)
    expected = f"artifact {aid[:12]}: object {oid[:12]} (a.bin) has size 1001, expected 1000"
    assert _refusal(store, aid, full=False) == expected


# ----------------------------------------------------------------------------- diff._seconds
def test_a_step_duration_in_diff_is_end_minus_start_in_seconds_to_the_millisecond():
    """diff._seconds 1–8 (end − start, not a sum, not None, rounded to 3 decimals, not to an integer);
    a missing timestamp is no duration rather than an error."""
    start, end = "2026-01-01T00:00:00.000+00:00", "2026-01-01T00:00:01.234567+00:00"
    assert _seconds(start, end) == 1.235
    assert _seconds(start, "2026-01-01T00:00:02.500+00:00") == 2.5
    assert _seconds(start, None) is None
    assert _seconds("not a time", end) is None


# ----------------------------------------------------------------------------- diff.describe
STEP_RECORD = {
    "type": "step-record",
    "step": "train",
    "code_version": "c0ffee",
    "host": "lab-1",
    "started": "2026-01-01T00:00:00.000+00:00",
    "finished": "2026-01-01T00:01:30.250+00:00",
    "config": {"lr": 0.001},
    "inputs": {},
    "outputs": {},
}


def test_diff_describes_a_step_record_by_step_code_host_and_duration(store):
    """diff.describe 18–30, 33–38 (the step record's step, code_version, host and duration_s fields, read
    from their own keys), 51, 52, 57–64, 69–74 (its inputs and outputs flattened under input. / output.)."""
    out = store.put_json({"type": "note"})  # an output that is no artifact: no metrics
    record = {**STEP_RECORD, "inputs": {"demos": "d" * 64}, "outputs": {"model": out}}
    fields, metrics = describe(store, store.put_json(record))
    assert fields == {
        "step": "train",
        "code_version": "c0ffee",
        "host": "lab-1",
        "duration_s": 90.25,
        "config.lr": 0.001,
        "input.demos": "d" * 64,
        "output.model": out,
    }
    assert metrics == {}


def test_diff_refuses_a_data_object_over_the_metrics_limit_without_reading_it(store):
    """diff.describe 1, 4–6 (an object over METRICS_FILE_MAX bytes is named a data object; one of
    exactly METRICS_FILE_MAX bytes is still read)."""
    big = store.put_bytes(b"\0" * (METRICS_FILE_MAX + 1))
    with pytest.raises(StoreError) as exc:
        describe(store, big)
    assert str(exc.value) == f"{big[:12]} is a data object; diff compares step records, artifacts or runs"
    base = len(canonical_json({**STEP_RECORD, "pad": ""}))
    exact = store.put_json({**STEP_RECORD, "pad": "x" * (METRICS_FILE_MAX - base)})
    assert store.object_size(exact) == METRICS_FILE_MAX
    assert describe(store, exact)[0]["step"] == "train"
