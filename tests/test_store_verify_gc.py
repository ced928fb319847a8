"""verify (quick/full, quarantine) and gc (roots, dry run, grace period, lock)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from rich.console import Console
from test_runner_support import count_invocation  # noqa: E402

from artifacts.errors import StoreError
from artifacts.gc import collect_garbage
from artifacts.hashing import hash_bytes
from artifacts.ingest import add_path
from artifacts.locks import store_lock
from artifacts.reachability import walk
from artifacts.records import list_attempts
from artifacts.refs import set_ref
from artifacts.store import Store
from artifacts.verify import verify_store
from stages.runner import Runner


def quiet_runner(store: Store) -> Runner:
    return Runner(store, console=Console(file=open(os.devnull, "w")))


@pytest.fixture
def populated(tmp_path: Path) -> Store:
    store = Store.init(tmp_path / "store")[0]
    src = tmp_path / "demos"
    src.mkdir()
    (src / "a.bin").write_bytes(os.urandom(3000))
    (src / "seed.txt").write_text("42")
    aid, _ = add_path(store, src, "demos")
    quiet_runner(store).run(count_invocation(n=6, every=2, inputs={"seed": aid}))
    return store


def flip_byte(path: Path, offset: int) -> None:
    os.chmod(path, 0o644)
    data = bytearray(path.read_bytes())
    data[offset % len(data)] ^= 0x40
    path.write_bytes(bytes(data))


def test_clean_store_verifies(populated):
    assert verify_store(populated).ok
    report = verify_store(populated, full=True)
    assert report.ok and report.objects_checked == len(list(populated.iter_object_ids()))


def test_flipped_byte_in_any_object_is_found_and_quarantined(populated, tmp_path):
    ids = list(populated.iter_object_ids())
    reachable = set(walk(populated).sizes)
    assert len(ids) > 8 and len(reachable) < len(ids)
    for n, oid in enumerate(ids):
        store = Store.init(tmp_path / f"copy{n}")[0]
        os.system(f"cp -a {populated.root}/. {store.root}/")
        flip_byte(store.object_path(oid), n * 7919)
        report = verify_store(store, full=True)
        assert not report.ok and report.quarantined == [oid], oid
        assert not store.has_object(oid)
        assert any(p.name.startswith(oid) for p in store.quarantine_dir.iterdir())
        again = verify_store(store, full=False)  # afterwards: missing, if anything still names it
        if oid in reachable:
            assert any("missing object " + oid[:12] in p for p in again.problems), again.problems
        else:
            assert again.ok


def test_quick_verify_reports_missing_and_wrong_size(populated):
    reachable = [o for o in populated.iter_object_ids()]
    victim = max(reachable, key=lambda o: populated.object_size(o))
    flip = populated.object_path(victim)
    os.chmod(flip, 0o644)
    with open(flip, "ab") as f:
        f.write(b"extra")
    report = verify_store(populated)
    assert not report.ok and any("has size" in p or "not a JSON" in p or "corrupt" in p for p in report.problems)
    flip.unlink()
    assert any("missing object" in p for p in verify_store(populated).problems)


def test_gc_keeps_roots_and_honours_dry_run_and_grace(populated, tmp_path):
    loose = populated.put_bytes(b"nobody refers to me")
    report = collect_garbage(populated, dry_run=True, grace_s=0)
    assert loose in [o for o, _ in report.removed] and populated.has_object(loose)
    young = collect_garbage(populated, dry_run=False, grace_s=3600)
    assert young.removed == [] and young.young >= 1 and populated.has_object(loose)
    done = collect_garbage(populated, dry_run=False, grace_s=0)
    assert loose in [o for o, _ in done.removed] and not populated.has_object(loose)
    # committed checkpoints were superseded by the record: collectable; everything else verifies
    assert verify_store(populated, full=True).ok
    again = Runner(populated, console=Console(file=open(os.devnull, "w")))
    # the committed result is still a cache hit after gc
    aid = list_attempts(populated)[0]["inputs"]["seed"]
    assert again.run(count_invocation(n=6, every=2, inputs={"seed": aid})).cached


def test_gc_keeps_checkpoints_of_interrupted_attempts(tmp_path):
    store = Store.init(tmp_path / "s")[0]

    class Stop(Exception):
        pass

    from stages.runner_types import StepDef, StepInvocation

    def body(ctx):
        d = ctx.scratch_dir("c")
        (d / "w.bin").write_bytes(b"weights")
        ctx.save_checkpoint(d, {"i": 1})
        raise Stop("crash")

    inv = StepInvocation(step=StepDef("train", "1", body), config={})
    with pytest.raises(Stop):
        quiet_runner(store).run(inv)
    ckpt = list_attempts(store)[0]["checkpoints"][0]["id"]
    collect_garbage(store, dry_run=False, grace_s=0)
    assert store.has_object(ckpt)
    assert verify_store(store, full=True).ok


def test_gc_refuses_while_another_gc_holds_the_lock(populated):
    lock = store_lock(populated.locks_dir, "gc")
    with lock:
        # filelock is re-entrant per object, so test with a second lock object on the same file
        with pytest.raises(StoreError, match="locked"):
            collect_garbage(populated)


def test_gc_refuses_to_delete_from_a_damaged_store(populated):
    some_ref_target = populated.put_json(
        {"type": "artifact", "layout": "file", "content": "ab" * 32, "size": 1, "inputs": {}}
    )
    set_ref(populated, "broken", some_ref_target)
    with pytest.raises(StoreError, match="gc refused"):
        collect_garbage(populated, dry_run=False, grace_s=0)


def test_gc_never_sweeps_a_live_writers_staging_area(populated):
    live = populated.new_tmp_dir("attempt-live")  # carries this (live) process's pid
    dead = populated.tmp_dir / "attempt-dead-999999999-abcd"
    dead.mkdir()
    stray = populated.refs_dir / ".tmp-999999999-00ff"  # a ref update cut off before its rename
    stray.write_text("x")
    report = collect_garbage(populated, dry_run=False, grace_s=0)
    assert live.exists() and not dead.exists() and not stray.exists()
    assert report.tmp_removed == [dead.name, "refs/.tmp-999999999-00ff"]


def test_damaged_attempt_record_is_a_verify_problem_not_a_crash(populated):
    victim = next(populated.records_dir.glob("*/0001.json"))
    victim.write_text("{not json")
    report = verify_store(populated)
    assert not report.ok and any("damaged attempt record" in p for p in report.problems)
    with pytest.raises(StoreError, match="gc refused"):
        collect_garbage(populated, dry_run=False, grace_s=0)


FULL = "ab" * 32
NOT_MANIFESTS = {
    "a list": [FULL],
    "an artifact without a layout": {"type": "artifact", "content": FULL, "size": 1},
    "a tree entry without a size": {"type": "tree", "entries": [{"path": "a", "id": FULL}]},
    "a tree entry whose size is text": {"type": "tree", "entries": [{"path": "a", "id": FULL, "size": "1"}]},
    "a step record naming a short id": {"type": "step-record", "inputs": {"seed": FULL[:12]}, "outputs": {}},
    "a step record whose outputs are a list": {"type": "step-record", "inputs": {}, "outputs": [FULL]},
    "an unknown type": {"type": "scrapbook", "inputs": {"x": FULL}},
}


@pytest.mark.parametrize("shape", sorted(NOT_MANIFESTS))
def test_a_ref_to_json_of_no_manifests_shape_is_one_verify_problem_and_gc_refuses(populated, shape):
    """Quick verify and gc walk by the rule push, pull and verify --remote use (artifacts/links.py):
    JSON that hashes fine but is shaped like no manifest is one problem naming the ref, never a
    traceback (KeyError, TypeError) or a walk into an id that is no id; the walk goes on past it (refs
    are walked last name first, so ref zzz's object is met before ref aaa's lost content)."""
    lost = hash_bytes(b"never stored")
    holder = populated.put_json({"type": "artifact", "layout": "file", "content": lost, "size": 12})
    set_ref(populated, "aaa", holder)
    before = walk(populated)
    odd = populated.put_json(NOT_MANIFESTS[shape])
    set_ref(populated, "zzz", odd)
    reach = walk(populated)
    first, *rest = reach.problems
    assert first.startswith(f"object {odd[:12]} ") and "ref zzz" in first and "manifest" in first, first
    assert rest == before.problems == [f"missing object {lost[:12]} (named by artifact {holder[:12]})"]
    assert set(reach.sizes) == set(before.sizes) | {odd}
    report = verify_store(populated)
    assert report.problems == reach.problems
    with pytest.raises(StoreError, match="gc refused"):
        collect_garbage(populated, dry_run=False, grace_s=0)


def test_walk_names_each_object_by_the_manifest_and_role_that_reach_it(populated):
    """The `named by` of a missing object says which manifest and in which role: an artifact's content
    (the manifest alone), a tree's path, a step record's input or output."""
    reach = walk(populated)
    data = [o for o, size in reach.sizes.items() if size is not None]
    grown = max(data, key=lambda o: reach.sizes[o])
    os.chmod(populated.object_path(grown), 0o644)
    with open(populated.object_path(grown), "ab") as f:
        f.write(b"!")
    [problem] = walk(populated).problems
    size = reach.sizes[grown]
    assert problem.startswith(f"object {grown[:12]} has size {size + 1}, expected {size} (named by tree "), problem
    for oid in data:
        populated.object_path(oid).unlink()
    problems = walk(populated).problems
    assert len(problems) == len(data)
    assert any(p.startswith("missing object ") and ("(named by tree " in p and ":seed.txt)" in p) for p in problems)
    record = next(a["record_id"] for a in list_attempts(populated) if a["state"] == "committed")
    for oid in [o for o in reach.sizes if o != record and reach.sizes[o] is None]:
        os.chmod(populated.object_path(oid), 0o644)
        populated.object_path(oid).unlink()
    roles = " ".join(walk(populated).problems)
    assert f"(named by step-record {record[:12]} input seed)" in roles
    assert f"(named by step-record {record[:12]} output " in roles


def test_a_step_record_naming_only_outputs_or_only_inputs_is_a_manifest_of_those():
    """links._named 66, 68, 77, 79 (a step record with no "inputs", or no "outputs", refused as no manifest):
    an attempt recorded before its inputs were known names only its outputs (its checkpoints), and one
    recorded before any output names only its inputs; gc, verify, push and pull follow either."""
    from artifacts.links import Link, links

    record, ckpt, config = (hash_bytes(b) for b in (b"record", b"checkpoint", b"config"))
    assert links(record, {"type": "step-record", "outputs": {"ckpt": ckpt}}) == [Link(ckpt, None, " output ckpt")]
    assert links(record, {"type": "step-record", "inputs": {"config": config}}) == [Link(config, None, " input config")]
    assert links(record, {"type": "step-record"}) == []
