"""Any lerobot 0.6 `Robot` behind deadlines: every call to the robot runs on a worker thread and is
given up after its timeout, so a robot that stops answering ends the episode instead of hanging it.

    bridge = RobotBridge(make_robot, mapping, Timeouts(connect_s=10, observation_s=1, action_s=1), actions=env)
    bridge.connect()                     # RobotFault on failure; the mapping is bound to the robot's features
    state, done = bridge.observe()       # q (the robot's scalar readings) as float32; done = robot ended the episode
    bridge.observation()                 # {"state": (1, D), "images": [(1, h, w, 3) per camera], "cameras": names,
                                         #  "image": the first camera's}
    bridge.act(a)                        # a: (d,) normalised, in the robot's action space -> its action dict,
                                         # through the action envelope (per-key bounds, rate limits)
    bridge.reconnect()                   # a fresh Robot from make_robot, connected; False when it cannot be
    bridge.move_to(ResetPose(...))       # drive the arm to a fixed joint pose through the action envelope

A call that times out leaves its worker thread behind (a driver stuck in I/O cannot be interrupted from
Python); the bridge starts a new one and treats the robot as lost until reconnect() succeeds.
"""

from __future__ import annotations

import concurrent.futures as cf
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from accrue.errors import AccrueError
from accrue.robot.mapping import RobotMapping
from accrue.robot.safety import ActionEnvelope, SafetyEnvelope


class RobotFault(Exception):
    """The robot disconnected, stopped answering, or raised: the episode ends as not a success."""

    def __init__(self, kind: str, message: str):
        super().__init__(message)
        self.kind = kind  # "disconnected" | "timeout" | "error"


@dataclass(frozen=True)
class Timeouts:
    connect_s: float = 15.0
    observation_s: float = 1.0
    action_s: float = 1.0
    reconnect_attempts: int = 3
    reconnect_wait_s: float = 1.0

    @classmethod
    def from_dict(cls, d: dict | None) -> "Timeouts":
        return cls(**{k: v for k, v in (d or {}).items() if k in cls.__dataclass_fields__})


def robot_factory(robot_type: str, config: dict[str, Any], imports: tuple[str, ...] = ()) -> Callable[[], Any]:
    """A function building the lerobot Robot of `robot_type` (a RobotConfig registry name) from `config`.

    `imports` are modules to import first so that third-party robot types register themselves; an installed
    `lerobot_robot_*` plugin distribution is found without one (accrue.robot.robot_types.lerobot_factory).
    accrue's simulated robot is built in. The robot is built once here: a missing SDK or a bad field is a
    configuration error now, not a fault mid-session."""
    from accrue.robot.robot_types import lerobot_factory

    make = lerobot_factory("robot", robot_type, config, imports, where="robot", type_key="type")
    make()
    return make


@dataclass(frozen=True)
class ResetPose:
    """A fixed pose the arm is driven to before each episode (robot.reset_pose): targets in the robot's own
    action units for some of its action keys (the others held where they are), reached when every key reads
    within `tolerance` of its target, given up after `max_steps` control steps."""

    pose: tuple[tuple[str, float], ...]
    tolerance: float
    max_steps: int = 200

    @classmethod
    def from_dict(cls, d: dict | None) -> "ResetPose | None":
        if not d:
            return None
        pose = tuple((str(k), float(v)) for k, v in (d.get("pose") or {}).items())
        if not pose:
            raise AccrueError("robot.reset_pose.pose: name at least one action key and its target")
        tolerance, max_steps = float(d.get("tolerance", 0)), int(d.get("max_steps", 200))
        if not tolerance > 0 or max_steps < 1:
            raise AccrueError(
                f"robot.reset_pose: tolerance must be > 0 and max_steps >= 1 (got {tolerance:g}, {max_steps})"
            )
        return cls(pose, tolerance, max_steps)

    def check(self, mapping: RobotMapping, observation_features: dict, actions: ActionEnvelope) -> None:
        """One line for a pose the robot cannot be driven to: a key it does not take or read back, a key whose
        motion robot.safety.max_step does not limit, a target outside robot.safety.joint_bounds."""
        for key, target in self.pose:
            if key not in mapping.action_keys:
                raise AccrueError(
                    f"robot.reset_pose: {key!r} is not one of the robot's action keys ({', '.join(mapping.action_keys)})"
                )
            if key not in observation_features:
                raise AccrueError(
                    f"robot.reset_pose: the robot does not read {key!r} back, so reaching it cannot be seen"
                )
            if key not in actions.max_step:
                raise AccrueError(
                    f"robot.reset_pose: {key!r} has no robot.safety.max_step, which limits the reset's motion; set one"
                )
            lo, hi = actions.bounds.get(key, (-np.inf, np.inf))
            if not lo <= target <= hi:
                raise AccrueError(
                    f"robot.reset_pose: {key} = {target:g} is outside robot.safety.joint_bounds [{lo:g}, {hi:g}]"
                )


class RobotBridge:
    def __init__(
        self,
        make_robot: Callable[[], Any],
        mapping: RobotMapping,
        timeouts: Timeouts = Timeouts(),
        report: Callable[[str], None] = lambda line: None,
        actions: ActionEnvelope = ActionEnvelope(),
        safety: SafetyEnvelope = SafetyEnvelope(),
    ):
        self.make_robot, self.mapping, self.timeouts, self.report = make_robot, mapping, timeouts, report
        self.actions, self.safety = actions, safety
        self.robot = None
        self._last_obs: dict = {}
        self._last_sent: dict[str, float] = {}
        self.limited = 0  # commands the action envelope changed
        self._pool: cf.ThreadPoolExecutor | None = None
        self.last_latency_s = 0.0

    # ------------------------------------------------------------------ calls with deadlines
    def _call(self, what: str, fn: Callable, timeout: float, *args, **kw):
        if self._pool is None:
            self._pool = cf.ThreadPoolExecutor(max_workers=1, thread_name_prefix="robot")
        started = time.monotonic()
        future = self._pool.submit(fn, *args, **kw)
        try:
            result = future.result(timeout=timeout)
        except cf.TimeoutError:
            self._pool.shutdown(wait=False)  # the stuck call keeps its thread; later calls get a new one
            self._pool = None
            raise RobotFault("timeout", f"robot did not answer {what} within {timeout:g} s") from None
        except (RobotFault, AccrueError):
            raise  # AccrueError: the robot's configuration (a missing SDK), not a fault of the arm
        except Exception as exc:  # noqa: BLE001 - any driver error ends the episode, with its text
            kind = (
                "disconnected" if "connect" in type(exc).__name__.lower() or "connect" in str(exc).lower() else "error"
            )
            raise RobotFault(
                kind,
                f"robot {what} failed: {type(exc).__name__}: "
                f"{str(exc).strip().splitlines()[0] if str(exc).strip() else ''}",
            ) from None
        self.last_latency_s = time.monotonic() - started
        return result

    # ------------------------------------------------------------------ lifecycle
    def connect(self) -> None:
        if self.robot is None:
            self.robot = self._call("creation", self.make_robot, self.timeouts.connect_s)
            self.mapping = self.mapping.bind(
                self.robot.observation_features,
                self.robot.action_features,
                f"robot {getattr(self.robot, 'name', type(self.robot).__name__)}",
                robot=self.robot,
            )
            self.safety.check_names(self.mapping.state_keys)
            self.actions.check_keys(self.mapping.action_keys)
        if not self.robot.is_connected:
            self._call("connect", self.robot.connect, self.timeouts.connect_s, calibrate=False)

    def disconnect(self) -> None:
        robot, self.robot = self.robot, None
        if robot is None:
            return
        try:
            if robot.is_connected:
                self._call("disconnect", robot.disconnect, self.timeouts.connect_s)
        except RobotFault as exc:
            self.report(f"robot: disconnect did not complete ({exc})")

    def reconnect(self) -> bool:
        """Drop the robot and connect a fresh one; False after `reconnect_attempts` failures."""
        keep = self.robot
        for attempt in range(1, self.timeouts.reconnect_attempts + 1):
            try:
                if keep is not None and not self._is_stale(keep):
                    self.robot = keep  # same driver object: just connect it again
                else:
                    self.disconnect()
                self.connect()
                self.report(f"robot: reconnected (attempt {attempt})")
                return True
            except RobotFault as exc:
                self.report(f"robot: reconnect attempt {attempt} failed: {exc}")
                keep = None
                time.sleep(self.timeouts.reconnect_wait_s)
        return False

    def _is_stale(self, robot) -> bool:
        return self._pool is None  # a timed-out call left the old driver mid-call: build a new one

    # ------------------------------------------------------------------ control
    def observe(self) -> tuple[np.ndarray, bool]:
        if self.robot is None:
            raise RobotFault("disconnected", "robot is not connected")
        obs = self._call("get_observation", self.robot.get_observation, self.timeouts.observation_s)
        self._last_obs = obs
        return self.mapping.state(obs), self.mapping.done(obs)

    def observation(self) -> dict:
        """The last observation as a batch of one: q, and the frames of its cameras (if any), in camera_keys
        order, with their names (a base policy reads each camera by its name)."""
        out = {"state": self.mapping.state(self._last_obs)[None]}
        frames = self.frames()
        if frames:
            out["images"] = [f[None] for f in frames]
            out["cameras"] = tuple(self.mapping.camera_keys)
            out["image"] = out["images"][0]
        return out

    def last_observation(self) -> dict:
        """The last observation as the robot gave it (a teleoperator's feedback, the takeover's held keys)."""
        return self._last_obs

    def frames(self) -> list[np.ndarray]:
        """The last observation's camera frames, (h, w, 3) uint8 each, in camera_keys order."""
        return self.mapping.images(self._last_obs)

    def new_episode(self) -> None:
        """Rate limits start again from the robot's observed values (after a reset)."""
        self._last_sent = {}

    def act(self, normalised: np.ndarray) -> bool:
        """Send one action; False when the robot reports it did not take it (a dropped command)."""
        if self.robot is None:
            raise RobotFault("disconnected", "robot is not connected")
        observed = {k: float(self._last_obs[k]) for k in self.mapping.action_keys if k in self._last_obs}
        action, changed = self.actions.limit(self.mapping.action(normalised), {**observed, **self._last_sent})
        self.limited += bool(changed)
        sent = self._call("send_action", self.robot.send_action, self.timeouts.action_s, action)
        self._last_sent = dict(action)
        return not isinstance(sent, dict) or all(k in sent for k in action)

    def move_to(self, reset: ResetPose, period_s: float = 0.0) -> int:
        """Drive the arm to `reset.pose` before an episode: each control step commands the pose (the keys it
        leaves out at their observed values) through the action envelope, which moves every key at most its
        max_step from the last command and clips it to its joint bounds, as during an episode. Returns the
        control steps it took (not robot time of any episode); one line when the pose is not reached within
        reset.max_steps (the arm is blocked, or the tolerance is finer than it can hold). RobotFault as act."""
        if self.robot is None:
            raise RobotFault("disconnected", "robot is not connected")
        reset.check(self.mapping, self.robot.observation_features, self.actions)
        pose = dict(reset.pose)
        for n in range(reset.max_steps + 1):
            tick = time.monotonic()
            self.observe()
            observed = {k: float(self._last_obs[k]) for k in self.mapping.action_keys if k in self._last_obs}
            off = {k: abs(observed[k] - v) for k, v in pose.items()}
            worst = max(off, key=off.get)
            if off[worst] <= reset.tolerance:
                return n
            if n == reset.max_steps:
                break
            held = {**observed, **self._last_sent}
            target = {k: pose.get(k, held.get(k, 0.0)) for k in self.mapping.action_keys}
            action, _ = self.actions.limit(target, held)
            self._call("send_action", self.robot.send_action, self.timeouts.action_s, action)
            self._last_sent = dict(action)
            wait = period_s - (time.monotonic() - tick)
            if wait > 0:
                time.sleep(wait)
        raise AccrueError(
            f"robot.reset_pose: the arm did not reach the pose within {reset.max_steps} control steps "
            f"({worst} reads {observed[worst]:g}, target {pose[worst]:g}, tolerance {reset.tolerance:g})"
        )

    def hook(self, name: str):
        """An optional extra of the robot object (the simulated robot's reset_scene / episode_success)."""
        return getattr(self.robot, name, None) if self.robot is not None else None
