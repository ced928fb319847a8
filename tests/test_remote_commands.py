"""The git/restic/DVC-like commands around remotes (issue 22), against a directory remote and
moto's S3: clone, status, push --delete, remote prune, log --remote, diff."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

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
    assert "a push is running (pushes/other-store-1-abc (host ? pid ?, renewed " in line
    assert "nothing was deleted" in line and "`accrue remote unlock origin --all` if no push is running" in line
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


# --- mutmut survivors, batch D (issue 23): remote remove / remote set / the both-moved line ---

ID_A, ID_B, ID_C = "0123456789abcdef" * 4, "fedcba9876543210" * 4, "00112233445566778899aabbccddeeff" * 2


def test_remote_remove_refuses_a_partial_clone_until_forced_and_then_forgets_only_its_promises(tmp_path):
    """Kills forget_remote 1, 18, 19, 51."""
    from artifacts.errors import StoreError
    from artifacts.remotes.forget import forget_remote
    from artifacts.remotes.lazy import add_promised
    from artifacts.store import Store

    s = tmp_path / "s"
    assert accrue("init", "--store", str(s)).returncode == 0
    with_remote(s, str(tmp_path / "nas"), "nas")
    with_remote(s, str(tmp_path / "lab"), "lab")
    store = Store.open(s)
    add_promised(store, "nas", [ID_B, ID_A])  # two ids it lacks, noted in sorted order
    add_promised(store, "lab", [ID_C])
    line = one_line_error(cli(s, "remote", "remove", "nas"))
    assert "remote nas still holds 2 object(s)" in line and f"(e.g. {ID_A[:12]});" in line
    with pytest.raises(StoreError, match=r"still holds 2 object\(s\)"):
        forget_remote(store, "nas")  # not forced unless asked
    assert "nas" in json.loads(cli(s, "remote", "list", "--json").stdout)
    assert store.is_promised(ID_A) and store.is_promised(ID_C)
    assert forget_remote(store, "nas", force=True) == 0
    # the same Store object reads the promises again: lab's stays, nas's went with it
    assert store.is_promised(ID_C) and not store.is_promised(ID_A)
    assert set(json.loads(cli(s, "remote", "list", "--json").stdout)) == {"lab"}


def test_remote_remove_counts_both_kinds_of_tracking_refs_and_forgets_a_never_used_remote(tmp_path):
    """Kills forget_remote 31, 32, 39, 41, 46."""
    a, b, url = tmp_path / "a", tmp_path / "b", str(tmp_path / "remote")
    make_store(a)
    assert cli(a, "remote", "add", "origin", url, "--create").returncode == 0
    cli(a, "push")
    assert accrue("clone", url, str(b)).returncode == 0
    # a remote added and never fetched from has no remotes/<name>/ state yet
    with_remote(b, str(tmp_path / "unused"), "nas")
    out = cli(b, "remote", "remove", "nas")
    assert out.returncode == 0 and "removed remote nas (0 remote-tracking refs dropped)" in out.stdout
    tracking = json.loads(cli(b, "refs", "remotes/origin/", "--json").stdout)
    logs = json.loads(cli(b, "refs", "remote-logs/origin/", "--json").stdout)
    assert len(tracking) >= 2 and len(logs) == 1
    gone = json.loads(cli(b, "remote", "remove", "origin", "--json").stdout)
    assert gone == {"removed": "origin", "tracking_refs_dropped": len(tracking) + len(logs)}
    assert json.loads(cli(b, "refs", "remotes/", "--json").stdout) == {}
    assert json.loads(cli(b, "refs", "remote-logs/", "--json").stdout) == {}
    assert not (b / "remotes" / "origin").exists()


def test_remote_remove_drops_tracking_refs_under_the_refs_lock(tmp_path, monkeypatch):
    """Kills forget_remote 23, 26, 27: ref writers (artifacts.refs) lock locks/refs.lock; the
    tracking refs are deleted while it is held, so no ref write lands in a half-removed tree."""
    import shutil

    from artifacts.errors import StoreError
    from artifacts.locks import store_lock, try_lock
    from artifacts.refs import set_ref
    from artifacts.remotes.forget import forget_remote
    from artifacts.store import Store

    s = tmp_path / "s"
    assert accrue("init", "--store", str(s)).returncode == 0
    with_remote(s, str(tmp_path / "nas"), "nas")
    store = Store.open(s)
    set_ref(store, "remotes/nas/team/x", store.put_bytes(b"x"), log=False)
    held: list[bool] = []
    real_rmtree = shutil.rmtree

    def rmtree(path, *args, **kwargs):
        if store.refs_dir in Path(path).parents:
            try:
                try_lock(store_lock(store.locks_dir, "refs"), "refs", timeout=0).release()
                held.append(False)
            except StoreError:
                held.append(True)
        return real_rmtree(path, *args, **kwargs)

    monkeypatch.setattr(shutil, "rmtree", rmtree)
    assert forget_remote(store, "nas") == 1
    assert held == [True]


def test_remove_remote_entry_of_an_absent_remote_changes_nothing(tmp_path):
    """Kills remove_remote_entry 3, 5, 7 (a `remote remove` racing another one finds the entry gone)."""
    from artifacts.remotes.config import remove_remote_entry
    from artifacts.store import Store

    s = tmp_path / "s"
    assert accrue("init", "--store", str(s)).returncode == 0
    store = Store.open(s)
    before = store.read_config()
    assert "remotes" not in before
    remove_remote_entry(store, "origin")  # no remotes at all
    assert store.read_config() == before
    with_remote(s, str(tmp_path / "nas"), "nas")
    remove_remote_entry(store, "origin")  # remotes, but not that one
    assert list(store.read_config()["remotes"]) == ["nas"]


def test_remote_set_explains_unknown_keys_and_directory_remotes_and_unsets_what_was_never_set(tmp_path):
    """Kills set_setting 9, 13, 34."""
    s = tmp_path / "s"
    assert accrue("init", "--store", str(s)).returncode == 0
    with_remote(s, "s3://my-bucket/team")
    with_remote(s, str(tmp_path / "nas"), "nas")
    line = one_line_error(cli(s, "remote", "set", "origin", "colour", "blue"))
    assert line == "error: unknown remote setting 'colour' (settings: endpoint, profile, region)"
    line = one_line_error(cli(s, "remote", "set", "nas", "region", "eu-west-1"))
    assert line == "error: remote nas is a directory; region applies to S3 remotes only"
    out = cli(s, "remote", "set", "origin", "region", "--unset", "--json")  # never set: nothing to do
    assert out.returncode == 0 and json.loads(out.stdout) == {"name": "origin"}
    assert cli(s, "remote", "set", "origin", "region", "eu-west-1").returncode == 0
    assert json.loads(cli(s, "remote", "set", "origin", "region", "--unset", "--json").stdout) == {"name": "origin"}


def test_both_moved_line_names_both_ids_the_base_and_both_displaced_refs():
    """Kills both_moved 2, 4, 9, 13, 17, 18. The theirs=None case (push's swap lost to a deletion) once
    named `displaced/<ref>/`, which is no ref name (found in issue 23's triage): it now says the ref was
    deleted there and names the one way on."""
    from artifacts.remotes.pointers import both_moved

    mine, theirs, last = ID_A, ID_B, ID_C
    line = both_moved("team/x", "origin", mine, theirs, last)
    assert line == (
        f"ref team/x: moved on both sides since {last[:12]}: this store has {mine[:12]}, remote origin has "
        f"{theirs[:12]}; `accrue pull --force origin team/x` takes the remote's (this store's kept as "
        f"ref displaced/team/x/{mine[:12]}), `accrue push --force origin team/x` sends this store's (the "
        f"remote's kept there as ref displaced/team/x/{theirs[:12]})"
    )
    gone = both_moved("team/x", "origin", mine, None, last)
    assert gone == (
        f"ref team/x: moved here to {mine[:12]} and deleted on remote origin since {last[:12]}; "
        "`accrue push --force origin team/x` puts this store's back there"
    )  # no displaced ref named for a remote side that has none (it was `displaced/team/x/`, not a ref name)
    never = both_moved("team/x", "origin", mine, None, None)
    assert "deleted on remote origin (this store never saw it there); " in never


def test_short_names_a_missing_id_nothing():
    """Kills short 2, 4, 5."""
    from artifacts.remotes.pointers import short

    assert short(None) == "nothing" and short("") == "nothing"
    assert short("0123456789abcdef") == "0123456789ab"
