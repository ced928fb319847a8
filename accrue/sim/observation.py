"""The state vector every task shares (one learner serves all tasks), and its scaling.

Everything is expressed in the robot frame, in which the socket sits at an unknown pose that
the state only carries as a noisy estimate. Units are scaled so typical magnitudes are ~1.
"""

from __future__ import annotations

import numpy as np

STATE_NAMES = (
    "ee_x_cm",
    "ee_y_cm",
    "ee_z_cm",  # plug tip (bottom centre) position, robot frame, cm
    "ee_roll_x10",
    "ee_pitch_x10",  # tilt, rad x 10
    "ee_yaw_sin",
    "ee_yaw_cos",  # yaw, robot frame
    "ee_vx",
    "ee_vy",
    "ee_vz",  # linear velocity, m/s x 10
    "ee_wx",
    "ee_wy",
    "ee_wz",  # angular velocity, rad/s
    "wrist_fx",
    "wrist_fy",
    "wrist_fz",  # wrist force in the wrist frame, N / 10
    "wrist_tx",
    "wrist_ty",
    "wrist_tz",  # wrist torque in the wrist frame, N m
    "socket_est_x_cm",
    "socket_est_y_cm",
    "socket_est_z_cm",  # noisy socket-top estimate, robot frame, cm
    "socket_est_yaw_sin",
    "socket_est_yaw_cos",  # noisy socket yaw estimate
    "time_frac",  # step / max_steps
    # the socket estimate relative to the plug tip (estimate - tip, robot frame): redundant with the
    # columns above, but it is the quantity a controller servos on, and a policy imitating from a few
    # demonstrations generalises from it far better than from two absolute positions (20 demos, MLP:
    # 0.06 -> 0.73 success on nist/rect_peg)
    "socket_rel_x_mm",
    "socket_rel_y_mm",
    "socket_rel_z_mm",
    "socket_rel_yaw_x10",  # estimate yaw - plug yaw, wrapped to (-pi, pi], rad x 10
)
STATE_DIM = len(STATE_NAMES)
ACTION_DIM = 6
ACTION_NAMES = ("dx", "dy", "dz", "droll", "dpitch", "dyaw")

POS_SCALE = 100.0  # m -> cm
TILT_SCALE = 10.0
VEL_SCALE = 10.0
FORCE_SCALE = 0.1
TORQUE_SCALE = 1.0
REL_POS_SCALE = 1000.0  # m -> mm

IDX = {name: i for i, name in enumerate(STATE_NAMES)}

# obs["history"]: the last HISTORY_STEPS control steps, newest first, each the wrist force/torque and the
# socket estimate relative to the tip after that step, and the action that led there (zeros before the
# episode's first step). A searching policy's memory (how long it has pushed without sinking) lives here.
HISTORY_STEPS = 8
HISTORY_NAMES = (
    "wrist_fx",
    "wrist_fy",
    "wrist_fz",
    "wrist_tx",
    "wrist_ty",
    "wrist_tz",
    "socket_rel_x_mm",
    "socket_rel_y_mm",
    "socket_rel_z_mm",
    *ACTION_NAMES,
)
HISTORY_DIM = len(HISTORY_NAMES)


def rotate_xy(xy: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Rotate (N, 2) vectors by per-row yaw (N,)."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([c * xy[:, 0] - s * xy[:, 1], s * xy[:, 0] + c * xy[:, 1]], axis=1)


def decode_state(state: np.ndarray) -> dict[str, np.ndarray]:
    """The state back in SI units (robot frame), for experts and diagnostics."""
    s = np.asarray(state, dtype=np.float64)
    sl = lambda a, b: s[:, IDX[a] : IDX[b] + 1]  # noqa: E731
    return {
        "pos": sl("ee_x_cm", "ee_z_cm") / POS_SCALE,
        "tilt": sl("ee_roll_x10", "ee_pitch_x10") / TILT_SCALE,
        "yaw": np.arctan2(s[:, IDX["ee_yaw_sin"]], s[:, IDX["ee_yaw_cos"]]),
        "lin_vel": sl("ee_vx", "ee_vz") / VEL_SCALE,
        "ang_vel": sl("ee_wx", "ee_wz"),
        "force": sl("wrist_fx", "wrist_fz") / FORCE_SCALE,
        "torque": sl("wrist_tx", "wrist_tz") / TORQUE_SCALE,
        "est_pos": sl("socket_est_x_cm", "socket_est_z_cm") / POS_SCALE,
        "est_yaw": np.arctan2(s[:, IDX["socket_est_yaw_sin"]], s[:, IDX["socket_est_yaw_cos"]]),
        "time_frac": s[:, IDX["time_frac"]],
    }
