"""A learner that refuses the actor (a wrong link token, or TLS) ends the robot's hold at once.

Waiting cannot bring such a learner back: before the fix the actor held for robot.hold.wait_s and then
said "the learner did not come back", which names the wrong thing to fix. Now the hold ends at the first
look, in one line naming the refusal, with every sealed episode kept once (a --continue finds them)."""

from __future__ import annotations

import pytest
from robot_workflow import run_stage
from test_robot_hold import fake_link, hold_workflow, store, train_events, use_link, warm_store  # noqa: F401

from stages.errors import StageError

pytestmark = pytest.mark.timeout(600)
LINE = (
    "the learner at 127.0.0.1:50051 refused this actor's link token: start the learner with this token "
    "(`accrue robot token --out FILE` here, then --token-file FILE there) or set robot.link.token_file"
)


def refusing_link():
    """fake_link's learner, which after the first train episode refuses the actor (LearnerLink.refused)."""
    from accrue.robot.transport import LinkRefused

    class Refusing(fake_link(down_after=1)):
        refused = None

        def push(self, header, blob):
            super().push(header, blob)
            if not self.up:
                self.refused = LinkRefused(LINE, "token")

    return Refusing


def test_a_refused_link_ends_the_hold_at_once_in_one_line(store, monkeypatch):  # noqa: F811
    use_link(monkeypatch, store / "store", refusing_link())
    # a wait the test would notice: the old code held all of it, then blamed an unreachable learner
    wf = hold_workflow(store / "hw.yaml", store / "calib", hold={"staleness_s": 1.0, "wait_s": 120})
    with pytest.raises(StageError) as err:
        run_stage(store / "store", wf, 1, step="train")
    line = str(err.value)
    assert "\n" not in line and LINE in line and "--continue" in line and "did not come back" not in line
    [ended] = train_events(store / "store", "robot-hold-ended")
    assert ended["outcome"] == "refused" and ended["held_s"] < 60
    assert [e["how"] for e in train_events(store / "store", "robot-session-ended")] == [f"held: {LINE}"]
    sealed = train_events(store / "store", "robot-episode-sealed")
    assert sealed and len({e["index"] for e in sealed}) == len(sealed)

    use_link(monkeypatch, store / "store", fake_link())  # the token fixed: the session goes on from them
    run_stage(store / "store", wf, 1, step="train", mode="continue")
    started = train_events(store / "store", "robot-session-started")
    assert started[-1]["sealed"] == len(sealed)
    indices = [e["index"] for e in train_events(store / "store", "robot-episode-sealed")]
    assert len(indices) == len(set(indices)) > len(sealed)  # nothing sealed twice
