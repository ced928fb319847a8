"""push / pull / fetch against both kinds of remote: a directory, and a real S3 API (moto's server,
started by the suite). Round trips, later pushes, fetch, the audit log carried across."""

from __future__ import annotations

import json
import os
import sys
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

from artifacts.store import Store  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def test_push_then_pull_into_an_empty_store_gives_the_same_refs(tmp_path, remote_url):
    a = tmp_path / "robot"
    store_a = make_store(a)
    with_remote(a, remote_url)
    pushed = json.loads(cli(a, "push", "--json").stdout)
    assert pushed["conflicts"] == [] and pushed["objects_sent"] == len(list(store_a.iter_object_ids())) + 2
    # the log line of the push itself waits for the next push that moves a ref: a no-op push sends nothing
    again = json.loads(cli(a, "push", "--json").stdout)
    assert again["objects_sent"] == 0 and again["moved"] == {} and again["log_segment"] is None
    assert again["objects_checked"] == pushed["objects_sent"] - 2  # everything its refs reach: still there
    assert [e["event"] for e in map(json.loads, (a / "log" / "events.jsonl").read_bytes().splitlines())][-1] == "pushed"

    b = tmp_path / "learner"
    assert cli(b, "init").returncode == 0
    with_remote(b, remote_url)
    pulled = cli(b, "pull")
    assert pulled.returncode == 0 and "received" in pulled.stdout
    assert user_refs(b) == user_refs(a) and len(user_refs(a)) >= 4
    assert cli(b, "verify", "--full").returncode == 0
    assert cli(b, "verify", "--remote", "origin").returncode == 0
    # lineage and show read pulled refs exactly as local ones
    ref = "workflow/wf/stage/1/train:result"
    assert cli(b, "lineage", ref).stdout == cli(a, "lineage", ref).stdout
    assert json.loads(cli(b, "show", "team/handoff", "--json").stdout) == json.loads(
        cli(a, "show", "team/handoff", "--json").stdout
    )
    # the robot's audit log came along as chained segments (artifacts) under remote-logs/: put
    # together they are its log, byte for byte
    [log_id] = json.loads(cli(b, "refs", "remote-logs/", "--json").stdout).values()
    parts, segment_id = [], log_id
    while segment_id:
        segment = json.loads(cli(b, "show", segment_id, "--json").stdout)
        assert segment["kind"] == "audit-log"
        parts.insert(0, Store.open(b).read_bytes(segment["content"]))
        segment_id = segment["inputs"].get("previous")
    log = (a / "log" / "events.jsonl").read_bytes()
    assert len(parts) == 1 and log.startswith(parts[0])
    assert [json.loads(line)["event"] for line in log[len(parts[0]) :].splitlines()] == ["pushed"]  # not sent yet
    # a second pull finds nothing to do
    assert json.loads(cli(b, "pull", "--json").stdout)["objects_received"] == 0


def test_a_later_push_sends_only_the_new_objects_and_a_chained_log_segment(tmp_path, remote_url):
    a = tmp_path / "robot"
    make_store(a)
    with_remote(a, remote_url)
    first = json.loads(cli(a, "push", "--json").stdout)
    extra = tmp_path / "episode.bin"
    extra.write_bytes(os.urandom(5000))
    cli(a, "add", str(extra), "--kind", "episodes", "--ref", "team/episodes")
    second = json.loads(cli(a, "push", "team/episodes", "--json").stdout)
    # the file and its manifest, and a new log segment (data + manifest) naming the previous one
    assert second["objects_sent"] == 4 and list(second["moved"]) == ["team/episodes"]
    b = tmp_path / "learner"
    cli(b, "init")
    with_remote(b, remote_url)
    cli(b, "pull")
    seg = json.loads(cli(b, "show", second["log_segment"], "--json").stdout)
    assert seg["inputs"] == {"previous": first["log_segment"]}
    first_line = Store.open(b).read_bytes(seg["content"]).splitlines()[0]
    previous = Store.open(b).read_bytes(json.loads(cli(b, "show", first["log_segment"], "--json").stdout)["content"])
    from artifacts.hashing import hash_bytes

    assert json.loads(first_line)["prev"] == hash_bytes(previous.splitlines()[-1])  # the chain crosses segments


def test_fetch_moves_only_tracking_refs_and_refs_deleted_there_come_back_only_by_force(tmp_path, remote_url):
    a, b = tmp_path / "a", tmp_path / "b"
    make_store(a)
    with_remote(a, remote_url)
    cli(a, "push")
    cli(b, "init")
    with_remote(b, remote_url)
    fetched = json.loads(cli(b, "fetch", "--json").stdout)
    assert fetched["moved"] == {} and user_refs(b) == {}
    tracking = json.loads(cli(b, "refs", "remotes/origin/", "--json").stdout)
    assert {n.removeprefix("remotes/origin/"): i for n, i in tracking.items()} == user_refs(a)
    assert cli(b, "verify", "--full").returncode == 0  # tracking refs keep what they reach
    for key in remote_file_keys(remote_url, "refs/"):
        delete_remote_key(remote_url, key)
    again = json.loads(cli(a, "push", "--json").stdout)  # deleted there since a last saw them: not made again
    assert again["moved"] == {} and sorted(again["gone_there"]) == sorted(user_refs(a)) and again["objects_sent"] == 0
    forced = json.loads(cli(a, "push", "--force", "--json").stdout)
    assert sorted(forced["moved"]) == sorted(user_refs(a)) and forced["objects_sent"] == 2  # a log segment
