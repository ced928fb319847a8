"""Resume after any interruption of a hardware train step (simulated robot, scripted operator): `kill -9` of
the actor mid-episode, of the learner mid-update, and of both, each followed by `--continue` (or, for the
learner alone, by the actor restarting it): no sealed episode is lost or counted twice, the half-finished
episode is discarded and the log says so, and robot time, the 20-episode window and the sessions continue."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from robot_workflow import robot_events, run_stage, write_hw_workflow

pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]
ROOT = Path(__file__).resolve().parents[1]
STOP_AT_STEP = 241


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie child of ours counts as gone
        return os.waitpid(pid, os.WNOHANG) == (0, 0)
    except ChildProcessError:
        return True


def wait_for(check, timeout: float, what: str):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = check()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


_ACTORS: list[subprocess.Popen] = []  # every actor a test started, for kill_leftover_actors


@pytest.fixture(autouse=True)
def kill_leftover_actors():
    """An actor that stopped itself (SIGSTOP) stays stopped if a check fails before the test kills it: kill
    it and its learners after every test, so a failure leaves no frozen processes behind."""
    yield
    while _ACTORS:
        actor = _ACTORS.pop()
        if actor.poll() is None:
            for pid in children(actor.pid):
                if alive(pid):
                    os.kill(pid, signal.SIGKILL)
            actor.kill()
            actor.wait(timeout=60)


def start_actor(store: Path, wf: Path, stage: int) -> subprocess.Popen:
    env = {**os.environ, "ACCRUE_STORE": str(store), "OMP_NUM_THREADS": "1"}
    actor = subprocess.Popen(
        [sys.executable, "-m", "cli.main", "stage", "run", str(wf), "--stage", str(stage), "--step", "train"],
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    _ACTORS.append(actor)
    return actor


def stopped_mid_episode(actor: subprocess.Popen, store: Path, stage: int, after: int) -> int:
    """Wait until the actor has stopped itself at robot.faults.stop_at_step (a SIGSTOP inside a train
    episode: it stays there, so the kill lands exactly at that step however busy the machine is; issue 23:
    a polled 'episode in progress' could be sealed before the kill); the index of that episode."""
    _, status = os.waitpid(actor.pid, os.WUNTRACED)  # blocks until the child stops (or ends)
    assert os.WIFSTOPPED(status), f"the actor ended (wait status {status}) before its stop step"
    sealed = sealed_train(store, stage)
    started = [
        e["index"]
        for e in robot_events(store, "robot-episode-started")
        if e["stage"] == stage and e["phase"] == "train"
    ]
    assert len(sealed) >= after, f"only {len(sealed)} train episodes sealed before the stop step"
    assert started and started[-1] not in sealed, "the actor did not stop inside a train episode"
    return started[-1]


def learner_pids(store: Path, stage: int) -> list[int]:
    return [e["pid"] for e in robot_events(store, "robot-learner-started") if e["stage"] == stage]


def children(pid: int) -> list[int]:
    """The live processes whose parent is pid (from /proc: the learner an actor spawned shows there before
    it has started up far enough for its robot-learner-started event)."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue  # gone meanwhile
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


def actor_learners(actor: subprocess.Popen, store: Path, stage: int) -> list[int]:
    """The learner processes of a stopped actor: those it logged and its child processes."""
    return sorted(set(learner_pids(store, stage)) | set(children(actor.pid)))


def sealed_train(store: Path, stage: int) -> dict[int, dict]:
    return {
        e["index"]: e
        for e in robot_events(store, "robot-episode-sealed")
        if e["stage"] == stage and e["phase"] == "train"
    }


def curve_of(store: Path, result) -> dict:
    from artifacts.manifests import read_artifact, read_tree
    from artifacts.store import Store

    st = Store.open(store)
    entries = {e["path"]: e["id"] for e in read_tree(st, read_artifact(st, result.outputs["curve"])["content"])}
    return json.loads(st.read_bytes(entries["curve.json"]))


def check_resumed(store: Path, stage: int, before: dict[int, dict], killed: int, result) -> dict:
    curve = curve_of(store, result)
    indices = [e["index"] for e in curve["episodes"]]
    assert len(indices) == len(set(indices)) == len(sealed_train(store, stage))  # none counted twice
    assert set(before) <= set(indices)  # none lost
    for e in curve["episodes"]:
        if e["index"] in before:
            assert e["robot_time_s"] == pytest.approx(before[e["index"]]["robot_time_s"], abs=1e-3)
            assert e["success"] == before[e["index"]]["success"]
    assert curve["rl_robot_time_s"] == pytest.approx(sum(e["robot_time_s"] for e in curve["episodes"]))
    # the window runs over the sealed episodes of both sessions, in order
    labels = [e["success"] for e in curve["episodes"]]
    assert [e["window_success"] for e in curve["episodes"]] == [
        sum(labels[max(0, i - 19) : i + 1]) for i in range(len(labels))
    ]
    assert killed not in indices
    discarded = [e for e in robot_events(store, "robot-episode-discarded") if e["stage"] == stage]
    assert [e["index"] for e in discarded] == [killed]
    assert curve["sessions"][0]["ended"].startswith("interrupted") and curve["sessions"][-1]["ended"].startswith("stop")
    return curve


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    from artifacts.store import Store

    root = tmp_path_factory.mktemp("hwk")
    Store.init(root / "store")
    fast = write_hw_workflow(root / "fast.yaml", root / "calib", name="hwk")
    # the same workflow (same cache keys): only session settings differ - real time x4, a slower operator,
    # and the robot's fault stop_at_step: the actor stops itself (SIGSTOP) at that control step of its
    # train step. An episode has at most 80 control steps (the tasks' max_steps), so step 241 is inside
    # the 4th train episode or a later one: at least 3 are sealed when it stops
    slow = write_hw_workflow(
        root / "slow.yaml",
        root / "calib",
        name="hwk",
        clock=4,
        scripted="{delay_s: 0.2}",
        faults=f"{{stop_at_step: {STOP_AT_STEP}}}",
    )
    return root / "store", fast, slow


def test_kill_actor_mid_episode_then_learner_mid_update(setup, monkeypatch):
    from stages.steps import robot_env

    store, fast, slow = setup
    run_stage(store, fast, 1, step="warmup")
    actor = start_actor(store, slow, 1)
    killed = stopped_mid_episode(actor, store, 1, after=3)
    its_learners = actor_learners(actor, store, 1)
    assert its_learners, "the actor started no learner"
    actor.send_signal(signal.SIGKILL)
    actor.wait(timeout=60)
    before = sealed_train(store, 1)
    assert killed not in before
    for pid in its_learners:  # its learner notices and exits
        wait_for(lambda pid=pid: not alive(pid), 120, f"learner {pid} to exit after its actor died")

    old = set(learner_pids(store, 1))
    killed_learner = {}
    failures: list[BaseException] = []  # an assertion in the killer thread fails the test (issue 23)
    # the continued session (in this process) may not stop before the restarted learner has been killed,
    # reported lost and started again: its stop rule is held until then, so the "learner lost" checks
    # below always run (issue 23: they were skipped when the stage ended too soon after the kill)
    cycle_done = threading.Event()
    stop_state = robot_env.stop_state

    def held_stop_state(session, c):
        done, why = stop_state(session, c)
        if done and not cycle_done.is_set():
            return False, ""
        return done, why

    monkeypatch.setattr(robot_env, "stop_state", held_stop_state)
    # the restart takes seconds of wall time, many more of robot time at the fast clock: past
    # robot.hold.staleness_s the actor would hold and discard an episode (tests/test_robot_hold.py covers
    # that); a session setting, so the cache keys stay those of `fast`
    unheld = fast.with_name("fast-unheld.yaml")
    unheld.write_text(fast.read_text().replace("robot:\n", "robot:\n  hold: {staleness_s: 1000000}\n", 1))
    since = max([e["seq"] for e in robot_events(store)], default=0)

    def kill_learner_mid_update():
        try:
            kill_when_updating()
        except BaseException as exc:  # noqa: BLE001 - re-raised in the test's thread after join
            failures.append(exc)
        finally:
            cycle_done.set()  # on a failure too: the session stops and the failure is raised below

    def kill_when_updating():
        def updating():  # the restarted learner has sealed a checkpoint: it is training
            new = [p for p in learner_pids(store, 1) if p not in old]
            trained = [
                e
                for e in robot_events(store, "robot-learner-checkpoint")
                if e["stage"] == 1 and e["seq"] > since and e["updates"] > 0
            ]
            return new[-1] if new and trained else None

        pid = wait_for(updating, 300, "the restarted learner to train")
        at_kill = max(e["seq"] for e in robot_events(store))
        os.kill(pid, signal.SIGKILL)
        killed_learner["pid"] = pid

        def lost():
            return [e for e in robot_events(store, "robot-learner-lost") if e["stage"] == 1 and e["seq"] > at_kill]

        wait_for(lost, 300, "the dead learner to be reported lost")
        wait_for(
            lambda: [p for p in learner_pids(store, 1) if p not in old and p != pid],
            300,
            "the learner to be started again",
        )

    thread = threading.Thread(target=kill_learner_mid_update, daemon=True)
    thread.start()
    try:
        result = run_stage(store, unheld, 1, step="train", mode="continue")["train"]
    finally:
        cycle_done.set()  # the killer's waits end by their own timeouts at worst
        thread.join(timeout=330)
    assert not thread.is_alive()
    if failures:
        raise failures[0]
    assert killed_learner, "the restarted learner was never killed"
    assert not alive(killed_learner["pid"])
    curve = check_resumed(store, 1, before, killed, result)
    assert curve["stopped"].startswith("stop rule")
    lost = [e for e in robot_events(store, "robot-learner-lost") if e["stage"] == 1 and e["seq"] > since]
    assert lost, "the dead learner was not reported"
    restarted = [p for p in learner_pids(store, 1) if p not in old and p != killed_learner["pid"]]
    assert restarted, "the learner was not started again"


def test_kill_both_then_continue(setup):
    store, fast, slow = setup
    run_stage(store, fast, 1)  # the rest of stage 1 (its train step is done)
    run_stage(store, fast, 2, step="warmup")
    actor = start_actor(store, slow, 2)
    killed = stopped_mid_episode(actor, store, 2, after=2)
    pids = actor_learners(actor, store, 2)
    assert pids, "the actor started no learner"
    for pid in pids:
        if alive(pid):
            os.kill(pid, signal.SIGKILL)
    actor.send_signal(signal.SIGKILL)
    actor.wait(timeout=60)
    before = sealed_train(store, 2)
    result = run_stage(store, fast, 2, step="train", mode="continue")["train"]
    check_resumed(store, 2, before, killed, result)
