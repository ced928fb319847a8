"""Issue 13: a full disk during every kind of publish (objects, manifests, attempt records, refs, the
log) is one clean StoreError; the store still verifies, nothing partial is left behind, and the same
write succeeds once there is room. Runs on a small tmpfs (root only; skipped otherwise)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from reliability_support import fill, small_fs  # noqa: E402
from test_cli_store import accrue, one_line_error  # noqa: E402

from artifacts.auditlog import append_event  # noqa: E402
from artifacts.errors import StoreError  # noqa: E402
from artifacts.ingest import add_path  # noqa: E402
from artifacts.manifests import store_content, write_manifest  # noqa: E402
from artifacts.records import list_attempts, write_attempt  # noqa: E402
from artifacts.refs import read_ref, set_ref  # noqa: E402
from artifacts.store import Store  # noqa: E402
from artifacts.verify import verify_store  # noqa: E402


def leftovers(store: Store) -> list[str]:
    """Temp files of a publish that did not finish."""
    found = [p for p in store.tmp_dir.iterdir()]
    for area in (store.refs_dir, store.records_dir, store.log_path.parent, store.objects_dir):
        found += [p for p in area.rglob(".*tmp*")]
    return [str(p.relative_to(store.root)) for p in found]


def _object(store, tmp):
    return store.put_bytes(os.urandom(200_000))


def _ingest(store, tmp):
    return add_path(store, tmp["big"], "demos")


def _manifest(store, tmp):
    # another kind than the add's: the same kind and content would be the add's manifest, already stored
    return write_manifest(store, tmp["content"], "episodes", producer={"step": "add", "source": "x"})


def _record(store, tmp):
    write_attempt(
        store,
        {"cache_key": "ef" * 32, "attempt": 1, "step": "train", "state": "running", "inputs": {}, "checkpoints": []},
    )


def _ref(store, tmp):
    set_ref(store, "demos/full", tmp["aid"])


def _log(store, tmp):
    for i in range(50):  # the log's last page may have room for a few lines; its head file does not
        append_event(store, "custom", i=i, pad="p" * 200)


@pytest.mark.parametrize(
    "publish",
    [_object, _ingest, _manifest, _record, _ref, _log],
    ids=["objects", "ingest", "manifests", "records", "refs", "log"],
)
def test_disk_full_during_publish_is_clean(tmp_path, publish):
    outside = tmp_path / "big.bin"
    outside.write_bytes(os.urandom(300_000))
    with small_fs(tmp_path / "fs", "3m") as fs:
        store = Store.init(fs / "store")[0]
        src = tmp_path / "ds"
        src.mkdir()
        (src / "a.bin").write_bytes(os.urandom(5000))
        aid, _ = add_path(store, src, "demos", ref="demos/one")
        ctx = {"big": outside, "aid": aid, "content": store_content(store, src)}
        filler = fill(fs)
        with pytest.raises(StoreError, match="No space left on device"):
            publish(store, ctx)
        assert leftovers(store) == []
        report = verify_store(store, full=True)
        assert report.ok, report.problems
        assert read_ref(store, "demos/one") == aid
        filler.unlink()
        publish(store, ctx)  # with room, the same write succeeds
        assert verify_store(store, full=True).ok
        if publish is _record:
            assert [a["state"] for a in list_attempts(store)] == ["running"]


def test_disk_full_during_cli_add_is_one_line_and_leaves_nothing(tmp_path):
    outside = tmp_path / "big.bin"
    outside.write_bytes(os.urandom(400_000))
    with small_fs(tmp_path / "fs", "3m") as fs:
        store = Store.init(fs / "store")[0]
        store.close()
        fill(fs, leave=100_000)
        line = one_line_error(
            accrue("add", str(outside), "--kind", "demos", "--ref", "big", "--store", str(store.root))
        )
        assert "No space left on device" in line and str(store.root) in line
        assert leftovers(store) == [] and not (store.refs_dir / "big").exists()
        assert accrue("verify", "--full", "--store", str(store.root)).returncode == 0
