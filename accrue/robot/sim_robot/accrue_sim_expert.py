"""A lerobot `Teleoperator` for the simulated robot: accrue's scripted expert takes over.

It is fed the robot's observation (send_feedback, its feedback_features are the state readings
accrue.sim.STATE_NAMES) and answers get_action() with the expert's 6-D end-effector delta, named like
the simulated robot's actions (accrue.sim.ACTION_NAMES). get_teleop_events() says IS_INTERVENTION during
the configured `takeover` windows of control steps, as a person holding a takeover button would; the
episode loop calls new_episode(index) at each episode start (an extra no physical teleoperator has).
"""

from __future__ import annotations

import numpy as np
from lerobot.teleoperators.teleoperator import Teleoperator
from lerobot.teleoperators.utils import TeleopEvents
from lerobot.utils.errors import DeviceNotConnectedError

from accrue.robot.sim_robot.config_accrue_sim_expert import AccrueSimExpertConfig
from accrue.sim.observation import ACTION_NAMES, STATE_NAMES


class AccrueSimExpert(Teleoperator):
    config_class = AccrueSimExpertConfig
    name = "accrue_sim_expert"

    def __init__(self, config: AccrueSimExpertConfig):
        super().__init__(config)
        self.config = config
        self._connected = False
        self._expert = None
        self._state: np.ndarray | None = None
        self._episode: int | None = None
        self._step = 0  # control steps of this episode whose events were asked for

    @property
    def action_features(self) -> dict:
        return {n: float for n in ACTION_NAMES}

    @property
    def feedback_features(self) -> dict:
        return {n: float for n in STATE_NAMES}

    @property
    def is_connected(self) -> bool:
        return self._connected

    @property
    def is_calibrated(self) -> bool:
        return True

    def calibrate(self) -> None:
        pass

    def configure(self) -> None:
        pass

    def connect(self, calibrate: bool = True) -> None:
        from accrue.sim import make_expert

        bad = [w for w in self.config.takeover if len(w) != 2 or not 0 <= w[0] < w[1]]
        if bad:
            raise ValueError(f"accrue_sim_expert: takeover windows are [from, to) with 0 <= from < to (got {bad[0]})")
        self._expert = make_expert(
            self.config.task, quality=self.config.quality, seed=self.config.seed, bias_known=self.config.bias_known
        )
        self._connected = True

    def disconnect(self) -> None:
        self._connected = False

    def _check(self) -> None:
        if not self._connected:
            raise DeviceNotConnectedError(f"{self} is not connected")

    def new_episode(self, index: int) -> None:
        self._episode, self._step = index, 0

    def send_feedback(self, feedback: dict) -> None:
        self._check()
        self._state = np.array([float(feedback[n]) for n in STATE_NAMES], dtype=np.float64)

    def get_action(self) -> dict:
        self._check()
        if self._state is None:
            raise DeviceNotConnectedError(f"{self}: no observation fed yet (send_feedback)")
        a = self._expert.act(self._state[None])[0]
        return {n: float(v) for n, v in zip(ACTION_NAMES, a)}

    def get_teleop_events(self) -> dict:
        self._check()
        step, self._step = self._step, self._step + 1
        mine = not self.config.episodes or self._episode in self.config.episodes
        held = mine and any(lo <= step < hi for lo, hi in self.config.takeover)
        return {
            TeleopEvents.IS_INTERVENTION: bool(held),
            TeleopEvents.TERMINATE_EPISODE: False,
            TeleopEvents.SUCCESS: False,
            TeleopEvents.RERECORD_EPISODE: False,
        }
