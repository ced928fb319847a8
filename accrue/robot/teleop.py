"""Interventions (beyond the paper, off by default): the operator takes over the robot through a lerobot
`Teleoperator` (keyboard end-effector teleop, gamepad, leader arm; `accrue_sim_expert` on the simulated
robot), made through lerobot's own config registry and factory as the robot is.

    take = Intervention.from_dict(settings.intervention)   # None: off
    take.connect(bridge.mapping)                            # one line if the teleop cannot drive the robot
    take.new_episode(index)
    a = take.step(observation, mapping)                    # None: the policy acts; else the human's (6,)
                                                            # normalised action in the robot's action space

Takeover is signalled by the teleop's own IS_INTERVENTION event (`signal: events`: a held button or key,
as lerobot's HIL-SERL does; the teleop is read every control step, get_action then get_teleop_events, in
HIL-SERL's order) or by the operator's `i` key on the terminal or page (`signal: key`, toggled; the teleop
is read only on the steps it drives).
The teleop's action is mapped onto the robot's action keys (`action_map`, `action_scale`), normalised and
clipped like a policy's action, and then goes through the same bridge and action envelope. The flag is
the episode loop's own record of which steps it executed from the teleop; nothing downstream overwrites it
(HIL-SERL 0.4.4's env reset it to False and its actor did not forward it to the learner). Every teleop call
has a deadline (`timeout_s`): a teleop that stops answering or raises ends the episode as a fault.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from accrue.errors import AccrueError

WINDOW = 20  # episodes in the intervention-rate window (the stop rule's window size)


def teleop_factory(teleop_type: str, config: dict[str, Any], imports: tuple[str, ...] = ()) -> Callable[[], Any]:
    """A function building the lerobot Teleoperator of `teleop_type` (a TeleoperatorConfig registry name);
    a package it lacks is one line naming lerobot's extra when it is built (robot_types.lerobot_factory)."""
    from accrue.robot.robot_types import lerobot_factory

    return lerobot_factory("teleoperator", teleop_type, config, imports, where="robot.intervention", type_key="teleop")


def feature_names(features: dict) -> list[str]:
    """A teleop's action keys: {key: float}, or lerobot's {"dtype", "shape", "names": {key: i}} form
    (keyboard_ee, gamepad)."""
    if isinstance(features.get("names"), dict):
        return list(features["names"])
    return [k for k in features if k not in ("dtype", "shape", "names")]


def window_rate(counts: list[tuple[int, int]], size: int = WINDOW) -> float:
    """Intervened control steps over all control steps of the last `size` episodes ((intervened, steps) each)."""
    last = counts[-size:]
    steps = sum(n for _, n in last)
    return float(sum(i for i, _ in last)) / steps if steps else 0.0


def connect_without_calibration(teleop) -> None:
    """lerobot's arm teleops (so101_leader) take connect(calibrate=...), its keyboard and gamepad teleops
    take no argument: never ask a person to calibrate mid-session, where the device lets us say so."""
    import inspect

    if "calibrate" in inspect.signature(teleop.connect).parameters:
        teleop.connect(calibrate=False)
    else:
        teleop.connect()


@dataclass
class Intervention:
    make_teleop: Callable[[], Any]
    signal: str = "events"  # events | key
    action_map: dict[str, str] = field(default_factory=dict)
    action_scale: dict[str, float] = field(default_factory=dict)
    timeout_s: float = 1.0  # a teleop call slower than this ends the episode (RobotFault), never hangs it
    teleop: Any = None
    toggled: bool = False  # signal key: the operator's `i` has handed the robot to the teleop
    active: bool = False  # the last control step was the teleop's
    steps: int = 0  # control steps the teleop drove in this episode
    _keys: tuple[str, ...] = ()
    _driven: dict[str, str] = field(default_factory=dict)  # robot key -> teleop key
    _pool: Any = None

    @classmethod
    def from_dict(cls, d: dict | None) -> "Intervention | None":
        if not d:
            return None
        if d.get("signal", "events") not in ("events", "key"):
            raise AccrueError(f"robot.intervention.signal: must be events or key (got {d.get('signal')!r})")
        return cls(
            teleop_factory(d["teleop"], d.get("config") or {}, tuple(d.get("imports") or ())),
            signal=d.get("signal", "events"),
            action_map=dict(d.get("action_map") or {}),
            action_scale={k: float(v) for k, v in (d.get("action_scale") or {}).items()},
            timeout_s=float(d.get("timeout_s") or 1.0),
        )

    def _call(self, what: str, fn, *args):
        """A teleop call behind the deadline, on its own worker thread (a stuck device driver cannot be
        interrupted; a new worker is started after a timeout); a timeout or an error is a RobotFault, which
        ends the episode as not a success, as a robot fault does."""
        import concurrent.futures as cf

        from accrue.robot.bridge import RobotFault

        if self._pool is None:
            self._pool = cf.ThreadPoolExecutor(max_workers=1, thread_name_prefix="teleop")
        future = self._pool.submit(fn, *args)
        try:
            return future.result(timeout=self.timeout_s)
        except cf.TimeoutError:
            self._pool.shutdown(wait=False)
            self._pool = None
            raise RobotFault("timeout", f"the teleoperator did not answer {what} within {self.timeout_s:g} s") from None
        except Exception as exc:  # noqa: BLE001 - any device error ends the episode, with its text
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
            raise RobotFault("error", f"the teleoperator's {what} failed: {type(exc).__name__}: {first}") from None

    def connect(self, mapping) -> None:
        """Build and connect the teleop and check it can drive the robot's action keys (mapping bound)."""
        if self.teleop is None:
            try:
                self.teleop = self.make_teleop()
                connect_without_calibration(self.teleop)
                if getattr(self.teleop, "is_connected", True) is False:
                    # lerobot's keyboard teleops "connect" without a listener where they cannot capture keys
                    raise AccrueError(
                        f"robot.intervention: {type(self.teleop).__name__} reports it is not connected after connect() "
                        "(a keyboard teleop needs an X11 session, a Windows desktop or macOS input monitoring); "
                        "use a gamepad, a leader arm, or signal: key on the operator page"
                    )
            except AccrueError:
                raise
            except Exception as exc:  # noqa: BLE001 - a device that is not there, a bad field
                raise AccrueError(f"robot.intervention: the teleoperator did not connect ({exc})") from None
        have = feature_names(self.teleop.action_features)
        keys = tuple(mapping.action_keys)
        for k in (*self.action_map, *self.action_scale):
            if k not in keys:
                raise AccrueError(
                    f"robot.intervention: {k!r} is not one of the robot's action keys ({', '.join(keys)})"
                )
        for k, t in self.action_map.items():
            if t not in have:
                raise AccrueError(
                    f"robot.intervention.action_map: the teleoperator has no action {t!r} for {k!r} "
                    f"(its actions: {', '.join(have)})"
                )
        self._keys = keys
        self._driven = {k: self.action_map.get(k, k) for k in keys if self.action_map.get(k, k) in have}
        if not self._driven:
            raise AccrueError(
                f"robot.intervention: the teleoperator's actions ({', '.join(have)}) name none of the robot's "
                f"({', '.join(keys)}); map them with robot.intervention.action_map"
            )
        if self.signal == "events" and not hasattr(self.teleop, "get_teleop_events"):
            raise AccrueError(
                f"robot.intervention.signal: events, but {type(self.teleop).__name__} has no teleop events; "
                "use signal: key (the operator's i key)"
            )

    def new_episode(self, index: int) -> None:
        self.active, self.steps = False, 0
        self.toggled = False  # every episode starts with the policy driving: the operator takes over again with i
        hook = getattr(self.teleop, "new_episode", None)
        if hook is not None:
            hook(index)

    def toggle(self) -> bool:
        self.toggled = not self.toggled
        return self.toggled

    def _read(self) -> tuple[bool, Any]:
        """This control step's reading of the teleop: (the takeover is on, its action; None when not read).

        signal: events reads the device once a step in lerobot's own order (HIL-SERL's processor pipeline:
        get_action, then get_teleop_events, every step): the action first, because a teleop may refresh its
        state only there (keyboard_ee drains its key events in get_action, and its IS_INTERVENTION is read
        from that state and then cleared), then the events, which say whether the action is used. A teleop
        whose events refresh themselves (gamepad) reads the same either way. signal: key asks for the action
        only on the steps the teleop drives (a leader arm is read only then)."""
        if self.signal == "key":
            return self.toggled, (self._call("get_action", self.teleop.get_action) if self.toggled else None)
        from lerobot.teleoperators.utils import TeleopEvents

        got = self._call("get_action", self.teleop.get_action)
        events = self._call("get_teleop_events", self.teleop.get_teleop_events) or {}
        return bool(events.get(TeleopEvents.IS_INTERVENTION, events.get("is_intervention", False))), got

    def step(self, observation: dict, mapping) -> np.ndarray | None:
        """The human's normalised action for this control step, or None when the policy acts."""
        feedback = self.teleop.feedback_features
        if feedback:  # a teleop that follows the robot (force feedback; the simulated expert's view)
            self._call(
                "send_feedback", self.teleop.send_feedback, {k: observation[k] for k in feedback if k in observation}
            )
        self.active, got = self._read()
        if not self.active:
            return None
        self.steps += 1
        observed = mapping.normalise(np.array([float(observation.get(k, 0.0)) for k in self._keys]))
        held = observed if mapping.action_mode == "joint" else np.zeros(len(self._keys))
        raw = mapping._span()[0] + held * mapping._span()[1]  # keys the teleop does not drive are held
        for i, k in enumerate(self._keys):
            if k in self._driven:
                raw[i] = float(got[self._driven[k]]) * self.action_scale.get(k, 1.0)
        return np.clip(mapping.normalise(raw), -1.0, 1.0).astype(np.float32)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False)
            self._pool = None
        if self.teleop is not None:
            try:
                if self.teleop.is_connected:
                    self.teleop.disconnect()
            except Exception:  # noqa: BLE001 - releasing a device at the end must not mask the session's end
                pass
