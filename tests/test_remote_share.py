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
    # a plain push finds nothing to do: the remote's refs are where b saw them
    assert json.loads(cli(b, "push", "--json").stdout)["objects_sent"] <= 2  # (its own log lines only)
    assert cli(b, "verify", "--remote", "origin", "--full").returncode == 1
    healed = json.loads(cli(b, "remote", "repair", "origin", "--full", "--json").stdout)
    assert healed["ok"] and set(healed["resent"]) == {replay, handoff_tree}
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
