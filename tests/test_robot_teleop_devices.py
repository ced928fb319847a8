"""Takeover through lerobot 0.6's own teleoperator classes, each faked only at its device boundary: the
gamepad (GamepadTeleop over a stand-in `pygame` joystick, its RB button held for some control steps), the
keyboard (KeyboardEndEffectorTeleop over a stand-in `pynput` listener, its arrow and shift keys held for some
control steps) and the SO-101 leader arm (SO101Leader over a stand-in Feetech bus, taken over with the
operator's `i`). Each runs
episodes on the simulated robot through run_episode, the path a session takes, and the per-step
intervention flags and executed actions are checked against what the device did."""

from __future__ import annotations

import types

import numpy as np
from test_robot_reset_crop import BOUNDS, Recorder

H = 4


def sim_bridge(tmp_path, mode: str):
    from accrue.robot.bridge import RobotBridge
    from accrue.robot.mapping import RobotMapping
    from accrue.robot.robot_types import lerobot_factory

    config = {"calibration_dir": str(tmp_path / "calib"), "action_mode": mode, "task": "nist/rect_peg", "seed": 1}
    make = lerobot_factory("robot", "accrue_sim", config, (), where="robot", type_key="type")
    mapping = RobotMapping.from_dict(
        {"action_mode": mode, "done_key": "episode.done"} | ({"action_bounds": BOUNDS} if mode == "joint" else {})
    )
    bridge = RobotBridge(make, mapping)
    bridge.connect()
    return bridge


def episode(bridge, take, steps: int, poll=lambda: None):
    """One episode whose policy outputs zeros (no motion in delta mode; the middle of each range in joint)."""
    from accrue.robot.episode import EpisodeSettings, run_episode

    settings = EpisodeSettings(horizon=H, max_steps=steps, control_hz=15.0, clock=0)
    zeros = lambda obs: np.zeros((1, H, bridge.mapping.action_dim), dtype=np.float32)  # noqa: E731
    return run_episode(
        bridge,
        settings,
        zeros,
        lambda s, ref, fresh: ref,
        lambda obs: obs["state"],
        Recorder(),
        {"index": 0},
        poll=poll,
        intervene=take,
    )


class Joystick:
    """pygame.joystick.Joystick(0) of a pad whose RB (button 5) is held during `held` control steps and whose
    left stick is pushed forward (axis 1 = -0.8)."""

    def __init__(self, clock: dict, held: set[int]):
        self.clock, self.held = clock, held

    def init(self):
        pass

    def quit(self):
        pass

    def get_name(self):
        return "stand-in pad"

    def get_button(self, button: int) -> bool:
        return button == 5 and self.clock["step"] in self.held

    def get_axis(self, axis: int) -> float:
        return -0.8 if axis == 1 else 0.0


def fake_pygame(clock: dict, held: set[int]):
    pg = types.SimpleNamespace(JOYBUTTONDOWN=1539, JOYBUTTONUP=1540, error=RuntimeError)
    pg.init = pg.quit = lambda: None
    was = {"down": False}

    def get():  # as a pad does: one event when RB goes down or up (lerobot reads the button on events only)
        down = clock["step"] in held
        if down == was["down"]:
            return []
        was["down"] = down
        return [types.SimpleNamespace(type=pg.JOYBUTTONDOWN if down else pg.JOYBUTTONUP, button=5)]

    pg.event = types.SimpleNamespace(get=get)
    pg.joystick = types.SimpleNamespace(
        init=lambda: None,
        quit=lambda: None,
        get_init=lambda: True,
        get_count=lambda: 1,
        Joystick=lambda i: Joystick(clock, held),
    )
    return pg


def test_a_gamepads_rb_button_flags_exactly_the_steps_it_is_held(tmp_path, monkeypatch):
    """lerobot's GamepadTeleop (pygame backend): while RB is held the takeover is on (its IS_INTERVENTION
    event), the executed action is the stick's delta (dx from the left stick, scaled), the steps are flagged;
    released, the policy acts again and nothing is flagged."""
    import lerobot.teleoperators.gamepad.gamepad_utils as gu
    from lerobot.utils import import_utils

    from accrue.robot.teleop import Intervention

    clock = {"step": -1}
    held = {2, 3, 4, 9}
    monkeypatch.setattr(gu, "pygame", fake_pygame(clock, held))
    monkeypatch.setitem(import_utils._require_package_cache, "pygame", True)
    take = Intervention.from_dict(
        {
            "teleop": "gamepad",
            "config": {"calibration_dir": str(tmp_path / "g")},
            "action_map": {"dx": "delta_x"},
            "action_scale": {"dx": 0.5},
        }
    )
    bridge = sim_bridge(tmp_path, "delta")
    try:
        take.connect(bridge.mapping)
        assert type(take.teleop).__name__ == "GamepadTeleop"
        plain = take.teleop.get_teleop_events

        def events():  # each control step asks for the events once: the pad's clock moves with it
            clock["step"] += 1
            return plain()

        take.teleop.get_teleop_events = events
        take.new_episode(0)
        out = episode(bridge, take, 12)
    finally:
        take.close()
        bridge.disconnect()
    flags = out.intervention.reshape(-1)[: out.control_steps]
    assert out.control_steps == 12 and [t for t in range(12) if flags[t]] == sorted(held)
    actions = out.action.reshape(-1, 6)[: out.control_steps]
    dx = bridge.mapping.action_limits[0] if bridge.mapping.action_limits else 1.0
    for t in range(12):  # the stick's forward push is delta_x = 0.8 (x 0.5 robot units), the rest held at 0
        want = [0.8 * 0.5 / dx, 0, 0, 0, 0, 0] if t in held else [0] * 6
        assert np.allclose(actions[t], want, atol=1e-6), t
    assert take.steps == len(held)


class Listener:
    """pynput.keyboard.Listener where there is no display: started, it is alive; the test calls the teleop's
    on_press / on_release as the listener's thread would, with each key event the keyboard sends."""

    def __init__(self, on_press, on_release):
        self.on_press, self.on_release, self.alive = on_press, on_release, False

    def start(self):
        self.alive = True

    def stop(self):
        self.alive = False

    def is_alive(self) -> bool:
        return self.alive


def test_keyboard_ee_keys_held_take_over_exactly_those_steps_and_drive_the_deltas(tmp_path, monkeypatch):
    """lerobot's KeyboardEndEffectorTeleop (signal: events): it takes its key state from the listener's queue
    only in get_action and reports IS_INTERVENTION from that state (then clears it), so the takeover reads
    the action first every step. While an arrow key is held the takeover is on and the executed action is
    the keys' delta (up: delta_y -1, right shift: delta_z +1, scaled); released, the policy acts again; a
    key pressed and released between two control steps takes nothing over. A held key goes on sending
    presses (the OS's key repeat), one per control step here, as lerobot counts a key held on a step only
    when a press came since the last one."""
    import enum

    import lerobot.teleoperators.keyboard.teleop_keyboard as tk
    from lerobot.utils import import_utils

    from accrue.robot.teleop import Intervention

    Key = enum.Enum("Key", "up down left right shift shift_r ctrl_l ctrl_r esc")
    monkeypatch.setattr(tk, "keyboard", types.SimpleNamespace(Key=Key, Listener=Listener))
    monkeypatch.setattr(tk, "PYNPUT_AVAILABLE", True)
    monkeypatch.setattr(tk, "pynput_can_capture", lambda: True)
    monkeypatch.setitem(import_utils._require_package_cache, "pynput", True)
    up, lift = range(3, 9), range(5, 7)  # steps with up held, and with right shift held too
    # the key events that arrive before each control step's read: (key, pressed)
    arrive: dict[int, list] = {t: [(Key.up, True)] for t in up}
    arrive[9] = [(Key.up, False)]
    for t in lift:
        arrive[t].append((Key.shift_r, True))
    arrive[7].append((Key.shift_r, False))
    arrive[11] = [(Key.left, True), (Key.left, False)]  # a tap between two reads
    take = Intervention.from_dict(
        {
            "teleop": "keyboard_ee",
            "config": {"calibration_dir": str(tmp_path / "k")},
            "action_map": {"dx": "delta_x", "dy": "delta_y", "dz": "delta_z"},
            "action_scale": {"dx": 0.02, "dy": 0.02, "dz": 0.02},
        }
    )
    bridge = sim_bridge(tmp_path, "delta")
    try:
        take.connect(bridge.mapping)
        assert type(take.teleop).__name__ == "KeyboardEndEffectorTeleop" and take.teleop.is_connected
        listener, plain, clock = take.teleop.listener, take.step, {"step": 0}

        def step(observation, mapping):  # the keyboard's events of this step, then the episode loop's read
            for key, pressed in arrive.get(clock["step"], []):
                (listener.on_press if pressed else listener.on_release)(key)
            clock["step"] += 1
            return plain(observation, mapping)

        take.step = step
        take.new_episode(0)
        out = episode(bridge, take, 14)
    finally:
        take.close()
        bridge.disconnect()
    assert not listener.alive  # close() disconnected the teleop, which stopped its listener
    flags = out.intervention.reshape(-1)[: out.control_steps]
    assert out.control_steps == 14 and [t for t in range(14) if flags[t]] == list(up)
    assert take.steps == len(up)
    actions = out.action.reshape(-1, 6)[: out.control_steps]
    limits = bridge.mapping.action_limits or (1.0,) * 6
    for t in range(14):  # up: delta_y = -1, right shift: delta_z = +1 (x 0.02 robot units); the rest 0
        want = np.zeros(6)
        if t in up:
            want[1] = -0.02 / limits[1]
        if t in lift:
            want[2] = 0.02 / limits[2]
        assert np.allclose(actions[t], np.clip(want, -1, 1), atol=1e-6), (t, actions[t])
    assert np.abs(actions[list(up)][:, 1]).min() > 0  # the keys moved the robot (not clipped away to 0)


class Bus:
    """The Feetech bus an SO-101 leader reads: positions of its motors, in the units lerobot normalises to."""

    positions: dict[str, float] = {}
    reads = 0

    def __init__(self, port, motors, calibration=None, **kw):
        self.motors, self.calibration, self.is_connected = motors, calibration, False

    is_calibrated = property(lambda self: True)

    def connect(self):
        self.is_connected = True

    def disconnect(self, *a):
        self.is_connected = False

    def disable_torque(self, *a, **k):
        pass

    def configure_motors(self, *a, **k):
        pass

    def write(self, *a, **k):
        pass

    def sync_read(self, what, num_retry=0):
        assert what == "Present_Position"
        Bus.reads += 1
        return {m: Bus.positions[m] for m in self.motors}


def test_a_leader_arm_taken_over_with_the_operators_key_drives_the_joints_it_maps(tmp_path, monkeypatch):
    """lerobot's SO101Leader (signal: key, as a leader arm has no button): after the operator's `i` (at the
    second chunk's poll) every step is the leader's, its joint positions mapped onto the robot's joint
    targets (action_map, action_scale) and flagged; before it, the policy's, unflagged."""
    import lerobot.teleoperators.so_leader.so_leader as sl

    from accrue.robot.teleop import Intervention

    monkeypatch.setattr(sl, "FeetechMotorsBus", Bus)
    motors = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper")
    Bus.positions = {m: 10.0 * (i + 1) for i, m in enumerate(motors)}
    take = Intervention.from_dict(
        {
            "teleop": "so101_leader",
            "config": {"port": "/dev/null", "id": "leader", "calibration_dir": str(tmp_path / "l")},
            "signal": "key",
            "action_map": {"x.pos": "shoulder_pan.pos", "z.pos": "elbow_flex.pos"},
            "action_scale": {"x.pos": 0.001, "z.pos": 0.001},
        }
    )
    bridge = sim_bridge(tmp_path, "joint")
    polls = {"n": 0}

    def poll():
        polls["n"] += 1
        return "intervene" if polls["n"] == 2 else None

    try:
        take.connect(bridge.mapping)
        assert type(take.teleop).__name__ == "SOLeader"  # lerobot 0.6: SO101Leader is an alias of it
        take.new_episode(0)
        out = episode(bridge, take, 16, poll)
    finally:
        take.close()
        bridge.disconnect()
    flags = out.intervention.reshape(-1)[: out.control_steps]
    assert out.control_steps == 16 and np.array_equal(flags, np.arange(16) >= 2 * H)
    assert Bus.reads == 16 - 2 * H  # the leader is read only on the steps it drives
    raw = np.array(
        [bridge.mapping.action(a)[k] for a in out.action.reshape(-1, 6)[2 * H : 16] for k in ("x.pos", "z.pos")]
    )
    assert np.allclose(raw, np.tile([0.010, 0.030], 16 - 2 * H), atol=1e-6)  # 10 and 30 (x 0.001), in metres
    assert np.allclose(out.action.reshape(-1, 6)[: 2 * H], 0.0)  # the policy's before the key
