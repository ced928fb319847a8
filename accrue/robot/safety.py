"""The safety envelope: a state outside it ends the episode, and the operator is told why.

Checked on accrue's state vector (accrue.sim.observation units): the plug tip inside a workspace box
(cm), its linear speed under a limit (m/s), and - when the robot has a wrist sensor - the wrist force
and torque under limits (N, N m). A limit of None is not checked.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from accrue.sim.observation import FORCE_SCALE, IDX, POS_SCALE, TORQUE_SCALE, VEL_SCALE


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

    def violation(self, state: np.ndarray) -> str | None:
        """None inside the envelope, else one line saying which limit and by how much."""
        s = np.asarray(state, dtype=np.float64)
        pos = s[IDX["ee_x_cm"] : IDX["ee_z_cm"] + 1] / POS_SCALE
        for lo, hi, name in ((self.workspace_min_m, None, "below"), (None, self.workspace_max_m, "above")):
            bound = lo if lo is not None else hi
            if bound is None:
                continue
            for axis, (p, b) in enumerate(zip(pos, bound)):
                if (lo is not None and p < b) or (hi is not None and p > b):
                    return (
                        f"workspace: end effector {'xyz'[axis]} = {p * 1000:.1f} mm is {name} the "
                        f"limit {b * 1000:.1f} mm"
                    )
        if self.max_speed_m_s is not None:
            speed = float(np.linalg.norm(s[IDX["ee_vx"] : IDX["ee_vz"] + 1] / VEL_SCALE))
            if speed > self.max_speed_m_s:
                return f"speed: {speed:.3f} m/s exceeds the limit {self.max_speed_m_s} m/s"
        if self.max_force_n is not None:
            force = float(np.linalg.norm(s[IDX["wrist_fx"] : IDX["wrist_fz"] + 1] / FORCE_SCALE))
            if force > self.max_force_n:
                return f"wrist force: {force:.1f} N exceeds the limit {self.max_force_n} N"
        if self.max_torque_nm is not None:
            torque = float(np.linalg.norm(s[IDX["wrist_tx"] : IDX["wrist_tz"] + 1] / TORQUE_SCALE))
            if torque > self.max_torque_nm:
                return f"wrist torque: {torque:.2f} N m exceeds the limit {self.max_torque_nm} N m"
        return None
