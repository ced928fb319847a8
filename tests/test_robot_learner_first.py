"""The actor reaches its learner before the robot's first warmup episode (a learner on another host answers
Hello with the token, or nothing moves), and a learner this actor starts itself is started during warmup
(`accrue run`, `accrue stage run`), so that train's first episode does not wait for its start-up."""

from __future__ import annotations

import json
import time

import pytest
from robot_workflow import robot_events, run_stage, write_hw_workflow
from test_robot_learner_link import init_payload, wait_for

from stages.errors import StageError

pytestmark = pytest.mark.timeout(600)


def test_warmup_holds_before_its_first_episode_for_a_learner_that_never_answers(tmp_path):
    """Before: warmup ran every episode, and train then acted staleness_s of robot time before it held."""
    from artifacts.store import Store

    Store.init(tmp_path / "store")
    wf = write_hw_workflow(tmp_path / "hw.yaml", tmp_path / "calib")
    extra = {"learner_address": "127.0.0.1:1", "hold": {"staleness_s": 1.0, "wait_s": 2}}
    wf.write_text(wf.read_text() + "".join(f"  {k}: {json.dumps(v)}\n" for k, v in extra.items()))
    started = time.monotonic()
    with pytest.raises(StageError) as err:
        run_stage(tmp_path / "store", wf, 1, step="warmup")
    line = str(err.value)
    assert line.startswith("warmup: the learner at 127.0.0.1:1 never answered within robot.hold.wait_s 2 s")
    assert "nothing listens there (connection refused)" in line and "nothing moved" in line and "\n" not in line
    assert not robot_events(tmp_path / "store", "robot-episode-started")  # the robot never acted
    assert time.monotonic() - started < 120


def test_train_takes_the_learner_warmup_started(tmp_path, one_torch_thread):
    from accrue.robot import learner_client
    from accrue.robot.learner_client import LearnerLink, prestart_learner, take_spare

    spare = prestart_learner(dead_after_s=1.0)
    assert prestart_learner(dead_after_s=1.0) is spare  # one at a time
    spare.started.wait(300)
    assert spare.port is not None and spare.alive()
    time.sleep(3 * spare.KEEP_S)  # kept from taking itself for an orphan (its --orphan-after is 10 s)
    reports: list[tuple[str, dict]] = []
    link = LearnerLink(
        lambda: init_payload(tmp_path),
        lambda: [],
        lambda h, d: None,
        lambda line, fields: reports.append((line, dict(fields))),
        heartbeat_s=0.1,
        dead_after_s=1.0,
    )
    link.start()
    try:
        wait_for(link.healthy, 300, "the learner to answer")
        assert link.proc is spare.proc and link.address == f"127.0.0.1:{spare.port}"
        assert any("ahead of train" in line for line, _ in reports)
        assert take_spare() is None and not learner_client._SPARE  # taken: none left for another link
    finally:
        link.close()
    assert spare.proc.poll() is not None  # the link stopped it, as its own


def test_an_unclaimed_spare_learner_is_stopped():
    from accrue.robot.learner_client import drop_spare, prestart_learner

    spare = prestart_learner(dead_after_s=1.0)
    spare.started.wait(300)
    drop_spare()
    assert spare.proc.wait(timeout=30) is not None
