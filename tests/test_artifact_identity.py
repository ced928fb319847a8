"""An artifact's id is a function of its kind, content, inputs, config and code version (issue 23,
item 3): two stores at different paths, different attempts and different times give the same id;
time, host, attempt and an added file's source path are provenance (the audit log), which lineage
reads; format-1 manifests, which held them, are still read."""

from __future__ import annotations

from pathlib import Path

import pytest

from artifacts.auditlog import append_event
from artifacts.ingest import add_path
from artifacts.lineage import lineage
from artifacts.manifests import ARTIFACT_FORMAT, publish_artifact, read_artifact, store_content
from artifacts.provenance import provenance_index
from artifacts.refs import set_ref
from artifacts.store import Store
from artifacts.verify import verify_store


def tree(root: Path, files: dict[str, bytes]) -> Path:
    for rel, data in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(data)
    return root


def publish(store: Store, src: Path, attempt: int, **change) -> str:
    fields = {"kind": "checkpoint", "inputs": {"demos": "ab" * 32}, "config": {"seed": 3}, "code_version": "v1"}
    fields.update(change)
    return publish_artifact(
        store, src, producer={"step": "train", "cache_key": "cd" * 32, "attempt": attempt}, meta={"role": "x"}, **fields
    )


def test_two_stores_at_different_paths_give_the_same_id(tmp_path, monkeypatch):
    a = Store.init(tmp_path / "one" / "store")[0]
    b = Store.init(tmp_path / "elsewhere" / "deeper" / "store")[0]
    src_a = tree(tmp_path / "src-a", {"w.bin": b"weights", "sub/s.json": b"{}"})
    src_b = tree(tmp_path / "src-b", {"w.bin": b"weights", "sub/s.json": b"{}"})
    first = publish(a, src_a, attempt=1)
    monkeypatch.setattr("artifacts.manifests.now_iso", lambda: "2031-01-01T00:00:00+00:00")  # later
    second = publish(b, src_b, attempt=7)
    assert first == second
    manifest = read_artifact(b, second)
    assert manifest["format"] == ARTIFACT_FORMAT == 2 and "created" not in manifest
    assert manifest["producer"] == {"step": "train"}


@pytest.mark.parametrize(
    "change",
    [
        {"kind": "replay"},
        {"inputs": {"demos": "ef" * 32}},
        {"inputs": {"other-role": "ab" * 32}},
        {"config": {"seed": 4}},
        {"code_version": "v2"},
    ],
    ids=["kind", "input id", "input role", "config", "code version"],
)
def test_what_an_artifact_is_a_function_of_changes_its_id(tmp_path, change):
    store = Store.init(tmp_path / "store")[0]
    src = tree(tmp_path / "src", {"w.bin": b"weights"})
    assert publish(store, src, attempt=1) != publish(store, src, attempt=1, **change)


def test_other_content_changes_the_id(tmp_path):
    store = Store.init(tmp_path / "store")[0]
    one = publish(store, tree(tmp_path / "a", {"w.bin": b"weights"}), attempt=1)
    assert one != publish(store, tree(tmp_path / "b", {"w.bin": b"weightz"}), attempt=1)


def test_adding_the_same_data_from_two_paths_gives_one_id_and_lineage_keeps_the_source(tmp_path):
    a = Store.init(tmp_path / "a")[0]
    b = Store.init(tmp_path / "b")[0]
    id_a, _ = add_path(a, tree(tmp_path / "here" / "demos", {"data.bin": b"123"}), "demos")
    id_b, _ = add_path(b, tree(tmp_path / "there" / "other-name", {"data.bin": b"123"}), "demos")
    assert id_a == id_b
    # the source path is provenance: each store's own log says where its copy came from
    node_a, node_b = lineage(a, id_a), lineage(b, id_b)
    assert node_a["source"] == str(tmp_path / "here" / "demos")
    assert node_b["source"] == str(tmp_path / "there" / "other-name")
    assert node_a["created"] and node_a["created"] == provenance_index(a)[id_a]["created"]


def test_a_checkpoints_provenance_is_its_checkpoint_saved_event(tmp_path):
    store = Store.init(tmp_path / "store")[0]
    cid = publish(store, tree(tmp_path / "c", {"w.bin": b"w"}), attempt=2)
    append_event(store, "checkpoint-saved", step="train", cache_key="cd" * 32, attempt=2, checkpoint=cid)
    made = provenance_index(store)[cid]
    assert made["attempt"] == 2 and made["step"] == "train" and made["host"] and made["created"]


def test_format_1_manifests_are_still_read(tmp_path):
    """A store made before format 2: its manifests hold `created` and the producer's attempt."""
    store = Store.init(tmp_path / "store")[0]
    content = store_content(store, tree(tmp_path / "d", {"data.bin": b"old"}))
    old = store.put_json(
        {
            "type": "artifact",
            "format": 1,
            "kind": "demos",
            "producer": {"step": "add", "source": "/data/old-demos"},
            "inputs": {},
            "config": {},
            "code_version": "",
            "created": "2026-01-02T03:04:05+00:00",
            "meta": {},
            **content,
        }
    )
    assert read_artifact(store, old)["kind"] == "demos"
    node = lineage(store, old)
    assert node["created"] == "2026-01-02T03:04:05+00:00" and node["source"] == "/data/old-demos"
    set_ref(store, "demos/old", old)
    assert verify_store(store, full=True).ok


def test_a_pulled_artifact_keeps_the_provenance_of_the_store_that_made_it(tmp_path):
    from artifacts.remotes.config import add_remote
    from artifacts.remotes.pull import pull
    from artifacts.remotes.push import push

    robot = Store.init(tmp_path / "robot")[0]
    aid, _ = add_path(robot, tree(tmp_path / "recorded" / "demos", {"data.bin": b"123"}), "demos", ref="team/demos")
    (tmp_path / "nas" / "remote").mkdir(parents=True)  # the remote's directory (`accrue remote init` makes one)
    add_remote(robot, "origin", str(tmp_path / "nas" / "remote"))
    push(robot, "origin")
    learner = Store.init(tmp_path / "learner")[0]
    add_remote(learner, "origin", str(tmp_path / "nas" / "remote"))
    pull(learner, "origin")
    # the learner's own log never wrote it; the robot's log, pulled as segments, did
    assert lineage(learner, aid)["source"] == str(tmp_path / "recorded" / "demos")
    assert lineage(learner, aid)["created"] == lineage(robot, aid)["created"]


def test_a_step_records_lineage_gives_its_step_finish_time_outputs_and_each_input_once(tmp_path):
    """Kills lineage 15, 16, 47, 52, 64, 65, 66, 91, 93, 94, 95, 97, 98, 108, 109, 110, 111, 115, 116, 122."""
    store = Store.init(tmp_path / "store")[0]
    aid = publish(store, tree(tmp_path / "c", {"w.bin": b"weights"}), attempt=1)
    record = {
        "type": "step-record",
        "step": "evaluate",
        "inputs": {"checkpoint": aid, "same-again": aid},
        "config": {"eval": {"seed": 9}},
        "outputs": {"report": "ef" * 32},
        "finished": "2026-02-03T04:05:06+00:00",
    }
    node = lineage(store, store.put_json(record))
    assert node["type"] == "step-record" and node["step"] == "evaluate"
    assert node["created"] == "2026-02-03T04:05:06+00:00"
    assert node["outputs"] == {"report": "ef" * 32} and node["seeds"] == {"eval.seed": 9}
    first, again = node["inputs"]["checkpoint"], node["inputs"]["same-again"]
    assert first["id"] == aid and first["kind"] == "checkpoint" and "repeat" not in first
    assert first["size"] == read_artifact(store, aid)["size"] == len(b"weights")
    assert again == {"id": aid, "repeat": True}


def test_a_step_record_without_outputs_or_inputs_has_empty_ones_in_its_lineage(tmp_path):
    """Kills lineage 112, 114, 130, 132."""
    store = Store.init(tmp_path / "store")[0]
    node = lineage(store, store.put_json({"type": "step-record", "step": "noop"}))
    assert node["outputs"] == {} and node["inputs"] == {} and node["created"] is None


def test_the_lineage_of_a_missing_object_is_its_id_and_why(tmp_path):
    """Kills lineage 19, 20, 21, 22, 23."""
    store = Store.init(tmp_path / "store")[0]
    gone = "ab" * 32
    assert lineage(store, gone) == {"id": gone, "error": "object abababababab is missing from the store"}
