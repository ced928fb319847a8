"""A lerobot `Robot` driving the SO-101 of lerobot-env-so101 (a MuJoCo gymnasium env on PyPI, written
elsewhere), used as a dependency: its scene, servos, IK, camera and success signals are the package's.

The arm reports and takes what a real SO-101 does (lerobot's so101_follower names): the positions of its
five arm joints and its gripper (`shoulder_pan.pos` ... `gripper.pos`, in rad, the package's actuator
units), the absolute joint targets its position servos take, and the frame of the scene's `front`
camera. `episode.done` is 1.0 once the scene's own success signal holds, the cube left the workspace or
the time limit passed. Two extras of a simulated robot, as accrue_sim has, stand in for the person at a
real arm: `reset_scene()` (the parts are put back) and `episode_success()` (what the person would see).

The package's native action ([dx, dy, dz, grasp] through its position-only IK) drives its scripted
controllers: `scripted_joint_targets()` asks the package's controller for the scene's next move, solves
it through the package's IK and returns the joint targets it commands, which is what a demonstration of
this arm records (accrue.robot.sim_robot.so101_demos).
"""

from __future__ import annotations

import numpy as np
from lerobot.robots.robot import Robot
from lerobot.utils.errors import DeviceNotConnectedError

from accrue.robot.sim_robot.config_so101_env import SCENES, SO101EnvConfig

DONE_KEY = "episode.done"
JOINTS = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper")
JOINT_KEYS = tuple(f"{j}.pos" for j in JOINTS)


def _joint_env_class(name: str):
    """The package's env class with one addition: a 6-value action is the six servos' targets (rad),
    held over the control step's physics substeps; its native 4-value action still goes through its IK.
    Its step() (observation, success, termination) is its own."""
    import lerobot_env_so101 as package

    base = getattr(package, name)

    class JointTargets(base):
        def apply_action(self, action):
            action = np.asarray(action, dtype=np.float64)
            if action.shape != (len(JOINTS),):
                return super().apply_action(action)
            import mujoco

            ids = [self.model.actuator(j).id for j in JOINTS]
            lo, hi = self.model.actuator_ctrlrange[ids].T
            self.data.ctrl[ids] = np.clip(action, lo, hi)
            for _ in range(int(self.control_dt // self.physics_dt)):
                mujoco.mj_step(self.model, self.data)

    JointTargets.__name__ = f"{name}JointTargets"
    return JointTargets


class SO101Env(Robot):
    config_class = SO101EnvConfig
    name = "so101_env"

    def __init__(self, config: SO101EnvConfig):
        super().__init__(config)
        self.config = config
        if config.scene not in SCENES:
            raise ValueError(f"so101_env: scene must be one of {', '.join(SCENES)} (got {config.scene!r})")
        bad = [c for c in config.render_cameras if c != "front"]
        if bad:
            raise ValueError(f"so101_env: the scene has one camera, 'front' (got {bad[0]!r})")
        self.scene = SCENES[config.scene]
        self.max_steps = int(config.episode_steps or self.scene.max_steps)
        self._env = None
        self._renderer = None
        self._connected = False
        self._obs: dict | None = None
        self._steps = 0
        self._done = self._success = False
        self._controller = None
        self._episode = 0

    # ------------------------------------------------------------------ declared features
    @property
    def observation_features(self) -> dict:
        size = int(self.config.image_size)
        return {
            **{k: float for k in JOINT_KEYS},
            DONE_KEY: float,
            **{c: (size, size, 3) for c in self.config.render_cameras},
        }

    @property
    def action_features(self) -> dict:
        return {k: float for k in JOINT_KEYS}

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

    # ------------------------------------------------------------------ lifecycle
    def connect(self, calibrate: bool = True) -> None:
        if self._env is None:
            from lerobot_env_so101.mujoco_env import GymRenderingSpec
            from lerobot_env_so101.policy import DEFAULT_ACTION_SCALE

            size = int(self.config.image_size)
            self._env = _joint_env_class(self.scene.env)(
                seed=self.config.seed,
                render_spec=GymRenderingSpec(size, size, "front"),
                random_block_position=bool(self.config.random_block_position),
                action_scale=DEFAULT_ACTION_SCALE,  # the scale its scripted controllers are written for
            )
            self.reset_scene()
        if self.config.render_cameras:
            self._render()  # the GL context and first frame now, not inside the first timed observation
        self._connected = True

    def disconnect(self) -> None:
        self._connected = False
        if self._env is not None:
            self._env.close()
        if self._renderer is not None:
            self._renderer.close()  # the GL context (made again on the next frame); the scene stays
            self._renderer = None

    def _check(self) -> None:
        if not self._connected:
            raise DeviceNotConnectedError(f"{self} is not connected")

    # ------------------------------------------------------------------ control
    def joint_positions(self) -> np.ndarray:
        m, d = self._env.model, self._env.data
        return np.array([d.qpos[m.joint(j).qposadr[0]] for j in JOINTS], dtype=np.float64)

    def get_observation(self) -> dict:
        self._check()
        out = {k: float(v) for k, v in zip(JOINT_KEYS, self.joint_positions())}
        out[DONE_KEY] = 1.0 if self._done else 0.0
        for camera in self.config.render_cameras:
            out[camera] = self._render()
        return out

    def _render(self) -> np.ndarray:
        """The front camera's frame, (size, size, 3) uint8. With fast_render (the default) the package's
        scene is drawn without shadows, reflections, skybox and multisampling: on a software GL (CI's
        EGL) its 4096-px shadow map costs ~2 s a frame, the plain scene ~0.1 s."""
        import mujoco

        env = self._env
        if self._renderer is None:
            if self.config.fast_render:
                env.model.vis.quality.offsamples = 0
            size = int(self.config.image_size)
            self._renderer = mujoco.Renderer(env.model, size, size)
        self._renderer.update_scene(env.data, camera="front")
        if self.config.fast_render:
            flags = self._renderer.scene.flags
            for flag in (
                mujoco.mjtRndFlag.mjRND_SHADOW,
                mujoco.mjtRndFlag.mjRND_REFLECTION,
                mujoco.mjtRndFlag.mjRND_SKYBOX,
            ):
                flags[flag] = 0
        return self._renderer.render().copy()

    def send_action(self, action: dict) -> dict:
        self._check()
        if not self._done:
            self._step(np.array([float(action[k]) for k in JOINT_KEYS]))
        return dict(action)

    def _step(self, action: np.ndarray) -> None:
        obs, _, terminated, truncated, info = self._env.step(action)
        self._obs, self._steps = obs, self._steps + 1
        self._success = self._scene_success(obs, info)
        self._done = bool(self._success or terminated or truncated or self._steps >= self.max_steps)

    def _scene_success(self, obs: dict, info: dict) -> bool:
        if self.config.scene == "reach_close":
            from lerobot_env_so101.policy import flatten_observation
            from lerobot_env_so101.scripted import is_reach_close_success

            return bool(is_reach_close_success(flatten_observation(obs)))
        return bool(info.get("succeed", False))

    # ------------------------------------------------------------------ the scripted operator's view
    def reset_scene(self) -> None:
        self._obs, _ = self._env.reset(seed=self.config.seed + self._episode)
        self._episode += 1
        self._steps, self._done, self._success = 0, False, False
        self._controller = None

    def episode_success(self) -> bool:
        return self._success

    def episode_done(self) -> bool:
        return self._done

    # ------------------------------------------------------------------ the package's scripted controller
    def scripted_joint_targets(self) -> np.ndarray:
        """The package's scripted controller's next move, as the joint targets its IK commands; the arm
        makes that move. (6,) rad in JOINT_KEYS order: what a demonstration of this arm records."""
        self._check()
        from lerobot_env_so101.policy import DEFAULT_ACTION_SCALE

        env = self._env
        if self.config.scene == "reach_close":
            from lerobot_env_so101.policy import flatten_observation
            from lerobot_env_so101.scripted import scripted_reach_close

            native = scripted_reach_close(flatten_observation(self._obs), DEFAULT_ACTION_SCALE)
        else:
            from lerobot_env_so101.scripted import PickPlaceController

            if self._controller is None:
                self._controller = PickPlaceController(DEFAULT_ACTION_SCALE)
            block = env.data.sensor("block_pos").data.copy()
            native = self._controller.act(env.ik_point_pos, block, env.goal_pos)
        ids = [env.model.actuator(j).id for j in JOINTS]
        self._step(np.asarray(native, dtype=np.float64))  # through the package's IK (4 values)
        return np.array(env.data.ctrl[ids], dtype=np.float64)
