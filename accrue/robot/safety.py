"""The safety envelope, stated in the robot's own spaces.

SafetyEnvelope (observations): a state outside it ends the episode, and the operator is told why. Where
the robot reports pose and wrench under accrue.sim.STATE_NAMES' names (the simulated robot does): the plug
tip inside a workspace box (cm), its linear speed under a limit (m/s), the wrist force and torque under
limits (N, N m). A limit of None is not checked; a limit the robot's q cannot show is refused at connect.

ActionEnvelope (commands, in the action space the base policy and robot share - joint targets or
end-effector deltas): each command is clipped to per-key bounds and moved at most `max_step` per control
step from the last one sent (or, first, from the observed value of the same key), as lerobot's
`max_relative_target` does for its arms.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from accrue.errors import AccrueError
from accrue.sim.observation import FORCE_SCALE, POS_SCALE, STATE_NAMES, TORQUE_SCALE, VEL_SCALE

_NEEDS = {
    "workspace": ("ee_x_cm", "ee_y_cm", "ee_z_cm"),
    "max_speed_m_s": ("ee_vx", "ee_vy", "ee_vz"),
    "max_force_n": ("wrist_fx", "wrist_fy", "wrist_fz"),
    "max_torque_nm": ("wrist_tx", "wrist_ty", "wrist_tz"),
}


@dataclass(frozen=True)
class SafetyEnvelope:
    workspace_min_m: tuple[float, float, float] | None = None
    workspace_max_m: tuple[float, float, float] | None = None
    max_speed_m_s: float | None = None
    max_force_n: float | None = None  # None: no wrist sensor (or not checked)
    max_torque_nm: float | None = None

    @classmethod
    def from_dict(cls, d: dict | None) -> "SafetyEnvelope":
        d = dict(d or {})
        box = lambda v: None if v is None else tuple(float(x) for x in v)  # noqa: E731
        return cls(
            box(d.get("workspace_min_m")),
            box(d.get("workspace_max_m")),
            d.get("max_speed_m_s"),
            d.get("max_force_n"),
            d.get("max_torque_nm"),
        )

    def check_names(self, names: tuple[str, ...]) -> None:
        """One line when a limit is set that the robot's q (named `names`) cannot show."""
        active = {
            "workspace": self.workspace_min_m is not None or self.workspace_max_m is not None,
            "max_speed_m_s": self.max_speed_m_s is not None,
            "max_force_n": self.max_force_n is not None,
            "max_torque_nm": self.max_torque_nm is not None,
        }
        for limit, keys in _NEEDS.items():
            lacking = [k for k in keys if k not in names]
            if active[limit] and lacking:
                raise AccrueError(
                    f"robot.safety.{limit}: the robot's state has no {lacking[0]!r} to check it against "
                    "(drop the limit, or use the robot's own limits)"
                )

    def violation(self, state: np.ndarray, names: tuple[str, ...] = STATE_NAMES) -> str | None:
        """None inside the envelope, else one line saying which limit and by how much."""
        s = np.asarray(state, dtype=np.float64)
        at = {n: i for i, n in enumerate(names)}

        def part(limit: str) -> np.ndarray | None:
            keys = _NEEDS[limit]
            return np.array([s[at[k]] for k in keys]) if all(k in at for k in keys) else None

        pos = part("workspace")
        for lo, hi, name in ((self.workspace_min_m, None, "below"), (None, self.workspace_max_m, "above")):
            bound = lo if lo is not None else hi
            if bound is None or pos is None:
                continue
            for axis, (p, b) in enumerate(zip(pos / POS_SCALE, bound)):
                if (lo is not None and p < b) or (hi is not None and p > b):
                    return (
                        f"workspace: end effector {'xyz'[axis]} = {p * 1000:.1f} mm is {name} the "
                        f"limit {b * 1000:.1f} mm"
                    )
        return self._rest(part)

    def _rest(self, part) -> str | None:
        if self.max_speed_m_s is not None and part("max_speed_m_s") is not None:
            speed = float(np.linalg.norm(part("max_speed_m_s") / VEL_SCALE))
            if speed > self.max_speed_m_s:
                return f"speed: {speed:.3f} m/s exceeds the limit {self.max_speed_m_s} m/s"
        if self.max_force_n is not None and part("max_force_n") is not None:
            force = float(np.linalg.norm(part("max_force_n") / FORCE_SCALE))
            if force > self.max_force_n:
                return f"wrist force: {force:.1f} N exceeds the limit {self.max_force_n} N"
        if self.max_torque_nm is not None and part("max_torque_nm") is not None:
            torque = float(np.linalg.norm(part("max_torque_nm") / TORQUE_SCALE))
            if torque > self.max_torque_nm:
                return f"wrist torque: {torque:.2f} N m exceeds the limit {self.max_torque_nm} N m"
        return None


@dataclass(frozen=True)
class ActionEnvelope:
    bounds: dict[str, tuple[float, float]] = field(default_factory=dict)  # key -> [lo, hi], robot units
    max_step: dict[str, float] = field(default_factory=dict)  # key -> largest change per control step

    @classmethod
    def from_dict(cls, d: dict | None) -> "ActionEnvelope":
        d = dict(d or {})
        bounds = {str(k): (float(lo), float(hi)) for k, (lo, hi) in (d.get("joint_bounds") or {}).items()}
        steps = {str(k): float(v) for k, v in (d.get("max_step") or {}).items()}
        bad = [k for k, (lo, hi) in bounds.items() if not hi > lo] + [k for k, v in steps.items() if not v > 0]
        if bad:
            raise AccrueError(f"robot.safety: {bad[0]!r} needs hi > lo in joint_bounds and max_step > 0")
        return cls(bounds, steps)

    def check_keys(self, action_keys: tuple[str, ...]) -> None:
        unknown = [k for k in (*self.bounds, *self.max_step) if k not in action_keys]
        if unknown:
            raise AccrueError(
                f"robot.safety: {unknown[0]!r} is not one of the robot's action keys ({', '.join(action_keys)})"
            )

    def limit(self, action: dict[str, float], previous: dict[str, float]) -> tuple[dict[str, float], list[str]]:
        """(the command to send, the keys it changed). `previous`: last sent or observed value per key."""
        out, changed = {}, []
        for k, v in action.items():
            x = v
            if k in self.max_step and k in previous:
                x = float(np.clip(x, previous[k] - self.max_step[k], previous[k] + self.max_step[k]))
            if k in self.bounds:
                x = float(np.clip(x, *self.bounds[k]))
            out[k] = x
            if x != v:
                changed.append(k)
        return out, changed
