"""How a robot's flat lerobot observation/action dicts map onto accrue's vectors.

accrue's learner and base policies see the STATE_DIM-vector of accrue.sim.STATE_NAMES and act with the
6-D end-effector delta [dx, dy, dz, droll, dpitch, dyaw] normalised to [-1, 1]. A robot names its own
keys: `state_keys[i]` is the observation key read into state column i, `action_keys[j]` the action key
that receives axis j, scaled by `action_limits[j]` (robot units per unit of normalised action).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from accrue.errors import AccrueError
from accrue.sim.observation import ACTION_DIM, ACTION_NAMES, STATE_DIM, STATE_NAMES


@dataclass(frozen=True)
class RobotMapping:
    state_keys: tuple[str, ...] = STATE_NAMES
    action_keys: tuple[str, ...] = ACTION_NAMES
    action_limits: tuple[float, ...] = (1.0,) * ACTION_DIM
    done_key: str | None = None  # optional observation key > 0.5 when the robot ends the episode itself

    def __post_init__(self):
        if len(self.state_keys) != STATE_DIM:
            raise AccrueError(
                f"robot.state_keys: needs {STATE_DIM} keys, one per accrue state column "
                f"({', '.join(STATE_NAMES[:3])}, ...) (got {len(self.state_keys)})"
            )
        if len(self.action_keys) != ACTION_DIM or len(self.action_limits) != ACTION_DIM:
            raise AccrueError(
                f"robot.action_keys and robot.action_limits: need {ACTION_DIM} entries each ({', '.join(ACTION_NAMES)})"
            )
        if any(not (x > 0) for x in self.action_limits):
            raise AccrueError(f"robot.action_limits: must all be > 0 (got {list(self.action_limits)})")

    @classmethod
    def from_dict(cls, d: dict) -> "RobotMapping":
        return cls(
            state_keys=tuple(d.get("state_keys") or STATE_NAMES),
            action_keys=tuple(d.get("action_keys") or ACTION_NAMES),
            action_limits=tuple(float(x) for x in (d.get("action_limits") or (1.0,) * ACTION_DIM)),
            done_key=d.get("done_key"),
        )

    def check_features(self, observation_features: dict, action_features: dict, who: str) -> None:
        """One line naming the first key the robot (or dataset) lacks."""
        missing = [k for k in self.state_keys if k not in observation_features]
        if missing:
            raise AccrueError(
                f"{who}: observation has no {missing[0]!r} (robot.state_keys wants {len(missing)} "
                f"key(s) it lacks; it has {', '.join(list(observation_features)[:6])}...)"
            )
        missing = [k for k in self.action_keys if k not in action_features]
        if missing:
            raise AccrueError(
                f"{who}: action has no {missing[0]!r} (robot.action_keys; it has "
                f"{', '.join(list(action_features)[:6]) or 'none'})"
            )

    def state(self, observation: dict) -> np.ndarray:
        try:
            return np.array([float(observation[k]) for k in self.state_keys], dtype=np.float32)
        except KeyError as exc:
            raise AccrueError(f"robot observation lacks {exc.args[0]!r} (robot.state_keys)") from None

    def done(self, observation: dict) -> bool:
        return self.done_key is not None and float(observation.get(self.done_key, 0.0)) > 0.5

    def action(self, normalised: np.ndarray) -> dict[str, float]:
        a = np.clip(np.asarray(normalised, dtype=np.float64).reshape(ACTION_DIM), -1.0, 1.0)
        return {k: float(v * lim) for k, v, lim in zip(self.action_keys, a, self.action_limits)}
