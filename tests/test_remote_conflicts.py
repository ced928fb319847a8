"""When things go wrong between stores: a push killed mid-transfer resumes, two stores race for one
ref, a local ref changed meanwhile, a remote object is damaged or lost (directory and S3 remotes)."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from remote_support import (  # noqa: E402,F401
    cli,
    delete_remote_key,
    make_store,
    moto_endpoint,
    overwrite_remote_key,
    remote_file_keys,
    remote_url,
    s3_env,
    snapshot,
    user_refs,
    with_remote,
)
from test_cli_store import one_line_error  # noqa: E402

from artifacts.remotes.push import push  # noqa: E402
from artifacts.store import Store  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


_KILLER = """
import os, signal, sys, threading
sys.path.insert(0, {root!r})
from artifacts.remotes import directory, s3
after, lock, sent = int(sys.argv[2]), threading.Lock(), [0]
for cls in (s3.S3Backend, directory.DirBackend):
    def wrapped(self, oid, path, size, _orig=cls.upload_object):
        _orig(self, oid, path, size)
        with lock:
            sent[0] += 1
            if sent[0] >= after:
                os.kill(os.getpid(), signal.SIGKILL)
    cls.upload_object = wrapped
from artifacts.store import Store
from artifacts.remotes.push import push
push(Store.open(sys.argv[1]), "origin", jobs=1)
"""


def test_a_push_killed_mid_transfer_resumes_and_sends_only_the_rest(tmp_path, remote_url):
    a = tmp_path / "robot"
    store = make_store(a, files=30)
    with_remote(a, remote_url)
    total = len(list(store.iter_object_ids()))
    proc = subprocess.run(
        [sys.executable, "-c", _KILLER.format(root=str(ROOT)), str(a), "12"],
        env={**os.environ},
        capture_output=True,
        timeout=120,
    )
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    assert len(remote_file_keys(remote_url, "objects/")) == 12
    assert remote_file_keys(remote_url, "refs/") == {}  # refs move only after every object is there
    resumed = push(Store.open(a), "origin")
    assert resumed.objects_sent == total - 12 + 2  # the rest, and the log segment
    assert len(remote_file_keys(remote_url, "objects/")) == total + 2
    assert sorted(resumed.moved) == sorted(user_refs(a))


def test_two_stores_pushing_one_ref_at_once_one_wins_the_other_gets_a_conflict(tmp_path, remote_url):
    stores = []
    for name, seed in (("robot1", 1), ("robot2", 2)):
        path = tmp_path / name
        make_store(path, seed=seed)
        with_remote(path, remote_url)
        stores.append(path)
    ids = [user_refs(p)["team/handoff"] for p in stores]
    assert ids[0] != ids[1]
    barrier, reports = threading.Barrier(2), [None, None]

    def run(i: int) -> None:
        barrier.wait()
        reports[i] = push(Store.open(stores[i]), "origin", ["team/handoff"])

    threads = [threading.Thread(target=run, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    winners = [i for i in range(2) if "team/handoff" in reports[i].moved]
    assert len(winners) == 1
    loser = 1 - winners[0]
    [conflict] = reports[loser].conflicts
    assert "team/handoff" in conflict and ids[winners[0]][:12] in conflict
    remote_ref = remote_file_keys(remote_url, "refs/team/handoff")["refs/team/handoff"].decode().strip()
    assert remote_ref == ids[winners[0]]
    # the CLI says it in one line naming the ref and both ids, and --force overwrites
    line = one_line_error(cli(stores[loser], "push", "team/handoff"))
    assert re.search(
        rf"ref team/handoff: moved on both sides \(this store never saw it there\): this store has "
        rf"{ids[loser][:12]}, remote origin has {ids[winners[0]][:12]}; `accrue pull --force origin team/handoff`",
        line,
    ), line
    assert cli(stores[loser], "push", "team/handoff", "--force").returncode == 0
    remote_ref = remote_file_keys(remote_url, "refs/team/handoff")["refs/team/handoff"].decode().strip()
    assert remote_ref == ids[loser]
    # the winner now is the one behind: its push does not undo the loser's, it says to pull
    behind = json.loads(cli(stores[winners[0]], "push", "team/handoff", "--json").stdout)
    assert behind["behind"] == ["team/handoff"] and behind["moved"] == {}


def test_pull_refuses_to_move_a_local_ref_that_changed_since_it_was_last_seen(tmp_path, remote_url):
    a, b = tmp_path / "a", tmp_path / "b"
    make_store(a, seed=1)
    with_remote(a, remote_url)
    cli(a, "push")
    cli(b, "init")
    with_remote(b, remote_url)
    cli(b, "pull")
    other = tmp_path / "other.bin"
    other.write_bytes(b"local change")
    mine = cli(b, "add", str(other), "--kind", "replay", "--ref", "team/replay").stdout.strip()
    new = tmp_path / "new.bin"
    new.write_bytes(b"remote change")
    theirs = cli(a, "add", str(new), "--kind", "replay", "--ref", "team/replay").stdout.strip()
    cli(a, "push")
    line = one_line_error(cli(b, "pull"))
    assert f"this store has {mine[:12]}, remote origin has {theirs[:12]}" in line
    assert "pull --force origin team/replay" in line and "push --force origin team/replay" in line
    assert user_refs(b)["team/replay"] == mine
    assert one_line_error(cli(b, "push")).startswith("error: ref team/replay: moved on both sides")
    # either way on keeps the other side's work under a displaced/ ref
    assert cli(b, "pull", "--force").returncode == 0 and user_refs(b)["team/replay"] == theirs
    assert user_refs(b)[f"displaced/team/replay/{mine[:12]}"] == mine
    mine2 = cli(b, "add", str(other), "--kind", "replay", "--ref", "team/replay").stdout.strip()
    newer = tmp_path / "newer.bin"
    newer.write_bytes(b"another remote change")
    theirs2 = cli(a, "add", str(newer), "--kind", "replay", "--ref", "team/replay").stdout.strip()
    assert mine2 == mine and cli(a, "push").returncode == 0
    forced = json.loads(cli(b, "push", "--force", "--json").stdout)
    assert forced["displaced"] == {"team/replay": f"displaced/team/replay/{theirs2[:12]}"}
    assert cli(a, "pull").returncode == 0  # a has not moved since its push: it fast-forwards
    assert user_refs(a)["team/replay"] == mine
    assert user_refs(a)[f"displaced/team/replay/{theirs2[:12]}"] == theirs2  # a's work, still named


def test_a_byte_flipped_in_a_remote_object_is_refused_on_pull(tmp_path, remote_url):
    a, b = tmp_path / "a", tmp_path / "b"
    store = make_store(a)
    with_remote(a, remote_url)
    cli(a, "push")
    replay = json.loads(cli(a, "show", "team/replay", "--json").stdout)["content"]
    key = f"objects/blake3/{replay[:2]}/{replay[2:]}"
    data = bytearray(store.read_bytes(replay))
    data[4321] ^= 0x01
    overwrite_remote_key(remote_url, key, bytes(data))
    cli(b, "init")
    with_remote(b, remote_url)
    before = snapshot(b)
    line = one_line_error(cli(b, "pull"))
    assert f"object {replay[:12]} arrived corrupt 3 times; refused" in line
    assert not Store.open(b).has_object(replay) and user_refs(b) == {}
    assert not [p for p in (b / "tmp").iterdir()]  # no half download left behind
    # what did arrive intact is kept for the next try, but nothing corrupt, and no ref moved
    assert all(Store.open(b).read_bytes(o) for o in Store.open(b).iter_object_ids())
    assert {k: v for k, v in snapshot(b).items() if k.startswith("refs/")} == {
        k: v for k, v in before.items() if k.startswith("refs/")
    }
    # and verify --remote --full finds it too
    bad = cli(b, "verify", "--remote", "origin", "--full", "--json")
    assert bad.returncode == 1 and any(replay[:12] in p and "corrupt" in p for p in json.loads(bad.stdout)["problems"])


def test_verify_remote_reports_an_object_the_remote_lost(tmp_path, remote_url):
    a = tmp_path / "a"
    make_store(a)
    with_remote(a, remote_url)
    cli(a, "push")
    assert cli(a, "verify", "--remote", "origin").returncode == 0
    replay = json.loads(cli(a, "show", "team/replay", "--json").stdout)["content"]
    delete_remote_key(remote_url, f"objects/blake3/{replay[:2]}/{replay[2:]}")
    out = cli(a, "verify", "--remote", "origin")
    assert out.returncode == 1 and f"lacks object {replay[:12]}" in out.stdout
