"""The robot path's parts on their own: the observation/action mapping, the safety envelope, rewards from
operator labels, the scripted operator, the transport, the simulated lerobot robot behind the bridge with
injected faults (disconnect, late observation, dropped commands), and the learner service's RPCs."""

from __future__ import annotations

import numpy as np
import pytest

from accrue.errors import AccrueError
from accrue.robot.episode import chunk_rewards, relabelled
from accrue.robot.mapping import RobotMapping
from accrue.robot.operator import ScriptedOperator
from accrue.robot.safety import SafetyEnvelope
from accrue.robot.transport import pack, unpack
from accrue.sim import STATE_NAMES
from accrue.sim.observation import IDX


def test_mapping_takes_the_robots_declared_features():
    """q = the scalar observations as declared (not the simulator's 29), I = its cameras, a = its action keys."""
    so101 = {f"{j}.pos": float for j in ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll")}
    so101 |= {"gripper.pos": float, "wrist": (48, 64, 3), "front": (48, 64, 3)}
    actions = {k: float for k in so101 if k.endswith(".pos")}
    bounds = [(-100.0, 100.0)] * 5 + [(0.0, 100.0)]
    m = RobotMapping(action_mode="joint", action_bounds=tuple(bounds)).bind(so101, actions, "robot so101")
    assert m.state_keys == tuple(actions) and m.camera_keys == ("wrist", "front") and m.action_keys == tuple(actions)
    obs = {k: float(i) for i, k in enumerate(actions)} | {"wrist": np.ones((48, 64, 3)), "front": np.zeros((48, 64, 3))}
    assert m.state(obs).tolist() == [0, 1, 2, 3, 4, 5]
    assert [f.shape for f in m.images(obs)] == [(48, 64, 3)] * 2 and m.images(obs)[0].dtype == np.uint8
    # joint targets: a in [-1, 1] spread over [lo, hi]; the inverse takes recorded targets back
    sent = m.action(np.array([1, -1, 0, 0.5, 2.0, 0]))
    assert list(sent.values()) == pytest.approx([100, -100, 0, 50, 100, 50])
    assert m.normalise(np.array([list(sent.values())])) == pytest.approx(np.array([[1, -1, 0, 0.5, 1, 0]]))
    picked = RobotMapping(
        state_keys=("gripper.pos",), camera_keys=("front",), action_mode="joint", action_bounds=tuple(bounds)
    )
    assert picked.bind(so101, actions, "r").state(obs).tolist() == [5.0]
    with pytest.raises(AccrueError, match="observation has no 'ee_x_cm'"):
        RobotMapping(state_keys=("ee_x_cm",)).bind(so101, actions, "robot so101")
    with pytest.raises(AccrueError, match="action_mode joint needs one \\[lo, hi\\] per action key"):
        RobotMapping(action_mode="joint").bind(so101, actions, "robot so101")
    five = RobotMapping().bind(so101, dict(list(actions.items())[:5]), "robot so101")  # any width: chunks H x 5
    assert five.action_dim == 5 and len(five.action(np.ones(5))) == 5
    with pytest.raises(AccrueError, match="declares no action key"):
        RobotMapping().bind(so101, {}, "robot so101")


def test_mapping_scales_end_effector_deltas():
    keys = ("x", "y", "z", "r", "p", "w")
    m = RobotMapping(action_limits=(0.002, 0.002, 0.001, 0.05, 0.05, 0.05), done_key="end").bind(
        {"a": float, "end": float}, {k: float for k in keys}, "r"
    )
    assert m.state_keys == ("a",) and m.done({"end": 1.0})  # the done flag is not part of q
    sent = m.action(np.array([1, -1, 0.5, 2.0, 0, 0]))  # clipped to [-1, 1], then scaled
    assert sent == pytest.approx({"x": 0.002, "y": -0.002, "z": 0.0005, "r": 0.05, "p": 0.0, "w": 0.0})


def test_action_envelope_clips_to_joint_bounds_and_rate_limits():
    from accrue.robot.safety import ActionEnvelope

    env = ActionEnvelope.from_dict({"joint_bounds": {"a": [-10, 10]}, "max_step": {"a": 2.0, "b": 0.5}})
    sent, changed = env.limit({"a": 30.0, "b": 1.0, "c": 7.0}, {"a": 9.0, "b": 0.0})
    assert sent == {"a": 10.0, "b": 0.5, "c": 7.0} and changed == ["a", "b"]
    assert env.limit({"a": 1.0, "b": 0.2}, {"a": 0.0, "b": 0.0}) == ({"a": 1.0, "b": 0.2}, [])
    with pytest.raises(AccrueError, match="'zz' is not one of the robot's action keys"):
        ActionEnvelope.from_dict({"max_step": {"zz": 1.0}}).check_keys(("a", "b"))
    with pytest.raises(AccrueError, match="needs hi > lo"):
        ActionEnvelope.from_dict({"joint_bounds": {"a": [1, 0]}})


def test_safety_envelope_names_the_limit():
    env = SafetyEnvelope.from_dict(
        {
            "workspace_min_m": [-0.05, -0.05, -0.02],
            "workspace_max_m": [0.05, 0.05, 0.05],
            "max_speed_m_s": 0.1,
            "max_force_n": 30.0,
        }
    )
    s = np.zeros(len(STATE_NAMES), np.float32)
    assert env.violation(s) is None
    s[IDX["ee_z_cm"]] = 6.0  # 6 cm: above the 5 cm ceiling
    assert "workspace: end effector z = 60.0 mm is above" in env.violation(s)
    s[IDX["ee_z_cm"]] = 0.0
    s[IDX["wrist_fz"]] = 4.0  # 40 N (the state holds N / 10)
    assert env.violation(s).startswith("wrist force: 40.0 N exceeds")
    assert SafetyEnvelope().violation(s) is None  # no sensor limits: nothing checked
    joints = ("shoulder_pan.pos", "gripper.pos")
    with pytest.raises(AccrueError, match="safety.workspace: the robot's state has no 'ee_x_cm'"):
        env.check_names(joints)  # an arm reporting joints only cannot be held to a Cartesian box
    SafetyEnvelope().check_names(joints)


def test_rewards_follow_the_label_on_the_last_three_steps():
    steps = np.array([4, 4, 2])
    assert chunk_rewards(steps, False, 0.9).tolist() == [0, 0, 0]
    r = chunk_rewards(steps, True, 0.9)  # steps 7, 8, 9 of 10 carry reward 1
    assert r[0] == 0 and r[1] == pytest.approx(0.9**3) and r[2] == pytest.approx(1 + 0.9)
    arrays = {"steps": steps, "action": np.zeros((3, 4, 6)), "reward": r, "done": np.array([0, 0, 1], bool)}
    fixed = relabelled(arrays, False, 0.9)
    assert fixed["reward"].sum() == 0 and not fixed["done"].any()


def test_scripted_operator_labels_from_the_oracle_with_mistakes_and_corrections():
    truth = {"v": True}
    resets = []
    op = ScriptedOperator(
        oracle=lambda: truth["v"], reset_scene=lambda: resets.append(1), name="ann", mistakes={2, 5}, corrects={2}
    )
    assert op.wait_reset(1, "t", None).go and resets == [1]
    assert op.label(1, "").success is True
    wrong = op.label(2, "")
    assert wrong.success is False and wrong.by == "ann" and wrong.at
    answer = op.wait_reset(3, "t", 2)
    assert answer.relabel is not None and answer.relabel.success is True
    assert op.label(5, "").note.startswith("deliberate mistake") and op.wait_reset(6, "t", 5).relabel is None
    assert ScriptedOperator(oracle=lambda: True, abort_before=4).wait_reset(4, "t", 3).go is False


def test_transport_round_trip():
    head, blob = unpack(pack({"a": 1, "b": [1, 2]}, b"\x00\x01payload"))
    assert head == {"a": 1, "b": [1, 2]} and blob == b"\x00\x01payload"


# ------------------------------------------------------------------ the simulated robot (imports lerobot)
@pytest.fixture(scope="module")
def sim_factory(tmp_path_factory):
    from accrue.robot.bridge import robot_factory

    calib = tmp_path_factory.mktemp("calib")

    def make(**faults):
        return robot_factory("accrue_sim", {"task": "nist/rect_peg", "calibration_dir": str(calib), **faults})

    return make


def test_fault_schedules_belong_to_the_arm_a_config_describes(tmp_path):
    """A driver rebuilt from the same config talks to the same arm (its fault does not fire again); a new
    config is a new arm with a fresh schedule, even one equal in every field (a schedule keyed by id(config)
    once gave a later step's config a dead config's spent count, and that step never faulted)."""
    from lerobot.utils.errors import DeviceNotConnectedError

    from accrue.robot.sim_robot.accrue_sim import AccrueSim
    from accrue.robot.sim_robot.config_accrue_sim import AccrueSimConfig
    from accrue.sim.observation import ACTION_NAMES

    zero = {n: 0.0 for n in ACTION_NAMES}

    def faults_within(config, steps: int) -> bool:
        robot = AccrueSim(config)
        robot.connect()
        try:
            for _ in range(steps):
                robot.send_action(zero)
        except DeviceNotConnectedError:
            return True
        return False

    first = AccrueSimConfig(calibration_dir=tmp_path, disconnect_after_steps=2)
    assert faults_within(first, 2)
    assert not faults_within(first, 5)  # rebuilt driver, same arm: the fault already fired
    assert faults_within(AccrueSimConfig(calibration_dir=tmp_path, disconnect_after_steps=2), 2)


def test_sim_robot_is_a_registered_lerobot_robot(sim_factory):
    from lerobot.robots.config import RobotConfig
    from lerobot.robots.robot import Robot

    robot = sim_factory()()
    assert "accrue_sim" in RobotConfig.get_known_choices()
    assert isinstance(robot, Robot)
    assert set(STATE_NAMES) <= set(robot.observation_features) and len(robot.action_features) == 6
    with pytest.raises(AccrueError, match="unknown lerobot robot type 'no_such_arm'"):
        from accrue.robot.bridge import robot_factory

        robot_factory("no_such_arm", {})
    with pytest.raises(AccrueError, match="robot.config: not a valid AccrueSimConfig"):
        robot_factory("accrue_sim", {"no_such_field": 1})


def test_bridge_faults_end_in_robot_faults_never_hangs(sim_factory):
    import time

    from accrue.robot.bridge import RobotBridge, RobotFault, Timeouts
    from accrue.robot.episode import EpisodeSettings, run_episode
    from accrue.robot.sim_robot import DONE_KEY

    class NoLog:
        def start(self, *a, **k):
            pass

        def log_step(self, *a, **k):
            pass

    mapping = RobotMapping(done_key=DONE_KEY)
    settings = EpisodeSettings(horizon=4, max_steps=40, control_hz=20.0, clock=0)
    identity = lambda obs: obs["state"]  # noqa: E731
    zero_ref = lambda obs: np.zeros((len(obs["state"]), 4, 6), np.float32)  # noqa: E731
    execute = lambda s, ref, fresh: ref  # noqa: E731

    # disconnect at step 6: the episode ends as a fault after 5 executed steps, then reconnects
    bridge = RobotBridge(sim_factory(disconnect_after_steps=6), mapping, Timeouts(observation_s=0.5))
    bridge.connect()
    out = run_episode(bridge, settings, zero_ref, execute, identity, NoLog(), {})
    assert out.end == "fault" and "disconnected" in out.reason and not out.can_succeed
    assert out.control_steps == 5 and out.steps.sum() == 4 and len(out.s) == len(out.action) + 1
    assert bridge.reconnect()
    assert bridge.observe()[0].shape == (29,)

    # an observation later than the deadline: a timeout fault within the deadline, not a hang
    bridge = RobotBridge(
        sim_factory(late_observation_steps=[3], late_by_s=3.0),
        mapping,
        Timeouts(observation_s=0.3, reconnect_wait_s=0.0),
    )
    bridge.connect()
    started = time.monotonic()
    out = run_episode(bridge, settings, zero_ref, execute, identity, NoLog(), {})
    assert out.end == "fault" and "timeout" in out.reason and time.monotonic() - started < 2.5
    assert bridge.reconnect()  # a fresh robot object replaces the stuck one

    # late but within the deadline: noted, the episode goes on; a dropped command is noted too
    bridge = RobotBridge(
        sim_factory(late_observation_steps=[2], late_by_s=0.25, drop_command_steps=[5]),
        mapping,
        Timeouts(observation_s=2.0),
    )
    bridge.connect()
    out = run_episode(bridge, settings, zero_ref, execute, identity, NoLog(), {})
    assert out.end in ("time-limit", "done") and out.control_steps > 5
    assert any(f.startswith("late observation at step 1") for f in out.faults)
    assert "command dropped at step 4" in out.faults
    with pytest.raises(RobotFault):
        RobotBridge(sim_factory(), mapping).observe()  # never connected


@pytest.mark.timeout(30)
def test_terminal_operator_reads_single_keys_from_a_terminal(monkeypatch):
    import io
    import os
    import pty
    import sys

    from rich.console import Console

    from accrue.robot.operator import TerminalOperator

    master, slave = pty.openpty()
    with os.fdopen(slave, "r") as tty_in:
        monkeypatch.setattr(sys, "stdin", tty_in)
        op = TerminalOperator("ann", console=Console(file=io.StringIO()))
        os.write(master, b"xlfr")  # a stray key, re-label the last episode a failure, reset done
        answer = op.wait_reset(4, "nist/rect_peg", 3)
        assert answer.go and answer.relabel.success is False and answer.relabel.note == "re-label of episode 3"
        os.write(master, b"s")
        label = op.label(4, "done, 40 steps")
        assert label.success and label.by == "ann"
        assert op.poll() is None
        os.write(master, b"e")
        assert op.poll() == "end"
        os.write(master, b"prpa")  # paused: reset is not accepted until resumed; then abort
        assert op.wait_reset(5, "nist/rect_peg", 4).go is False
        op.close()
    os.close(master)
    monkeypatch.setattr(sys, "stdin", io.StringIO())
    with pytest.raises(AccrueError, match="needs an interactive terminal"):
        TerminalOperator("ann")
