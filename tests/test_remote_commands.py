"""The git/restic/DVC-like commands around remotes (issue 22), against a directory remote and
moto's S3: clone, status, push --delete, remote prune, log --remote, diff."""

from __future__ import annotations

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from remote_support import (  # noqa: E402,F401
    accrue,
    cli,
    make_store,
    moto_endpoint,
    remote_file_keys,
    remote_url,
    s3_env,
    user_refs,
    with_remote,
)
from test_cli_store import one_line_error  # noqa: E402


def _status(store: Path, *args: str) -> dict[str, str]:
    rows = json.loads(cli(store, "status", "--json", *args).stdout)["origin"]
    return {r["ref"]: r["state"] for r in rows}


def test_clone_makes_a_store_with_origin_and_its_step_cache(tmp_path, remote_url):
    a = tmp_path / "robot"
    make_store(a)
    with_remote(a, remote_url)
    cli(a, "push")
    b = tmp_path / "workstation"
    out = json.loads(accrue("clone", remote_url, str(b), "--json").stdout)
    assert out["steps_indexed"] == 1 and user_refs(b) == user_refs(a)
    assert json.loads(cli(b, "remote", "list", "--json").stdout)["origin"]["url"]
    assert cli(b, "verify", "--full").returncode == 0
    # a second clone into a store, or into a non-empty directory, is refused; a bad URL makes nothing
    assert "is a store already" in one_line_error(accrue("clone", remote_url, str(b)))
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "notes.txt").write_text("mine")
    assert "exists and is not empty" in one_line_error(accrue("clone", remote_url, str(tmp_path / "busy")))
    assert "is malformed" in one_line_error(accrue("clone", "s3:/x", str(tmp_path / "c")))
    assert not (tmp_path / "c").exists()
    assert "does not exist" in one_line_error(accrue("clone", str(tmp_path / "nothing"), str(tmp_path / "d")))
    assert not (tmp_path / "d").exists()


def test_status_names_which_side_moved_per_ref(tmp_path, remote_url):
    a, b = tmp_path / "a", tmp_path / "b"
    make_store(a)
    with_remote(a, remote_url)
    cli(a, "push")
    accrue("clone", remote_url, str(b))
    assert set(_status(b).values()) == {"up-to-date"}
    (tmp_path / "x.bin").write_bytes(b"b's work")
    (tmp_path / "y.bin").write_bytes(b"a's work")
    (tmp_path / "z.bin").write_bytes(b"both")
    cli(b, "add", str(tmp_path / "x.bin"), "--kind", "replay", "--ref", "team/replay")
    cli(b, "add", str(tmp_path / "x.bin"), "--kind", "replay", "--ref", "b/new")
    cli(a, "add", str(tmp_path / "y.bin"), "--kind", "replay", "--ref", "team/handoff")
    cli(a, "add", str(tmp_path / "y.bin"), "--kind", "replay", "--ref", "a/new")
    cli(a, "push")
    states = _status(b)
    assert states["team/replay"] == "ahead" and states["b/new"] == "local-only"
    assert states["team/handoff"] == "behind" and states["a/new"] == "remote-only"
    assert _status(b, "--offline")["team/handoff"] == "up-to-date"  # b has not fetched a's push
    cli(b, "add", str(tmp_path / "z.bin"), "--kind", "replay", "--ref", "team/handoff")
    assert _status(b)["team/handoff"] == "diverged"
    text = cli(b, "status").stdout
    assert "ahead" in text and "team/replay" in text and "diverged" in text


def test_push_delete_removes_a_remote_ref_only_where_it_was_last_seen(tmp_path, remote_url):
    a, b = tmp_path / "a", tmp_path / "b"
    make_store(a)
    with_remote(a, remote_url)
    cli(a, "push")
    accrue("clone", remote_url, str(b))
    deleted = json.loads(cli(a, "push", "--delete", "team/replay", "--json").stdout)
    assert list(deleted["deleted"]) == ["team/replay"]
    assert "refs/team/replay" not in remote_file_keys(remote_url, "refs")
    assert "team/replay" in user_refs(a)  # the local ref stays, as in git
    assert _status(a)["team/replay"] == "local-only"
    # b saw team/handoff at one id; a moves it; b's delete is refused, a's work stays
    (tmp_path / "n.bin").write_bytes(b"new handoff")
    cli(a, "add", str(tmp_path / "n.bin"), "--kind", "replay", "--ref", "team/handoff")
    cli(a, "push")
    line = one_line_error(cli(b, "push", "--delete", "team/handoff"))
    assert "fetch origin` first" in line and "refs/team/handoff" in remote_file_keys(remote_url, "refs")
    assert "no ref 'nope' on remote origin" in one_line_error(cli(a, "push", "--delete", "nope"))
    assert "name the ref(s)" in one_line_error(cli(a, "push", "--delete"))


def test_log_remote_shows_other_stores_logs_and_checks_each_as_one_chain(tmp_path, remote_url):
    from artifacts.hashing import canonical_json, hash_bytes
    from artifacts.refs import set_ref
    from artifacts.store import Store

    a, b = tmp_path / "robot", tmp_path / "workstation"
    make_store(a)
    with_remote(a, remote_url)
    cli(a, "push")
    (tmp_path / "x.bin").write_bytes(b"more")
    cli(a, "add", str(tmp_path / "x.bin"), "--kind", "replay", "--ref", "team/more")
    cli(a, "push")  # a second segment, chained to the first
    accrue("clone", remote_url, str(b))
    shown = json.loads(cli(b, "log", "--remote", "origin", "--all", "--json").stdout)
    [summary] = shown["stores"]
    assert summary["ok"] and summary["segments"] == 2
    a_lines = (a / "log" / "events.jsonl").read_bytes().splitlines()
    assert [e["seq"] for e in shown["events"]] == list(range(summary["events"]))
    assert summary["events"] == len(a_lines) - 1  # all but a's last `pushed` line (it rides the next push)
    assert "chain ok" in cli(b, "log", "--remote", "origin").stdout
    # a segment whose first line does not follow the one before it: the chain check finds it
    store = Store.open(b)
    [(ref, seg_id)] = json.loads(cli(b, "refs", "remote-logs/", "--json").stdout).items()
    seg = store.read_json(seg_id)
    lines = store.read_bytes(seg["content"]).splitlines()
    first = json.loads(lines[0])
    first["prev"] = "f" * 64
    data = b"\n".join([canonical_json(first)] + lines[1:]) + b"\n"
    forged = {**seg, "content": store.put_bytes(data), "size": len(data)}
    set_ref(store, ref, store.put_json(forged), log=False)
    assert hash_bytes(canonical_json(forged)) != seg_id
    broken = cli(b, "log", "--remote", "origin", "--json")
    assert broken.returncode == 1
    assert any("hash chain broken" in p for p in json.loads(broken.stdout)["stores"][0]["problems"])
    assert "no remote named 'nope'" in one_line_error(cli(b, "log", "--remote", "nope"))


def test_remote_prune_dry_run_first_then_deletes_only_the_unreachable_and_waits_for_pushes(tmp_path, remote_url):
    import os

    from remote_support import delete_remote_key, overwrite_remote_key, s3_client

    a = tmp_path / "a"
    make_store(a)
    with_remote(a, remote_url)
    cli(a, "push")
    replay = json.loads(cli(a, "show", "team/replay", "--json").stdout)
    gone = {replay["content"], user_refs(a)["team/replay"]}
    assert cli(a, "push", "--delete", "team/replay", "ingested/replay").returncode == 0
    # a killed push's unfinished upload
    if remote_url.startswith("s3://"):
        bucket, _, prefix = remote_url[5:].partition("/")
        s3_client(os.environ["AWS_ENDPOINT_URL"]).create_multipart_upload(Bucket=bucket, Key=f"{prefix}/objects/x")
    else:
        (Path(remote_url) / "tmp").mkdir(exist_ok=True)
        (Path(remote_url) / "tmp" / "obj-dead").write_bytes(b"half an object")
    kept = json.loads(cli(a, "remote", "prune", "--json").stdout)  # 24 h grace: all of it is young
    assert kept["removed"] == [] and kept["young"] >= 2 and kept["dry_run"]
    dry = json.loads(cli(a, "remote", "prune", "--grace", "0", "--json").stdout)
    assert gone <= set(dry["removed"]) and len(dry["uploads"]) == 1
    assert all(f"objects/blake3/{o[:2]}/{o[2:]}" in remote_file_keys(remote_url, "objects") for o in gone)
    # a push in progress (its lease): nothing is deleted
    if remote_url.startswith("s3://"):
        overwrite_remote_key(remote_url, "pushes/other-store-1-abc", b"{}")
    else:
        (Path(remote_url) / "pushes").mkdir(exist_ok=True)
        (Path(remote_url) / "pushes" / "other-store-1-abc").write_bytes(b"{}")
    line = one_line_error(cli(a, "remote", "prune", "--yes", "--grace", "0"))
    assert "a push is running (pushes/other-store-1-abc); nothing was deleted" in line
    delete_remote_key(remote_url, "pushes/other-store-1-abc")
    done = json.loads(cli(a, "remote", "prune", "--yes", "--grace", "0", "--json").stdout)
    assert set(done["removed"]) == set(dry["removed"])
    held = remote_file_keys(remote_url, "objects")
    assert not any(f"objects/blake3/{o[:2]}/{o[2:]}" in held for o in gone)
    assert json.loads(cli(a, "remote", "prune", "--grace", "0", "--json").stdout)["uploads"] == []
    assert cli(a, "verify", "--remote", "origin", "--full").returncode == 0
    b = tmp_path / "b"
    assert accrue("clone", remote_url, str(b)).returncode == 0 and cli(b, "verify", "--full").returncode == 0
    assert "team/handoff" in user_refs(b) and "team/replay" not in user_refs(b)


def test_diff_step_records_runs_and_artifacts_with_metrics_side_by_side(tmp_path):
    import os

    from rich.console import Console
    from test_runner_support import count_invocation

    from artifacts.store import Store
    from stages.runner import Runner
    from stages.runner_types import StagePlan

    a = tmp_path / "a"
    store = make_store(a, seed=3)
    handoff = user_refs(a)["team/handoff"]
    Runner(store, console=Console(file=open(os.devnull, "w"))).run_plan(
        StagePlan("wf2", 1, (count_invocation(5, seed=3, inputs={"seed": handoff}),))
    )
    one = json.loads(cli(a, "diff", "workflow/wf/stage/1/train", "workflow/wf2/stage/1/train", "--json").stdout)
    assert one["fields"]["config.n"] == [3, 5] and "config.seed" not in one["fields"]
    assert "input.seed" not in one["fields"] and "code_version" not in one["fields"]
    assert one["metrics"]["result/final.json:n"] == [3, 5]
    runs = json.loads(cli(a, "diff", "workflow/wf", "workflow/wf2", "--json").stdout)
    assert runs["fields"]["stage/1/train config.n"] == [3, 5] and runs["only_a"] == runs["only_b"] == []
    arts = json.loads(cli(a, "diff", "team/handoff", "team/replay", "--json").stdout)
    assert arts["fields"]["kind"] == ["handoff", "replay"]
    text = cli(a, "diff", "workflow/wf/stage/1/train", "workflow/wf2/stage/1/train").stdout
    assert "config.n" in text and "+2" in text
    assert "compare like with like" in one_line_error(cli(a, "diff", "workflow/wf", "team/handoff"))
    replay_data = json.loads(cli(a, "show", "team/replay", "--json").stdout)["content"]
    assert "is not a JSON manifest" in one_line_error(cli(a, "diff", replay_data, "team/replay"))
    assert Store.open(a).has_object(replay_data)
