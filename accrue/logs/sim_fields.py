"""What episode logs show of an accrue.sim state vector: end-effector pose, socket estimate, wrench.

Poses come out as (7,) [x, y, z, qx, qy, qz, qw] in the robot frame (metres), the wrench as
(6,) force (N) then torque (N m), all decoded from the scaled state with the sim's own decoder.
"""

from __future__ import annotations

import numpy as np


def euler_to_quat_xyzw(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Quaternion of R = Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    return np.array(
        [
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
            cr * cp * cy + sr * sp * sy,
        ]
    )


def yaw_pose(x: float, y: float, z: float, yaw: float) -> np.ndarray:
    return np.array([x, y, z, *euler_to_quat_xyzw(0.0, 0.0, yaw)])


def state_fields(state: np.ndarray) -> dict[str, np.ndarray]:
    """`ee_pose`, `socket_estimate` and `wrench` of one (STATE_DIM,) state."""
    from accrue.sim.observation import decode_state

    d = {k: v[0] for k, v in decode_state(np.asarray(state).reshape(1, -1)).items()}
    ee = np.concatenate([d["pos"], euler_to_quat_xyzw(d["tilt"][0], d["tilt"][1], d["yaw"])])
    estimate = yaw_pose(*d["est_pos"], d["est_yaw"])
    return {"ee_pose": ee, "socket_estimate": estimate, "wrench": np.concatenate([d["force"], d["torque"]])}
