"""Issue 21 item 4: clean stops of a hardware session.

Ctrl-C or SIGTERM: the episode in progress is discarded as at a kill, the robot disconnected, the session
closed as "stopped by operator (Ctrl-C)" / "stopped by signal (SIGTERM)", one line, exit 130 / 143, the
learner exits quietly; a second Ctrl-C forces. Before the fix Ctrl-C gave exit 130 with no line from the
actor and ~35 lines of tracebacks from the learner, SIGTERM killed the actor without disconnecting the
robot, and the session said "running" until the next resume.

The in-process tests send the signal from the operator's poll at a chosen chunk of a chosen episode (the
handler runs in the main thread, as for a person's Ctrl-C); the slow ones run `accrue stage run` with its
own learner and signal it as a terminal does, once its learner has delivered weights."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from robot_workflow import robot_events, run_stage
from test_robot_hold import fake_link, hold_workflow, train_events, use_link

from stages.steps.robot_session import SessionStop

pytestmark = pytest.mark.timeout(600)
ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def base_store(tmp_path_factory):
    """A store with stage 1's finetune-base done (every test's warmup and train start from it)."""
    from artifacts.store import Store

    root = tmp_path_factory.mktemp("stops-base")
    Store.init(root / "store")
    run_stage(root / "store", hold_workflow(root / "hw.yaml", root / "calib"), 1, step="finetune-base")
    return root


@pytest.fixture
def store(base_store, tmp_path):
    shutil.copytree(base_store / "store", tmp_path / "store")
    return tmp_path


def signalling_operator(monkeypatch, sig: int, episode: int, chunk: int = 2, again_on_close: bool = False):
    """The scripted operator, plus `sig` sent to this process at `chunk` of `episode` (and, with
    again_on_close, a second one while the session is being cleaned up)."""
    from accrue.robot import operator as operator_module

    class Signalling(operator_module.ScriptedOperator):
        def wait_reset(self, index, task, last):
            self._at = (index, 0)
            return super().wait_reset(index, task, last)

        def poll(self):
            index, n = self._at
            self._at = (index, n + 1)
            if index == episode and n + 1 == chunk:
                os.kill(os.getpid(), sig)
            return super().poll()

        def close(self):
            if again_on_close:
                os.kill(os.getpid(), sig)
            super().close()

    monkeypatch.setattr(operator_module, "ScriptedOperator", Signalling)


def attempts(store: Path, step: str) -> list[dict]:
    from artifacts.records import list_attempts
    from artifacts.store import Store

    return [a for a in list_attempts(Store.open(store), problems=[]) if a["step"] == step]


def test_ctrl_c_discards_the_episode_disconnects_and_closes_the_session(store, monkeypatch):
    before = signal.getsignal(signal.SIGINT)
    signalling_operator(monkeypatch, signal.SIGINT, episode=1)
    wf = hold_workflow(store / "hw.yaml", store / "calib")
    with pytest.raises(SessionStop) as err:
        run_stage(store / "store", wf, 1, step="warmup")
    stop = err.value
    assert stop.code == 130 and not stop.forced
    assert str(stop).startswith("warmup: stopped by operator (Ctrl-C); episode 1 discarded, 1 episodes sealed")
    assert "\n" not in str(stop)
    events = robot_events(store / "store")
    names = [e["event"] for e in events]
    [discarded] = [e for e in events if e["event"] == "robot-episode-discarded"]
    assert discarded["index"] == 1 and discarded["reason"].startswith("stopped by operator (Ctrl-C)")
    [ended] = [e for e in events if e["event"] == "robot-session-ended"]
    assert ended["how"] == "stopped by operator (Ctrl-C)" and ended["episodes"] == 1
    assert "robot-disconnected" in names
    assert [a["state"] for a in attempts(store / "store", "warmup")] == ["abandoned"]
    assert signal.getsignal(signal.SIGINT) is before  # the session's handlers are gone with it
    # resumed: the stopped session is on record as stopped (not "interrupted"), episode 1 told once
    monkeypatch.undo()
    run_stage(store / "store", wf, 1, step="warmup", mode="continue")
    events = robot_events(store / "store")
    assert [e["index"] for e in events if e["event"] == "robot-episode-discarded"] == [1]
    assert len([e for e in events if e["event"] == "robot-episode-sealed"]) == 3
    from artifacts.store import Store
    from stages.steps.robot_status import robot_status
    from stages.workflow import load_workflow

    [row] = [r for r in robot_status(Store.open(store / "store"), load_workflow(wf)) if r["step"] == "warmup"]
    assert [s["ended"] for s in row["sessions"]][0] == "stopped by operator (Ctrl-C)"


def test_sigterm_stops_train_cleanly_with_exit_143(store, monkeypatch):
    link = use_link(monkeypatch, store / "store", fake_link())
    wf = hold_workflow(store / "hw.yaml", store / "calib")
    run_stage(store / "store", wf, 1, step="warmup")
    signalling_operator(monkeypatch, signal.SIGTERM, episode=4, chunk=3)  # the second train episode
    with pytest.raises(SessionStop) as err:
        run_stage(store / "store", wf, 1, step="train")
    assert err.value.code == 143
    assert str(err.value).startswith("train: stopped by signal (SIGTERM); episode 4 discarded, 1 episodes sealed")
    assert link.last.closed
    [ended] = train_events(store / "store", "robot-session-ended")
    assert ended["how"] == "stopped by signal (SIGTERM)"
    assert train_events(store / "store", "robot-disconnected")
    assert [e["index"] for e in train_events(store / "store", "robot-episode-discarded")] == [4]


def test_a_second_ctrl_c_forces(store, monkeypatch):
    signalling_operator(monkeypatch, signal.SIGINT, episode=0, again_on_close=True)
    wf = hold_workflow(store / "hw.yaml", store / "calib")
    with pytest.raises(SessionStop) as err:
        run_stage(store / "store", wf, 1, step="warmup")
    assert err.value.forced and err.value.code == 130
    assert "(forced)" in str(err.value) and "episode 0 discarded" in str(err.value)
    [ended] = robot_events(store / "store", "robot-session-ended")
    assert ended["how"] == "stopped by operator (Ctrl-C)"


# ------------------------------------------------------------------------------------ `accrue stage run`


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def wait_for(check, timeout: float, what: str):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = check()
        if value:
            return value
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {what}")


def actor_with_learner(store: Path) -> tuple[subprocess.Popen, int, Path]:
    """`accrue stage run --step train` in its own process group, its learner started and delivering weights
    (a train episode sealed with weights from it); the process, its learner's pid and the file holding
    their stderr (the learner's is the actor's)."""
    wf = hold_workflow(
        store / "hw.yaml",
        store / "calib",
        max_episodes=1000,
        scripted={"mistakes": list(range(400))},  # never 19/20: the session runs until it is stopped
        hold={"staleness_s": 30, "wait_s": 300},
    )
    run_stage(store / "store", wf, 1, step="warmup")
    env = {**os.environ, "ACCRUE_STORE": str(store / "store"), "OMP_NUM_THREADS": "1"}
    log = store / "actor.err"
    with log.open("w") as err:  # a file, not a pipe: nothing blocks the actor's output
        proc = subprocess.Popen(
            [sys.executable, "-m", "cli.main", "stage", "run", str(wf), "--stage", "1", "--step", "train"],
            cwd=ROOT,
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=err,
            start_new_session=True,  # a process group of its own, as a terminal's foreground job
        )
    [pid] = wait_for(lambda: [e["pid"] for e in train_events(store / "store", "robot-learner-started")], 300, "learner")
    wait_for(
        lambda: any(
            (e.get("weights_version") or 0) >= 1 for e in train_events(store / "store", "robot-episode-sealed")
        ),
        300,
        "an episode acted with the learner's weights",
    )
    return proc, pid, log


@pytest.mark.slow
def test_ctrl_c_at_the_terminal_one_line_exit_130_and_a_quiet_learner(store):
    proc, learner, log = actor_with_learner(store)
    os.killpg(proc.pid, signal.SIGINT)  # what the terminal does: the whole foreground group
    proc.wait(timeout=120)
    wait_for(lambda: not alive(learner), 30, "the learner to exit")
    err = log.read_text()
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "cannot schedule new futures" not in err, err
    stops = [line for line in err.splitlines() if "stopped by operator (Ctrl-C)" in line]
    assert len(stops) == 1 and stops[0].startswith("train: stopped by operator (Ctrl-C)"), err
    assert err.rstrip().splitlines()[-1] == stops[0]  # the last word is that line
    [ended] = train_events(store / "store", "robot-session-ended")
    assert ended["how"] == "stopped by operator (Ctrl-C)"
    assert train_events(store / "store", "robot-disconnected")
