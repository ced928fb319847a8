"""A learner restart loses nothing it need not: the local learner the actor started is killed (-9) after
publishing a checkpoint; the one started in its place resumes from that checkpoint (its update count
continues from it, not from the stage start the init payload holds) and numbers its weights above every
version the link has exposed, so each version the episode records name is one set of weights."""

from __future__ import annotations

import json
import os
import signal

import pytest
from test_robot_learner_link import episode, init_payload, wait_for

pytestmark = [pytest.mark.timeout(1200), pytest.mark.slow]


def test_a_killed_local_learner_resumes_with_unique_versions_and_its_update_count(tmp_path, one_torch_thread):
    from accrue.robot.learner_client import LearnerLink

    sealed: list[tuple[dict, bytes]] = []
    snapshots: list[dict] = []  # every set of weights the actor received, in order
    reports: list[str] = []

    def on_snapshot(h, d):
        saved = json.loads((d / "learner.json").read_text())
        snapshots.append(
            dict(
                version=h["version"],
                updates=h["updates"],
                checkpoint=h.get("checkpoint"),
                saved=saved,
                pid=link.learner_pid,
            )
        )

    link = LearnerLink(  # no address: the link starts the learner process itself
        lambda: init_payload(tmp_path),  # always the stage start: updates 0, version 0
        lambda: list(sealed),
        on_snapshot,
        lambda line, fields: reports.append(fields.get("event", line)),
        heartbeat_s=0.1,
        dead_after_s=1.0,
    )
    link.start()
    try:
        for i in range(3):
            sealed.append(({"index": i, "relabel": False}, episode(i)))
            link.push(*sealed[-1])
        # 3 episodes x 5 chunks, utd 1: 15 updates; checkpoints at 4, 8, 12 (the learner publishes a snapshot
        # with its checkpoint mark at once: a Pull in between used to get the one at 12 unmarked - see
        # test_a_pull_between_any_two_trainer_writes_gets_every_checkpoint_marked)
        wait_for(lambda: any(s["checkpoint"] and s["updates"] >= 12 for s in snapshots), 400, "a checkpoint")
        first = link.proc.pid
        backs = reports.count("robot-learner-back")  # a heartbeat missed under load can report one earlier
        os.kill(first, signal.SIGKILL)
        wait_for(
            lambda: link.proc.pid != first and reports.count("robot-learner-back") > backs,
            400,
            "the learner to restart",
        )
        sealed.append(({"index": 3, "relabel": False}, episode(3)))
        link.push(*sealed[-1])
        wait_for(lambda: snapshots and snapshots[-1]["updates"] >= 20, 400, "training on after the restart")
    finally:
        link.close()
    before = [s for s in snapshots if s["pid"] == first]
    after = [s for s in snapshots if s["pid"] != first]
    assert after and snapshots == before + after, "no weights from the restarted learner"
    checkpoint = max(s["updates"] for s in before if s["checkpoint"])
    versions = [s["version"] for s in snapshots]
    assert versions == sorted(set(versions)), f"versions repeat or go back: {versions}"
    assert all(s["saved"]["version"] == s["version"] for s in snapshots)  # the saved learner says the same
    # the restarted learner starts from the last checkpoint, not from update 0
    assert min(s["updates"] for s in after) >= checkpoint >= 12
    assert link.version == versions[-1] and link.updates == snapshots[-1]["updates"]
