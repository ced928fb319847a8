"""Sharing without surprises (issue 51): a vanished directory remote is never made again, deletions
travel, push checks what the remote holds, leases of pushes that are gone are taken over, clone keeps
its settings and goes on where it stopped. Each test fails on the code before the issue."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from remote_support import (  # noqa: E402,F401
    accrue,
    cli,
    delete_remote_key,
    make_store,
    moto_endpoint,
    overwrite_remote_key,
    remote_file_keys,
    remote_url,
    s3_client,
    s3_env,
    snapshot,
    user_refs,
    with_remote,
)
from test_cli_store import one_line_error  # noqa: E402

from artifacts.store import Store  # noqa: E402


def _key(oid: str) -> str:
    return f"objects/blake3/{oid[:2]}/{oid[2:]}"


def _json(proc) -> dict:
    assert proc.returncode == 0, (proc.stdout, proc.stderr)
    return json.loads(proc.stdout)


def put_remote_key(url: str, key: str, data: bytes) -> None:
    if url.startswith("s3://"):
        overwrite_remote_key(url, key, data)
    else:
        (Path(url) / key).parent.mkdir(parents=True, exist_ok=True)
        (Path(url) / key).write_bytes(data)


def _content(store: Path, ref: str) -> str:
    return _json(cli(store, "show", ref, "--json"))["content"]


def _pushed(path: Path, url: str) -> Path:
    """A store (remote_support.make_store) that pushed everything to remote origin at url."""
    make_store(path)
    with_remote(path, url)
    assert cli(path, "push").returncode == 0
    return path


def _pushed_dir_remote(tmp_path: Path) -> tuple[Path, Path]:
    a, remote = tmp_path / "robot", tmp_path / "nas" / "accrue"
    make_store(a)
    (tmp_path / "nas").mkdir()
    assert cli(a, "remote", "add", "origin", str(remote), "--create").returncode == 0
    assert cli(a, "push").returncode == 0
    return a, remote


# ----------------------------------------------------------------------------- 1. a remote's root must exist
def test_a_push_to_a_vanished_directory_remote_exits_non_zero_and_writes_nothing(tmp_path):
    a, remote = _pushed_dir_remote(tmp_path)
    (tmp_path / "x.bin").write_bytes(b"new work")
    cli(a, "add", str(tmp_path / "x.bin"), "--kind", "replay", "--ref", "team/new")
    remote.rename(tmp_path / "nas" / "accrue.gone")  # the NAS is unmounted: its mount point is empty
    before = snapshot(a)
    line = one_line_error(cli(a, "push"))
    assert "the directory does not exist (is the disk mounted?); nothing was written" in line
    assert "`accrue remote init origin` makes it one" in line
    assert not remote.exists() and snapshot(a) == before
    # every command that writes refuses in one line too, and none makes the directory
    for args in (
        ("push", "--delete", "team/replay"),
        ("remote", "prune", "--yes", "--grace", "0"),
        ("remote", "repair"),
        ("remote", "unlock", "--all"),
    ):
        assert "the directory does not exist (is the disk mounted?)" in one_line_error(cli(a, *args)), args
        assert not remote.exists(), args
    assert snapshot(a) == before
    # the disk comes back: the next push goes on (it is not taken for a copied store)
    (tmp_path / "nas" / "accrue.gone").rename(remote)
    pushed = _json(cli(a, "push", "--json"))
    assert "team/new" in pushed["moved"]


def test_a_directory_remote_is_made_by_remote_init_or_add_create_only(tmp_path):
    a = tmp_path / "a"
    make_store(a)
    missing = tmp_path / "usb" / "accrue"
    added = cli(a, "remote", "add", "usb", str(missing))
    assert added.returncode == 0 and "does not exist yet: `accrue remote init usb` makes it" in added.stdout
    assert "does not exist (is the disk mounted?)" in one_line_error(cli(a, "remote", "init", "usb"))  # no parent
    assert "does not exist (is the disk mounted?)" in one_line_error(cli(a, "push", "usb"))
    assert not missing.parent.exists()
    missing.parent.mkdir()
    assert "made an empty remote at" in cli(a, "remote", "init", "usb").stdout
    assert json.loads((missing / "config").read_text())["type"] == "accrue-remote"
    assert "already an accrue remote" in cli(a, "remote", "init", "usb").stdout
    assert cli(a, "push", "usb").returncode == 0
    # a directory that holds other files is not made a remote; `add --create` that fails adds nothing
    busy = tmp_path / "home"
    busy.mkdir()
    (busy / "notes.txt").write_text("mine")
    assert "holds files but no accrue store" in one_line_error(cli(a, "remote", "add", "home", str(busy), "--create"))
    assert "home" not in _json(cli(a, "remote", "list", "--json")) and not (busy / "config").exists()
    assert "no remote named 'nope'" in one_line_error(cli(a, "remote", "init", "nope"))


def test_a_wiped_remote_is_refused_by_push_and_started_afresh_by_remote_init(tmp_path, remote_url):
    a = _pushed(tmp_path / "a", remote_url)
    for key in remote_file_keys(remote_url, ""):  # everything, its config too
        delete_remote_key(remote_url, key)
    line = one_line_error(cli(a, "push"))
    assert "holds no accrue store, but this store has used it before" in line and "remote init origin" in line
    assert remote_file_keys(remote_url, "") == {}
    assert cli(a, "remote", "init").returncode == 0
    pushed = _json(cli(a, "push", "--json"))
    assert sorted(pushed["moved"]) == sorted(user_refs(a))
    assert cli(a, "verify", "--remote", "origin").returncode == 0


# ----------------------------------------------------------------------------- 2. deletions travel
def test_refs_delete_removes_a_local_ref_and_refuses_what_it_must_not(tmp_path):
    a, _ = _pushed_dir_remote(tmp_path)
    oid = user_refs(a)["team/replay"]
    out = cli(a, "refs", "delete", "team/replay")
    assert out.returncode == 0 and f"deleted ref team/replay (was {oid[:12]}" in out.stdout
    assert "`accrue push --delete origin team/replay` deletes it there" in out.stdout
    assert "team/replay" not in user_refs(a)
    assert "no ref 'team/replay' in this store" in one_line_error(cli(a, "refs", "delete", "team/replay"))
    assert "name the ref(s) to delete" in one_line_error(cli(a, "refs", "delete"))
    line = one_line_error(cli(a, "refs", "delete", "remotes/origin/team/handoff"))
    assert "remote-tracking ref" in line and "fetch --prune" in line
    assert "bad ref name" in one_line_error(cli(a, "refs", "delete", "../x"))
    # one bad name among good ones: nothing is deleted
    assert "no ref 'team/nope'" in one_line_error(cli(a, "refs", "delete", "team/handoff", "team/nope"))
    assert "team/handoff" in user_refs(a)
    events = [json.loads(line) for line in (a / "log" / "events.jsonl").read_text().splitlines()]
    assert any(e["event"] == "ref-deleted" and e["ref"] == "team/replay" and e["old"] == oid for e in events)
    # the deletion is this store's until pushed: status says so, and a pull does not bring the ref back
    rows = {r["ref"]: r["state"] for r in _json(cli(a, "status", "--json"))["origin"]}
    assert rows["team/replay"] == "deleted-here"
    pulled = cli(a, "pull")
    assert pulled.returncode == 0 and "deleted in this store, not taken again" in pulled.stdout
    assert "team/replay" not in user_refs(a)
    assert cli(a, "refs").returncode == 0 and "team/handoff" in cli(a, "refs", "team/").stdout


def test_deletions_travel_and_a_plain_push_never_makes_a_deleted_ref_again(tmp_path, remote_url):
    a, b, c = tmp_path / "robot", tmp_path / "workstation", tmp_path / "auditor"
    make_store(a)
    with_remote(a, remote_url)
    assert cli(a, "push").returncode == 0
    for store in (b, c):
        assert accrue("clone", remote_url, str(store)).returncode == 0
    gone = user_refs(a)["team/replay"]
    # the workstation deletes the ref here and there; the remote's prune drops what nothing reaches
    assert cli(b, "refs", "delete", "team/replay").returncode == 0
    assert cli(b, "push", "--delete", "team/replay").returncode == 0
    assert cli(b, "remote", "prune", "--yes", "--grace", "0").returncode == 0
    rows = {r["ref"]: r["state"] for r in _json(cli(a, "status", "--json"))["origin"]}
    assert rows["team/replay"] == "gone-there"
    # the robot's plain push does not make it again, and says how to go on
    pushed = cli(a, "push")
    assert pushed.returncode == 0 and "deleted on origin since this store last saw it, not sent" in pushed.stdout
    assert "`accrue pull --prune origin team/replay` deletes it here" in pushed.stdout
    assert "refs/team/replay" not in remote_file_keys(remote_url, "refs/")
    # fetch --prune drops the remote-tracking ref only; pull --prune deletes the local ref too
    fetched = _json(cli(c, "fetch", "--prune", "--json"))
    assert fetched["pruned"] == ["team/replay"] and "team/replay" in user_refs(c)
    assert "remotes/origin/team/replay" not in _json(cli(c, "refs", "remotes/", "--json"))
    pulled = _json(cli(a, "pull", "--prune", "--json"))
    assert pulled["deleted"] == {"team/replay": gone} and "team/replay" not in user_refs(a)
    assert _json(cli(c, "pull", "--prune", "--json"))["deleted"] == {"team/replay": gone}
    assert cli(a, "verify").returncode == 0 and cli(a, "push").returncode == 0
    assert "refs/team/replay" not in remote_file_keys(remote_url, "refs/")


def test_pull_prune_keeps_a_ref_moved_here_since_as_a_conflict_and_push_force_puts_it_back(tmp_path):
    a, remote = _pushed_dir_remote(tmp_path)
    b = tmp_path / "b"
    assert accrue("clone", str(remote), str(b)).returncode == 0
    deleted = cli(b, "push", "--delete", "team/replay")
    assert deleted.returncode == 0 and "still in this store: `accrue refs delete` deletes it here" in deleted.stdout
    (tmp_path / "newer.bin").write_bytes(b"newer")
    mine = cli(a, "add", str(tmp_path / "newer.bin"), "--kind", "replay", "--ref", "team/replay").stdout.strip()
    line = one_line_error(cli(a, "pull", "--prune", "origin", "team/replay"))
    assert "ref team/replay: deleted on remote origin since" in line and f"moved here to {mine[:12]}" in line
    assert user_refs(a)["team/replay"] == mine
    assert "moved here to" in one_line_error(cli(a, "push", "origin", "team/replay"))  # both moved: refused
    assert _json(cli(a, "push", "--force", "origin", "team/replay", "--json"))["moved"]["team/replay"] == [None, mine]


# ----------------------------------------------------------------------------- 3. push checks the remote
def test_push_sends_again_what_its_refs_reach_but_the_remote_lost_and_verify_names_the_heal(tmp_path, remote_url):
    a = _pushed(tmp_path / "robot", remote_url)
    store = Store.open(a)
    replay, handoff_tree = _content(a, "team/replay"), _content(a, "team/handoff")
    data = bytearray(store.read_bytes(replay))
    data[10] ^= 0xFF
    overwrite_remote_key(remote_url, _key(replay), bytes(data))  # corrupt, same size
    delete_remote_key(remote_url, _key(handoff_tree))  # lost
    verified = cli(a, "verify", "--remote", "origin", "--full")
    assert verified.returncode == 1 and "to heal it: `accrue remote repair origin --full`" in verified.stdout
    assert json.loads(cli(a, "verify", "--remote", "origin", "--json").stdout)["heal"] == "accrue remote repair origin"
    pushed = _json(cli(a, "push", "--json"))  # nothing to move: what its refs reach is checked anyway
    assert pushed["healed"] == [handoff_tree] and pushed["moved"] == {}
    assert _key(handoff_tree) in remote_file_keys(remote_url, "objects/")
    assert cli(a, "verify", "--remote", "origin", "--full").returncode == 1  # the corrupt one: same size
    checked = _json(cli(a, "push", "--verify", "--json"))
    assert checked["healed"] == [replay] and checked["objects_rehashed"] >= 2
    assert cli(a, "verify", "--remote", "origin", "--full").returncode == 0
    # a truncated object is seen by its size alone
    overwrite_remote_key(remote_url, _key(replay), b"short")
    assert _json(cli(a, "push", "--json"))["healed"] == [replay]
    assert cli(a, "verify", "--remote", "origin", "--full").returncode == 0


def test_a_ref_moved_to_objects_the_remote_lost_gets_them_sent_first(tmp_path):
    a, remote = _pushed_dir_remote(tmp_path)
    handoff = user_refs(a)["team/handoff"]
    (remote / _key(handoff)).unlink()
    # a new ref that reaches the lost manifest through the step record: re-sent before the ref moves
    record = user_refs(a)["workflow/wf/stage/1/train"]
    from artifacts.refs import set_ref

    set_ref(Store.open(a), "team/record-copy", record)
    pushed = _json(cli(a, "push", "origin", "team/record-copy", "--json"))
    assert handoff in pushed["healed"] and "team/record-copy" in pushed["moved"]
    assert (remote / _key(handoff)).is_file()


def test_verify_remote_names_a_store_that_has_them_when_this_one_lacks_them(tmp_path):
    a, remote = _pushed_dir_remote(tmp_path)
    b = tmp_path / "b"
    assert accrue("clone", str(remote), str(b), "--only", "handoff").returncode == 0
    replay = _content(a, "team/replay")
    (remote / _key(replay)).unlink()
    out = cli(b, "verify", "--remote", "origin")
    assert out.returncode == 1
    assert "to heal it: `accrue remote repair origin` from a store that has them (1 of them are not in" in out.stdout


def test_a_failed_clone_names_the_commands_that_work_and_running_it_again_goes_on(tmp_path, remote_url):
    a = _pushed(tmp_path / "robot", remote_url)
    replay = _content(a, "team/replay")
    delete_remote_key(remote_url, _key(replay))
    b = tmp_path / "workstation"
    line = one_line_error(accrue("clone", remote_url, str(b)))
    assert f"lacks object {replay[:12]} that its refs reach; run `accrue remote repair origin`" in line
    assert f"`accrue clone {remote_url} {b}` again goes on from there" in line
    line = one_line_error(accrue("clone", remote_url, str(b)))  # again, before the repair: the same advice
    assert "`accrue remote repair origin`" in line and "remote add" not in line
    assert cli(a, "remote", "repair").returncode == 0
    done = accrue("clone", remote_url, str(b))
    assert done.returncode == 0, done.stderr
    assert user_refs(b) == user_refs(a) and cli(b, "verify", "--full").returncode == 0
    # finished: a clone into it again names what works there
    line = one_line_error(accrue("clone", remote_url, str(b)))
    assert f"`accrue pull origin --store {b}` brings what it lacks" in line


# ----------------------------------------------------------------------------- 4. leases expire by liveness
def _dead_pid() -> int:
    proc = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    return int(proc.stdout)


def _lease(pid: int, host: str | None = None) -> bytes:
    from artifacts.remotes.lease import lease_info

    info = {**lease_info("a" * 32), "pid": pid, "proc_start": None}
    if host is not None:
        info["host"] = host
    return json.dumps(info).encode()


def test_prune_takes_over_a_killed_pushs_lease_and_unlock_removes_the_rest(tmp_path, remote_url):
    a = tmp_path / "a"
    make_store(a)
    with_remote(a, remote_url)
    cli(a, "push")
    assert cli(a, "push", "--delete", "team/replay", "ingested/replay").returncode == 0  # unreachable now
    put_remote_key(remote_url, "pushes/dead-push", _lease(_dead_pid()))  # kill -9 on this host
    pruned = _json(cli(a, "remote", "prune", "--yes", "--grace", "0s", "--json"))
    assert pruned["removed"] and [t.split(" ")[0] for t in pruned["leases_taken_over"]] == ["pushes/dead-push"]
    assert remote_file_keys(remote_url, "pushes/") == {}
    # a push on another host is never judged from here: prune waits, unlock keeps it, unlock --all removes it
    (tmp_path / "x.bin").write_bytes(b"to be dropped")
    cli(a, "add", str(tmp_path / "x.bin"), "--kind", "replay", "--ref", "team/x")
    cli(a, "push")
    assert cli(a, "push", "--delete", "team/x", "ingested/replay").returncode == 0
    put_remote_key(remote_url, "pushes/far-push", _lease(4242, host="another-host"))
    line = one_line_error(cli(a, "remote", "prune", "--yes", "--grace", "0s"))
    assert "a push is running (pushes/far-push (host another-host pid 4242" in line
    assert "`accrue remote unlock origin --all` if no push is running there" in line
    kept = cli(a, "remote", "unlock")
    assert kept.returncode == 0 and "kept live: pushes/far-push" in kept.stdout
    gone = _json(cli(a, "remote", "unlock", "--all", "--json"))
    assert [r.split(" ")[0] for r in gone["removed"]] == ["pushes/far-push"]
    assert _json(cli(a, "remote", "prune", "--yes", "--grace", "0s", "--json"))["removed"]


def test_a_push_takes_over_leases_whose_holder_is_gone_and_leaves_none_of_its_own(tmp_path):
    a, remote = _pushed_dir_remote(tmp_path)
    (remote / "pushes").mkdir(exist_ok=True)
    (remote / "pushes" / "dead").write_bytes(_lease(_dead_pid()))
    (remote / "pushes" / "live").write_bytes(_lease(os.getpid()))
    pushed = cli(a, "push")
    assert pushed.returncode == 0 and "took over the lease of a push that is gone: pushes/dead" in pushed.stdout
    assert sorted(p.name for p in (remote / "pushes").iterdir()) == ["live"]


def test_a_lease_is_renewed_while_its_push_runs(tmp_path, monkeypatch):
    import time

    import artifacts.remotes.lease as lease
    from artifacts.remotes.config import parse_url
    from artifacts.remotes.directory import DirBackend

    (tmp_path / "remote").mkdir()
    backend = DirBackend(parse_url("nas", str(tmp_path / "remote")))
    monkeypatch.setattr(lease, "RENEW_S", 0.05)
    puts = []
    real_put = backend.put_bytes
    monkeypatch.setattr(backend, "put_bytes", lambda key, data: puts.append(key) or real_put(key, data))
    with lease.held_lease(backend, "s" * 32):
        [held] = lease.read_leases(backend)
        assert held.state == "live" and held.info["pid"] == os.getpid() and held.info["host"] == socket.gethostname()
        deadline = time.monotonic() + 10
        while len(puts) < 3 and time.monotonic() < deadline:
            time.sleep(0.02)
    assert len(puts) >= 3 and len(set(puts)) == 1  # put, then renewed (same key)
    assert lease.read_leases(backend) == []
    # what a push learns for resuming uploads: when its lease was written, and whether another push was live
    with lease.held_lease(backend, "s" * 32) as alone:
        assert not alone.others_live and alone.written_at() is not None
        with lease.held_lease(backend, "t" * 32) as second:
            assert second.others_live and second.taken == []


def test_a_lease_holder_is_gone_only_when_provably_so():
    from artifacts.remotes.lease import _proc_start, holder_gone, lease_info

    mine = lease_info("s" * 32)
    assert not holder_gone(mine)
    assert holder_gone({**mine, "pid": _dead_pid()})
    assert not holder_gone({**mine, "pid": _dead_pid(), "host": "another-host"})
    assert holder_gone({**mine, "proc_start": str(int(_proc_start(os.getpid()) or 0) + 1)})  # a reused pid
    assert holder_gone({**mine, "boot": "another-boot"})  # this host restarted since
    assert not holder_gone({**mine, "pid": "12"}) and not holder_gone({}) and not holder_gone([])


# ----------------------------------------------------------------------------- 5. clone keeps its settings
def test_clone_takes_and_keeps_the_endpoint_and_region(tmp_path, s3_env, monkeypatch):
    import uuid

    bucket = f"b-{uuid.uuid4().hex[:12]}"
    s3_client(s3_env).create_bucket(Bucket=bucket)
    url = f"s3://{bucket}/lab"
    a = tmp_path / "robot"
    make_store(a)
    with_remote(a, url)
    assert cli(a, "push").returncode == 0
    monkeypatch.delenv("AWS_ENDPOINT_URL")  # the lab's own server, not in the environment
    b = tmp_path / "workstation"
    made = accrue("clone", url, str(b), "--endpoint", s3_env, "--region", "eu-west-1")
    assert made.returncode == 0, made.stderr
    assert _json(cli(b, "remote", "list", "--json"))["origin"] == {
        "url": url,
        "kind": "s3",
        "promisor": False,
        "endpoint": s3_env,
        "region": "eu-west-1",
    }
    assert cli(b, "pull").returncode == 0 and cli(b, "status").returncode == 0  # no variable needed again
    assert "not an http(s) URL" in one_line_error(accrue("clone", url, str(tmp_path / "c"), "--endpoint", "minio"))
    line = one_line_error(accrue("clone", str(tmp_path / "nas"), str(tmp_path / "d"), "--region", "x"))
    assert "applies to S3 remotes only" in line
    assert not (tmp_path / "c").exists() and not (tmp_path / "d").exists()


# ----------------------------------------------------------------------------- 6. a no-op push sends nothing
def test_a_no_op_push_uploads_nothing(tmp_path, remote_url):
    a = _pushed(tmp_path / "a", remote_url)
    before = remote_file_keys(remote_url, "")
    noop = _json(cli(a, "push", "--json"))
    assert (noop["objects_sent"], noop["log_segment"], noop["moved"]) == (0, None, {})
    assert remote_file_keys(remote_url, "") == before
    # the last push's own log line goes with the next push that moves a ref
    (tmp_path / "x.bin").write_bytes(b"more")
    cli(a, "add", str(tmp_path / "x.bin"), "--kind", "replay", "--ref", "team/x")
    assert _json(cli(a, "push", "--json"))["log_segment"]


def test_a_killed_multipart_upload_is_finished_where_it_stopped(tmp_path, s3_env, monkeypatch):
    import time
    import uuid

    from artifacts.hashing import CHUNK_SIZE
    from artifacts.remotes.backends import SINGLE_PUT_MAX
    from artifacts.remotes.s3 import S3Backend

    bucket = f"b-{uuid.uuid4().hex[:12]}"
    client = s3_client(s3_env)
    client.create_bucket(Bucket=bucket)
    url = f"s3://{bucket}/lab"
    a = tmp_path / "a"
    assert cli(a, "init").returncode == 0
    data = os.urandom(SINGLE_PUT_MAX + CHUNK_SIZE + 1000)  # four parts: 8 + 8 + 8 MiB + 1000 bytes
    (tmp_path / "big.bin").write_bytes(data)
    cli(a, "add", str(tmp_path / "big.bin"), "--kind", "checkpoint", "--ref", "team/big")
    with_remote(a, url)
    oid = _content(a, "team/big")
    key = f"lab/{_key(oid)}"
    # a push killed (its lease left behind) with parts 1 (here: other bytes, as if the file changed) and 3 sent
    put_remote_key(url, "pushes/killed", _lease(_dead_pid()))
    upload = client.create_multipart_upload(Bucket=bucket, Key=key)["UploadId"]
    for n, body in ((1, b"x" * CHUNK_SIZE), (3, data[2 * CHUNK_SIZE : 3 * CHUNK_SIZE])):
        client.upload_part(Bucket=bucket, Key=key, UploadId=upload, PartNumber=n, Body=body)
    time.sleep(1.1)  # begun a second before the next push's lease (the remote's clock counts seconds)
    sent = []
    real = S3Backend._boto3

    def counting(backend):
        made = real(backend)
        upload_part = made.upload_part
        made.upload_part = lambda **kw: sent.append(kw["PartNumber"]) or upload_part(**kw)
        return made

    monkeypatch.setattr(S3Backend, "_boto3", counting)
    pushed = _json(cli(a, "push", "--json"))
    assert pushed["uploads_resumed"] == [f"{oid[:12]}: 1 of 4 parts were there"] and sorted(sent) == [1, 2, 4]
    assert [t.split(" ")[0] for t in pushed["leases_taken_over"]] == ["pushes/killed"]
    assert client.list_multipart_uploads(Bucket=bucket).get("Uploads", []) == []
    assert cli(a, "verify", "--remote", "origin", "--full").returncode == 0
    b = tmp_path / "b"
    assert accrue("clone", url, str(b)).returncode == 0 and cli(b, "verify", "--full").returncode == 0
