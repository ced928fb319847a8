"""Tests written to kill mutants of artifacts/ that survived mutmut's round-1 sweep of the store package
(docs/MUTATION.md, "The fourth sweep"). Each test's docstring names the mutmut ids it kills.

What they pin is what a user of the store relies on: the exact one-line messages (a mutant that swaps one
for `StoreError(None)` gives the user an empty line), file names a message tells the user to remove, the
modes of files the store publishes, and that an old audit log continues its hash chain from its real last
line however long that line is. Everything runs in a temporary directory, without a network.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import sys
from pathlib import Path

import pytest

from artifacts.auditlog import append_event
from artifacts.diff import METRICS_FILE_MAX, METRICS_PER_OUTPUT, _seconds, describe, diff
from artifacts.errors import QUOTE_LIMIT, StoreError, path_text
from artifacts.hashing import canonical_json, hash_bytes
from artifacts.ingest import add_path
from artifacts.manifests import content_objects, read_artifact, store_content, verify_artifact, write_manifest
from artifacts.refs import set_ref
from artifacts.remotes.backends import RefMoved
from artifacts.remotes.config import parse_url
from artifacts.remotes.directory import DirBackend
from artifacts.store import Store

sys.path.insert(0, str(Path(__file__).resolve().parent))
from auditlog_support import write_old_log  # noqa: E402

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


# ----------------------------------------------------------------------------- diff: artifacts and their metrics
def eval_artifact(store: Store, tmp_path: Path, files: dict[str, bytes], **drop: bool) -> str:
    """An eval artifact of `files` (one name: a file artifact; several: a directory), made as the store
    makes them; `drop` names manifest keys to leave out (a hand-made or older manifest)."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    if len(files) == 1:
        [(name, data)] = files.items()
        src = tmp_path / name
        src.write_bytes(data)
    else:
        src = tmp_path / "eval"
        for name, data in files.items():
            (src / name).parent.mkdir(parents=True, exist_ok=True)
            (src / name).write_bytes(data)
    content = store_content(store, src)
    aid = write_manifest(
        store,
        content,
        "eval",
        producer={"step": "evaluate"},
        inputs={"policy": "p" * 64},
        config={"episodes": 20},
        code_version="c0ffee",
    )
    manifest = store.read_json(aid)
    return store.put_json({k: v for k, v in manifest.items() if not drop.get(k)}) if drop else aid


def test_diff_describes_an_artifact_by_its_manifest_fields_and_its_json_metrics(store, tmp_path):
    """diff.describe 92–97 (kind, code_version, size, files), 100–105 (content), 106, 107, 112–117
    (producer.*), 119, 124–129 (config.*), 131, 136–141 (input.*), 145, 149, 151, 153, 154 (the
    metrics are labelled by the artifact's kind)."""
    aid = eval_artifact(store, tmp_path, {"scores.json": b'{"success": 0.75}', "video.bin": b"v" * 10})
    manifest = store.read_json(aid)
    fields, metrics = describe(store, aid)
    assert fields == {
        "kind": "eval",
        "code_version": "c0ffee",
        "size": manifest["size"],
        "files": 2,
        "content": manifest["content"],
        "producer.step": "evaluate",
        "config.episodes": 20,
        "input.policy": "p" * 64,
    }
    assert metrics == {"eval/scores.json:success": 0.75}


def test_diff_labels_the_metrics_of_a_manifest_without_a_kind_artifact(store, tmp_path):
    """diff.describe 150, 152, 155, 156 (the label when the manifest names no kind)."""
    aid = eval_artifact(store, tmp_path, {"scores.json": b'{"success": 0.75}', "x.bin": b"x"}, kind=True)
    fields, metrics = describe(store, aid)
    assert fields["kind"] is None
    assert metrics == {"artifact/scores.json:success": 0.75}


def test_diff_refuses_an_object_that_is_neither_step_record_nor_artifact_by_its_type(store):
    """diff.describe 157–161: the one-line refusal names the object's type, or 'data' without one."""
    tree = store.put_json({"type": "tree", "entries": []})
    with pytest.raises(StoreError) as exc:
        describe(store, tree)
    assert str(exc.value) == f"{tree[:12]} is a tree object; diff compares step records, artifacts or runs"
    untyped = store.put_json({"note": "no type"})
    with pytest.raises(StoreError) as exc:
        describe(store, untyped)
    assert str(exc.value) == f"{untyped[:12]} is a data object; diff compares step records, artifacts or runs"


def test_diff_reads_the_metrics_of_a_file_artifact_that_is_a_json_file(store, tmp_path):
    """diff._metrics 10–15 (a file artifact's JSON counts), 17, 19, 21, 22 (its name from the manifest),
    18, 20 (a manifest without a name: no metrics, not a crash), 28–30 (without a size: read), 27, 31,
    32, 63 (a JSON file over METRICS_FILE_MAX is not read), 68 (one of exactly that size is; 82, 83: its
    string field is no metric)."""
    small = b'{"success": 0.75}'
    assert describe(store, eval_artifact(store, tmp_path / "a", {"scores.json": small}))[1] == {
        "eval/scores.json:success": 0.75
    }
    assert describe(store, eval_artifact(store, tmp_path / "b", {"scores.json": small}, name=True))[1] == {}
    assert describe(store, eval_artifact(store, tmp_path / "c", {"scores.json": small}, size=True))[1] == {
        "eval/scores.json:success": 0.75
    }

    def padded(total: int) -> bytes:
        head = b'{"success": 0.5, "pad": "'
        return head + b"x" * (total - len(head) - 2) + b'"}'

    assert describe(store, eval_artifact(store, tmp_path / "d", {"big.json": padded(METRICS_FILE_MAX + 1)}))[1] == {}
    exact = eval_artifact(store, tmp_path / "e", {"edge.json": padded(METRICS_FILE_MAX)})
    assert describe(store, exact)[1] == {"eval/edge.json:success": 0.5}


def test_diff_metrics_are_the_numbers_in_a_directory_artifacts_top_level_json_files(store, tmp_path):
    """diff._metrics 58 (files in subdirectories do not count), 63, 69 (a non-JSON file is skipped and
    the rest still read), 73 (so is a JSON file that does not parse), 75 (a file that is one number:
    the metric is named by the file), 82, 83 (strings and booleans are not metrics)."""
    files = {
        "a.txt": b'{"x": 1}',
        "b.json": b"{not json",
        "c.json": b'{"loss": 0.5, "name": "run-3", "done": true, "nested": {"step": 3}}',
        "d.json": b"0.93",
        "sub/e.json": b'{"deep": 1}',
    }
    assert describe(store, eval_artifact(store, tmp_path, files))[1] == {
        "eval/c.json:loss": 0.5,
        "eval/c.json:nested.step": 3,
        "eval/d.json:": 0.93,
    }


def test_diff_keeps_at_most_metrics_per_output_numbers_of_one_artifact(store, tmp_path):
    """diff._metrics 85: exactly METRICS_PER_OUTPUT metrics, the first by name."""
    many = json.dumps({f"k{i:03d}": i for i in range(METRICS_PER_OUTPUT + 50)}).encode()
    metrics = describe(store, eval_artifact(store, tmp_path, {"many.json": many}))[1]
    assert metrics == {f"eval/many.json:k{i:03d}": i for i in range(METRICS_PER_OUTPUT)}


def test_diff_a_directory_artifact_whose_content_is_not_a_tree_has_no_metrics(store):
    """diff._metrics 53, 55: a damaged or foreign manifest (content without entries) gives no metrics
    rather than a traceback."""
    aid = store.put_json({"type": "artifact", "kind": "eval", "layout": "dir", "content": store.put_json({})})
    assert describe(store, aid)[1] == {}


# ----------------------------------------------------------------------------- diff: runs
def record(store: Store, config: dict, metrics: dict | None = None, **over) -> str:
    outputs = {}
    if metrics is not None:
        out = store.put_bytes(json.dumps(metrics).encode())
        manifest = {"type": "artifact", "kind": "checkpoint", "layout": "file", "name": "final.json"}
        outputs["model"] = store.put_json({**manifest, "content": out, "size": store.object_size(out)})
    return store.put_json({**STEP_RECORD, "config": config, "outputs": outputs, **over})


def two_runs(store: Store) -> dict[str, str]:
    """Runs exp/run-X (train, eval, and a ref to a data object listed first) and exp/run-Y (train,
    export); train's config and metrics differ."""
    refs = {
        "exp/run-X/aaa-notes": store.put_bytes(b"notes, not a step record"),
        "exp/run-X/train": record(store, {"lr": 0.001}, {"loss": 0.5}),
        "exp/run-X/eval": record(store, {}, step="eval"),
        "exp/run-Y/train": record(store, {"lr": 0.01, "batch": 64}, {"loss": 0.4, "accuracy": 0.9}),
        "exp/run-Y/export": record(store, {}, step="export"),
    }
    for name, oid in refs.items():
        set_ref(store, name, oid)
    return refs


def test_diff_of_two_runs_matches_steps_by_name_and_shows_one_sided_fields_and_metrics(store):
    """diff._run 7, 8 (a prefix given with its trailing slash), 9 (a prefix ending in X), 22 (a ref to
    something other than a step record is skipped, the rest still read); diff.diff 1 (same fields hidden
    by default), 3, 4 (A and B as given), 30 (steps only one side has); diff._compare 12, 23 (a field or
    metric only one side has)."""
    refs = two_runs(store)
    model = {side: store.read_json(refs[f"exp/run-{side}/train"])["outputs"]["model"] for side in "XY"}
    result = diff(store, "exp/run-X/", "exp/run-Y")
    assert (result.a, result.b) == ("exp/run-X/", "exp/run-Y")
    assert (result.only_a, result.only_b) == (["eval"], ["export"])
    assert result.fields == {
        "train config.batch": [None, 64],
        "train config.lr": [0.001, 0.01],
        "train output.model": [model["X"], model["Y"]],
    }
    assert result.metrics == {
        "train model/final.json:accuracy": [None, 0.9],
        "train model/final.json:loss": [0.5, 0.4],
    }


def test_diff_all_lists_the_fields_that_are_the_same_too(store):
    """diff.diff 38 (runs), 60 (two step records): --all shows equal fields as well."""
    two_runs(store)
    assert diff(store, "exp/run-X", "exp/run-Y", show_all=True).fields["train host"] == ["lab-1", "lab-1"]
    a, b = record(store, {"lr": 0.001}), record(store, {"lr": 0.01})
    assert "host" not in diff(store, a, b).fields
    assert diff(store, a, b, show_all=True).fields["host"] == ["lab-1", "lab-1"]


def test_diff_of_a_run_and_something_else_names_which_is_the_run(store):
    """diff.diff 49–51, 53, 54: the refusal names the run first, whichever side it is on."""
    two_runs(store)
    one = record(store, {"lr": 0.001})
    expected = f"'exp/run-X' is a run (a ref prefix) but '{one}' is not; compare like with like"
    for a, b in (("exp/run-X", one), (one, "exp/run-X")):
        with pytest.raises(StoreError) as exc:
            diff(store, a, b)
        assert str(exc.value) == expected


# ----------------------------------------------------------------------------- remotes.directory.list_aged
def test_a_directory_remotes_aged_listing_refuses_a_missing_directory(tmp_path):
    """DirBackend.list_aged 2: the exact line (prune and the tmp sweep call it)."""
    missing = tmp_path / "remote"
    with pytest.raises(StoreError) as exc:
        dir_backend(missing).list_aged("tmp")
    assert str(exc.value) == f"remote nas ({missing}): the directory does not exist (is the disk mounted?)"


def test_a_directory_remotes_aged_listing_skips_a_file_removed_while_listing(tmp_path):
    """DirBackend.list_aged 6: a file another prune removes between the walk and its stat is left out;
    the files after it are still listed, with their sizes and mtimes."""
    b = dir_backend(tmp_path / "remote")
    b.probe(create=True)
    for n in range(3):
        b.put_bytes(f"tmp/upload-{n}", b"x" * (n + 1))
    walk = b._walk
    gone: list[str] = []

    def walk_while_another_prune_runs(prefix):
        for key, path in walk(prefix):
            if not gone:
                path.unlink()
                gone.append(key)
            yield key, path

    b._walk = walk_while_another_prune_runs
    listed = b.list_aged("tmp")
    expected = {f"tmp/upload-{n}" for n in range(3)} - set(gone)
    assert set(listed) == expected and len(expected) == 2
    for key in expected:
        st = (tmp_path / "remote" / key).stat()
        assert listed[key] == (st.st_size, st.st_mtime)
