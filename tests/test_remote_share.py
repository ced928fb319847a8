"""Sharing one store between machines (issue 22), against a directory remote and moto's S3: a
damaged remote is repaired from any store that has the objects, pull and push fast-forward when
only one side moved, pulled step records are cache hits, bad remotes are refused in one line."""

from __future__ import annotations

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from remote_support import (  # noqa: E402,F401
    cli,
    delete_remote_key,
    make_store,
    moto_endpoint,
    overwrite_remote_key,
    remote_url,
    s3_env,
    user_refs,
    with_remote,
)
from test_cli_store import one_line_error  # noqa: E402


def _key(oid: str) -> str:
    return f"objects/blake3/{oid[:2]}/{oid[2:]}"


def test_a_corrupted_then_deleted_remote_object_is_healed_by_repair_from_another_store(tmp_path, remote_url):
    a, b = tmp_path / "robot", tmp_path / "workstation"
    store = make_store(a)
    with_remote(a, remote_url)
    assert cli(a, "push").returncode == 0
    cli(b, "init")
    with_remote(b, remote_url)
    assert cli(b, "pull").returncode == 0  # b has every object now
    replay = json.loads(cli(a, "show", "team/replay", "--json").stdout)["content"]
    handoff_tree = json.loads(cli(a, "show", "team/handoff", "--json").stdout)["content"]
    data = bytearray(store.read_bytes(replay))
    data[10] ^= 0xFF
    overwrite_remote_key(remote_url, _key(replay), bytes(data))  # same size: only --full sees it
    delete_remote_key(remote_url, _key(handoff_tree))  # a manifest lost: what it names is still checked
    # a plain push checks what its refs reach: the lost manifest is sent again (a corrupt object of
    # the right size is seen by re-hashing only)
    pushed = json.loads(cli(b, "push", "--json").stdout)
    assert pushed["healed"] == [handoff_tree] and pushed["moved"] == {}
    assert pushed["objects_sent"] == 1 + (2 if pushed["log_segment"] else 0)  # (and b's own log lines)
    assert cli(b, "verify", "--remote", "origin", "--full").returncode == 1
    healed = json.loads(cli(b, "remote", "repair", "origin", "--full", "--json").stdout)
    assert healed["ok"] and healed["resent"] == [replay]
    assert cli(a, "verify", "--remote", "origin", "--full").returncode == 0
    c = tmp_path / "fresh"
    cli(c, "init")
    with_remote(c, remote_url)
    assert cli(c, "pull").returncode == 0 and cli(c, "verify", "--full").returncode == 0


def test_repair_from_a_store_that_lacks_the_object_says_so_in_one_line(tmp_path, remote_url):
    a, b = tmp_path / "a", tmp_path / "b"
    make_store(a)
    with_remote(a, remote_url)
    cli(a, "push")
    cli(b, "init")
    with_remote(b, remote_url)
    assert cli(b, "pull", "--only", "handoff").returncode == 0  # replay's data stays on the remote
    replay = json.loads(cli(a, "show", "team/replay", "--json").stdout)["content"]
    delete_remote_key(remote_url, _key(replay))
    line = one_line_error(cli(b, "remote", "repair"))
    assert "1 damaged object(s) this store lacks too" in line and replay[:12] in line
    assert cli(a, "remote", "repair").returncode == 0  # the robot has it
    assert cli(b, "verify", "--remote", "origin").returncode == 0


def test_pull_and_push_fast_forward_when_only_one_side_moved(tmp_path, remote_url):
    a, b = tmp_path / "robot", tmp_path / "workstation"
    make_store(a)
    with_remote(a, remote_url)
    cli(a, "push")
    cli(b, "init")
    with_remote(b, remote_url)
    cli(b, "pull")
    extra = tmp_path / "x.bin"
    extra.write_bytes(b"workstation's own work")
    mine = cli(b, "add", str(extra), "--kind", "replay", "--ref", "team/replay").stdout.strip()
    cli(b, "add", str(extra), "--kind", "replay", "--ref", "team/x")
    # only b moved: pull leaves b's refs as they are and says so; no conflict, exit 0
    pulled = cli(b, "pull")
    assert pulled.returncode == 0 and "team/replay: only this store moved it" in pulled.stdout
    assert user_refs(b)["team/replay"] == mine
    assert cli(b, "push").returncode == 0
    # only the remote moved for a: pull takes it, and a's push afterwards says nothing is behind
    assert cli(a, "pull").returncode == 0 and user_refs(a)["team/replay"] == mine and user_refs(a)["team/x"] == mine
    newer = tmp_path / "y.bin"
    newer.write_bytes(b"robot's newer work")
    theirs = cli(a, "add", str(newer), "--kind", "replay", "--ref", "team/replay").stdout.strip()
    assert cli(a, "push").returncode == 0
    behind = json.loads(cli(b, "push", "--json").stdout)  # only the remote moved: nothing sent back
    assert behind["behind"] == ["team/replay"] and behind["conflicts"] == []
    assert cli(b, "pull").returncode == 0 and user_refs(b)["team/replay"] == theirs
    assert not [r for r in user_refs(b) if r.startswith("displaced/")]


def test_a_pulled_store_runs_the_same_plan_as_cache_hits(tmp_path, remote_url):
    import os

    from rich.console import Console
    from test_runner_support import count_invocation

    from artifacts.store import Store
    from stages.runner import Runner
    from stages.runner_types import StagePlan

    a, b = tmp_path / "robot", tmp_path / "workstation"
    make_store(a, seed=3)
    with_remote(a, remote_url)
    cli(a, "push")
    cli(b, "init")
    with_remote(b, remote_url)
    pulled = json.loads(cli(b, "pull", "--json").stdout)
    assert pulled["steps_indexed"] == 1
    assert json.loads(cli(b, "pull", "--json").stdout)["steps_indexed"] == 0  # entered once only
    store = Store.open(b)
    handoff = user_refs(b)["team/handoff"]
    plan = StagePlan("wf", 1, (count_invocation(3, seed=3, inputs={"seed": handoff}),))
    [result] = Runner(store, console=Console(file=open(os.devnull, "w"))).run_plan(plan)
    assert result.cached and result.record_id == user_refs(a)["workflow/wf/stage/1/train"]
    assert cli(b, "verify").returncode == 0
    again = json.loads(cli(b, "push", "--json").stdout)  # nothing recomputed: no ref of the remote moves
    assert again["moved"] == {} and again["conflicts"] == []


def test_bad_remote_urls_and_a_remote_inside_the_store_are_refused_in_one_line(tmp_path):
    a = tmp_path / "a"
    cli(a, "init")
    for url, says in [
        ("s3:/x", "is malformed (a scheme needs '//'"),
        ("s3:bucket/x", "is malformed"),
        ("file:/mnt/x", "is malformed"),
        ("s3://Bad_Bucket/x", "is not a valid S3 bucket name"),
        (str(a / "refs" / "nas"), "is inside this store"),
        (str(a), "is inside this store"),
    ]:
        line = one_line_error(cli(a, "remote", "add", "nas", url))
        assert says in line, (url, line)
    assert json.loads(cli(a, "remote", "list", "--json").stdout) == {}
    assert not (a / "refs" / "nas").exists()
    assert cli(a, "remote", "add", "nas", str(tmp_path / "nas:2026")).returncode == 0  # a path, not a scheme


def test_pull_only_an_unknown_kind_is_an_error_that_fetches_nothing(tmp_path, remote_url):
    a, b = tmp_path / "a", tmp_path / "b"
    make_store(a)
    with_remote(a, remote_url)
    cli(a, "push")
    cli(b, "init")
    with_remote(b, remote_url)
    line = one_line_error(cli(b, "pull", "--only", "handof"))
    assert "--only handof: no artifact of that kind on remote origin (kinds there: eval, handoff, replay)" in line
    assert user_refs(b) == {} and not any((b / "objects").rglob("*/*"))


def test_a_copied_store_is_refused_until_rekeyed_and_the_original_chain_is_kept(tmp_path, remote_url):
    import shutil

    a = tmp_path / "a"
    make_store(a)
    with_remote(a, remote_url)
    assert cli(a, "push").returncode == 0
    copy = tmp_path / "copy"
    shutil.copytree(a, copy, symlinks=True)  # what cp -a does: the config (and its store id) comes along
    (tmp_path / "new.bin").write_bytes(b"the copy's own work")
    cli(copy, "add", str(tmp_path / "new.bin"), "--kind", "replay", "--ref", "copy/replay")
    line = one_line_error(cli(copy, "push"))
    assert "was made in another directory (a copy, e.g. cp -a?); run `accrue remote rekey`" in line
    moved = tmp_path / "moved"
    a.rename(moved)  # a move keeps the directory's inode: not a copy
    assert cli(moved, "push").returncode == 0
    moved.rename(a)
    rekeyed = json.loads(cli(copy, "remote", "rekey", "--json").stdout)
    assert rekeyed["old"] != rekeyed["new"]
    assert cli(copy, "push").returncode == 0
    assert cli(a, "push").returncode == 0  # the original's log chain was not touched
    b = tmp_path / "b"
    cli(b, "init")
    with_remote(b, remote_url)
    assert cli(b, "pull").returncode == 0
    assert len(json.loads(cli(b, "refs", "remote-logs/", "--json").stdout)) == 2  # two stores, two chains


def test_a_store_id_shared_without_the_marker_is_caught_at_the_remote(tmp_path, remote_url):
    a = tmp_path / "a"
    make_store(a)
    with_remote(a, remote_url)
    assert cli(a, "push").returncode == 0
    cfg = json.loads((a / "config").read_bytes())
    twin = tmp_path / "twin"
    cli(twin, "init")
    (tmp_path / "t.bin").write_bytes(b"the twin's work")
    cli(twin, "add", str(tmp_path / "t.bin"), "--kind", "replay", "--ref", "twin/replay")
    with_remote(twin, remote_url)
    home = {"path": str(twin.resolve()), "ino": twin.stat().st_ino}
    (twin / "config").write_text(json.dumps({**cfg, "store_home": home}))  # same id, its own marker
    assert cli(twin, "push").returncode == 0  # first push of the twin: starts its chain over a's pointer
    line = one_line_error(cli(a, "push"))  # a's pointer moved behind its back: refused, not overwritten
    assert "another store pushed an audit log with this store's id" in line and "rekey" in line


def test_an_endpoint_that_accepts_and_never_answers_ends_in_one_line(tmp_path, s3_env, monkeypatch):
    import socket
    import threading

    silent = socket.socket()
    silent.bind(("127.0.0.1", 0))
    silent.listen(16)
    held: list = []
    stop = threading.Event()

    def accept() -> None:
        silent.settimeout(0.2)
        while not stop.is_set():
            try:
                held.append(silent.accept()[0])  # accepted, never answered
            except OSError:
                pass

    threading.Thread(target=accept, daemon=True).start()
    try:
        a = tmp_path / "a"
        make_store(a, files=1)
        with_remote(a, "s3://silent-bucket/x")
        endpoint = f"http://127.0.0.1:{silent.getsockname()[1]}"
        monkeypatch.setenv("ACCRUE_REMOTE_READ_TIMEOUT", "1")
        assert cli(a, "remote", "set", "origin", "endpoint", endpoint).returncode == 0  # per-remote setting
        line = one_line_error(cli(a, "push"))
        assert f"cannot reach {endpoint} (no answer, or the connection failed)" in line
    finally:
        stop.set()
        for c in held:
            c.close()
        silent.close()


def test_per_remote_endpoint_replaces_the_environment(tmp_path, s3_env, monkeypatch):
    from remote_support import s3_client

    s3_client(s3_env).create_bucket(Bucket="per-remote")
    monkeypatch.delenv("AWS_ENDPOINT_URL")
    a = tmp_path / "a"
    make_store(a, files=1)
    with_remote(a, "s3://per-remote/x")
    assert cli(a, "remote", "set", "origin", "endpoint", s3_env).returncode == 0
    assert cli(a, "remote", "set", "origin", "region", "us-east-1").returncode == 0
    assert json.loads(cli(a, "remote", "list", "--json").stdout)["origin"]["endpoint"] == s3_env
    assert cli(a, "push").returncode == 0 and cli(a, "verify", "--remote", "origin").returncode == 0
    assert "unknown remote setting 'colour'" in one_line_error(cli(a, "remote", "set", "origin", "colour", "x"))
    assert "not an http(s) URL" in one_line_error(cli(a, "remote", "set", "origin", "endpoint", "minio:9000"))
    assert cli(a, "remote", "set", "origin", "endpoint", "--unset").returncode == 0
    assert "endpoint" not in json.loads(cli(a, "remote", "list", "--json").stdout)["origin"]


def test_per_remote_profile_gives_the_credentials_and_an_unknown_one_is_one_line(tmp_path, s3_env, monkeypatch):
    from remote_support import s3_client

    s3_client(s3_env).create_bucket(Bucket="by-profile")
    home = tmp_path / "home"
    (home / ".aws").mkdir(parents=True)
    (home / ".aws" / "config").write_text(
        "[profile lab]\naws_access_key_id = testing\naws_secret_access_key = testing\nregion = us-east-1\n"
    )
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.setenv("AWS_CONFIG_FILE", str(home / ".aws" / "config"))
    for var in ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY"):
        monkeypatch.delenv(var)
    a = tmp_path / "a"
    make_store(a, files=1)
    with_remote(a, "s3://by-profile/x")
    assert cli(a, "remote", "set", "origin", "profile", "lab").returncode == 0
    assert cli(a, "push").returncode == 0 and cli(a, "verify", "--remote", "origin").returncode == 0
    assert cli(a, "remote", "set", "origin", "profile", "nope").returncode == 0
    assert "no AWS profile 'nope'" in one_line_error(cli(a, "push"))


def test_no_credentials_at_all_is_one_line_that_says_so(tmp_path, s3_env, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path))  # no ~/.aws either
    for var in ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY"):
        monkeypatch.delenv(var)
    a = tmp_path / "a"
    make_store(a, files=1)
    with_remote(a, "s3://no-creds/x")
    line = one_line_error(cli(a, "push"))
    assert "no AWS credentials found" in line and "169.254" not in line


_NODE = """
import os, sys
sys.path.insert(0, {tests!r}); sys.path.insert(0, {root!r})
from rich.console import Console
from test_runner_support import count_invocation
from artifacts.refs import read_ref
from artifacts.store import Store
from stages.runner import Runner
from stages.runner_types import StagePlan
from artifacts.remotes.push import push
store = Store.open(sys.argv[1])
handoff = read_ref(store, "team/handoff")
plan = StagePlan(sys.argv[2], 1, (count_invocation(int(sys.argv[3]), seed=3, inputs={{"seed": handoff}}),))
Runner(store, console=Console(file=open(os.devnull, "w"))).run_plan(plan)
report = push(store, "origin", ["workflow/" + sys.argv[2]])
assert report.conflicts == [] and report.moved, report
"""


def test_two_nodes_that_share_only_the_remote_run_cells_and_push_their_results(tmp_path, remote_url):
    """What a cell on a machine without the shared store does: a partial clone (the input's data
    left on the remote, fetched when the step reads it), run, push its workflow's refs; two such
    nodes at once, each with its own store, then the first store pulls both as cache hits."""
    import os
    import subprocess

    from remote_support import accrue
    from rich.console import Console
    from test_runner_support import count_invocation

    from artifacts.store import Store
    from stages.runner import Runner
    from stages.runner_types import StagePlan

    a = tmp_path / "driver"
    make_store(a)
    with_remote(a, remote_url)
    cli(a, "push")
    nodes = []
    for i in (1, 2):
        node = tmp_path / f"node{i}"
        assert accrue("clone", remote_url, str(node), "--only", "eval").returncode == 0
        tree = json.loads(cli(node, "show", "team/handoff", "--json").stdout)["content"]
        handoff_file = Store.open(node).read_json(tree)["entries"][0]["id"]
        assert not Store.open(node).has_object(handoff_file)  # its data was left on the remote
        nodes.append(node)
    code = _NODE.format(tests=str(Path(__file__).parent), root=str(Path(__file__).parents[1]))
    procs = [
        subprocess.Popen([sys.executable, "-c", code, str(n), f"node{i}", str(3 + i)], env=dict(os.environ))
        for i, n in enumerate(nodes, 1)
    ]
    assert [p.wait(timeout=120) for p in procs] == [0, 0]
    assert Store.open(nodes[0]).has_object(handoff_file)  # fetched when the step read its input
    assert cli(a, "pull").returncode == 0
    for i in (1, 2):
        plan = StagePlan(
            f"node{i}", 1, (count_invocation(3 + i, seed=3, inputs={"seed": user_refs(a)["team/handoff"]}),)
        )
        [result] = Runner(Store.open(a), console=Console(file=open(os.devnull, "w"))).run_plan(plan)
        assert result.cached and result.record_id == user_refs(a)[f"workflow/node{i}/stage/1/train"]
    assert cli(a, "verify", "--remote", "origin").returncode == 0


def test_a_push_landing_while_push_delete_runs_keeps_the_pushed_ref(tmp_path, remote_url, monkeypatch):
    """push --delete is a compare-and-swap on the ref's value: a push of the same ref that reaches the
    remote just before the delete does (on S3: after the deleting store read the ref) survives."""
    from artifacts.remotes.push import push
    from artifacts.remotes.unshare import delete_remote_refs
    from artifacts.store import Store

    a, b = tmp_path / "robot", tmp_path / "workstation"
    make_store(a)
    with_remote(a, remote_url)
    cli(a, "push")
    cli(b, "init")
    with_remote(b, remote_url)
    cli(b, "pull")  # b saw team/replay where the robot put it
    (tmp_path / "newer.bin").write_bytes(b"the robot's newer replay")
    newer = cli(a, "add", str(tmp_path / "newer.bin"), "--kind", "replay", "--ref", "team/replay").stdout.strip()
    landed = []

    def robot_pushes() -> None:
        if not landed:
            landed.append(push(Store.open(a), "origin", ["team/replay"]).moved)

    if remote_url.startswith("s3://"):
        # the moto server runs in this process: the robot's push lands when b's request to delete
        # the ref arrives (a DELETE of the key, or a bulk POST ?delete naming it), before it is handled
        from moto.s3.responses import S3Response

        one, bulk = S3Response._key_response_delete, S3Response._bucket_response_delete_keys

        def key_delete(self, bucket_name, query, key_name):
            if key_name.endswith("refs/team/replay"):
                robot_pushes()
            return one(self, bucket_name, query, key_name)

        def keys_delete(self, bucket_name, *args, **kwargs):
            body = self.body.decode() if isinstance(self.body, bytes) else str(self.body)
            if "refs/team/replay" in body:
                robot_pushes()
            return bulk(self, bucket_name, *args, **kwargs)

        monkeypatch.setattr(S3Response, "_key_response_delete", key_delete)
        monkeypatch.setattr(S3Response, "_bucket_response_delete_keys", keys_delete)
    else:
        from artifacts.remotes.directory import DirBackend

        real_delete = DirBackend.delete

        def delete(self, key, expect):
            robot_pushes()
            return real_delete(self, key, expect)

        monkeypatch.setattr(DirBackend, "delete", delete)
    report = delete_remote_refs(Store.open(b), "origin", ["team/replay"])
    assert landed and "team/replay" in landed[0]  # the push really ran in between
    assert report.deleted == {} and report.conflicts == [
        "ref team/replay: remote origin moved it meanwhile; fetch and try again"
    ]
    assert cli(b, "fetch").returncode == 0
    assert user_refs(b)["team/replay"] != newer  # (b's own ref stays where it was)
    fetched = json.loads(cli(b, "refs", "remotes/origin/", "--json").stdout)
    assert fetched["remotes/origin/team/replay"] == newer
