"""Partial clones: `pull --only handoff` brings every manifest and record but leaves the data of
other kinds on the remote; a step that needs it fetches it then, verified."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from remote_support import cli, make_store, moto_endpoint, overwrite_remote_key, remote_url, s3_env, user_refs  # noqa: E402,F401
from test_cli_store import one_line_error  # noqa: E402
from test_runner_support import count_invocation  # noqa: E402

from artifacts.store import Store  # noqa: E402


def robot_with_checkpoint(tmp_path: Path, url: str) -> tuple[Path, str]:
    robot = tmp_path / "robot"
    make_store(robot)
    ckpt = tmp_path / "ckpt"
    ckpt.mkdir()
    (ckpt / "seed.txt").write_text("5")
    (ckpt / "weights.bin").write_bytes(os.urandom(200_000))
    ckpt_id = cli(robot, "add", str(ckpt), "--kind", "checkpoint", "--ref", "team/ckpt").stdout.strip()
    cli(robot, "remote", "add", "origin", url)
    assert cli(robot, "push").returncode == 0
    return robot, ckpt_id


def content_ids(store: Path, ref: str) -> list[str]:
    """The data objects of the artifact a ref (or REF:role) names."""
    manifest = json.loads(cli(store, "show", ref, "--json").stdout)
    if manifest["layout"] == "file":
        return [manifest["content"]]
    return [e["id"] for e in Store.open(store).read_json(manifest["content"])["entries"]]


def test_pull_only_handoff_then_a_step_fetches_what_it_needs(tmp_path, remote_url):
    from rich.console import Console

    from stages.runner import Runner
    from stages.runner_types import StagePlan

    robot, ckpt_id = robot_with_checkpoint(tmp_path, remote_url)
    lab = tmp_path / "laptop"
    cli(lab, "init")
    cli(lab, "remote", "add", "origin", remote_url)
    pulled = json.loads(cli(lab, "pull", "--only", "handoff", "--json").stdout)
    st = Store.open(lab)
    assert user_refs(lab) == user_refs(robot)
    assert all(st.has_object(o) for o in content_ids(lab, "team/handoff"))
    # left behind: the replay file, the checkpoint's two files, the step's (non-handoff) result
    left = (
        content_ids(lab, "team/replay")
        + content_ids(lab, "team/ckpt")
        + content_ids(lab, "workflow/wf/stage/1/train:result")
    )
    assert pulled["promised"] == len(set(left)) >= 4
    assert not any(st.has_object(o) for o in left)
    # auditable as it is: lineage, show, and verify (quick and full) pass on the partial clone
    ref = "workflow/wf/stage/1/train:result"
    assert cli(lab, "lineage", ref).stdout == cli(robot, "lineage", ref).stdout
    assert cli(lab, "verify").returncode == 0 and cli(lab, "verify", "--full").returncode == 0
    assert "partial clone" in cli(lab, "remote", "list").stdout
    assert f"still holds {len(set(left))} object(s)" in one_line_error(cli(lab, "remote", "remove", "origin"))

    # a step whose input is the checkpoint materialises it: the hook fetches it, verified
    runner = Runner(Store.open(lab), console=Console(file=open(os.devnull, "w")))
    [result] = runner.run_plan(StagePlan("wf2", 1, (count_invocation(3, seed=9, inputs={"seed": ckpt_id}),)))
    assert result.record_id and all(Store.open(lab).has_object(o) for o in content_ids(lab, "team/ckpt"))
    assert not any(Store.open(lab).has_object(o) for o in content_ids(lab, "team/replay"))
    # a plain pull completes the clone
    still_missing = {o for o in left if not Store.open(lab).has_object(o)}
    assert still_missing and json.loads(cli(lab, "pull", "--json").stdout)["objects_received"] == len(still_missing)
    assert all(Store.open(lab).has_object(o) for o in left)
    assert cli(lab, "remote", "remove", "origin").returncode == 0


def test_a_lazy_fetch_refuses_a_corrupt_object_and_without_the_remote_it_is_missing(tmp_path, remote_url):
    robot, ckpt_id = robot_with_checkpoint(tmp_path, remote_url)
    lab = tmp_path / "laptop"
    cli(lab, "init")
    cli(lab, "remote", "add", "origin", remote_url)
    cli(lab, "pull", "--only", "handoff")
    [replay] = content_ids(lab, "team/replay")
    good = Store.open(robot).read_bytes(replay)
    overwrite_remote_key(remote_url, f"objects/blake3/{replay[:2]}/{replay[2:]}", good[:-10])
    line = one_line_error(cli(lab, "show", replay))
    assert f"object {replay[:12]} arrived truncated ({len(good) - 10} of" not in line  # sizes unknown here
    assert f"object {replay[:12]} arrived corrupt 3 times; refused" in line
    assert not Store.open(lab).has_object(replay)
    # forced removal of the promisor: the object is then plainly missing, and verify says so
    assert cli(lab, "remote", "remove", "origin", "--force").returncode == 0
    assert one_line_error(cli(lab, "show", replay)) == f"error: object {replay[:12]} is missing from the store"
    out = cli(lab, "verify")
    assert out.returncode == 1 and f"missing object {replay[:12]}" in out.stdout


def test_the_readme_flow_robot_learner_auditor(tmp_path):
    """docs/sharing.md's walk-through, with a directory remote and a tiny plan standing in for `accrue run`."""
    from rich.console import Console

    from stages.runner import Runner
    from stages.runner_types import StagePlan

    nas = tmp_path / "mnt" / "nas"
    nas.mkdir(parents=True)
    robot, learner, laptop = tmp_path / "robot", tmp_path / "learner", tmp_path / "laptop"
    for store in (robot, learner, laptop):
        cli(store, "init")
        made = ["--create"] if store == robot else []  # the robot makes the remote; the others find it
        assert cli(store, "remote", "add", "origin", str(nas / "accrue"), *made).returncode == 0
    day = tmp_path / "episodes" / "2026-12-01"
    day.mkdir(parents=True)
    (day / "seed.txt").write_text("4")
    (day / "ep-0000.bin").write_bytes(os.urandom(50_000))
    episodes = cli(robot, "add", str(day), "--kind", "episodes", "--ref", "robot/episodes/day1").stdout.strip()
    assert cli(robot, "push").returncode == 0

    assert cli(learner, "pull", "origin", "robot/episodes").returncode == 0
    Runner(Store.open(learner), console=Console(file=open(os.devnull, "w"))).run_plan(
        StagePlan("quickstart", 1, (count_invocation(3, seed=4, inputs={"seed": episodes}),))
    )
    assert cli(learner, "push", "origin", "workflow/quickstart").returncode == 0

    assert cli(laptop, "pull", "origin", "workflow/quickstart", "--only", "handoff").returncode == 0
    ref = "workflow/quickstart/stage/1/train:result"
    assert cli(laptop, "lineage", ref).stdout == cli(learner, "lineage", ref).stdout
    assert "episodes" in cli(laptop, "lineage", ref).stdout
    assert cli(laptop, "verify", "--remote", "origin").returncode == 0
    assert cli(laptop, "verify").returncode == 0
