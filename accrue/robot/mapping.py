"""A robot's own lerobot features as accrue's vectors: q, its camera frames I, and its actions.

lerobot robots declare `observation_features` ({key: float} for a motor or sensor reading, {key: (h, w, 3)}
for a camera) and `action_features` ({key: float}). By default accrue takes them as declared:

    q = the scalar observations, in declared order (minus `done_key`)      -> s = (E(I), q)
    I = the camera frames, in declared order                                  (accrue.learner_inputs)
    a = the action keys, in declared order, in the base policy's own space (d = their number, the width
        of the learner's H x d chunks):
        action_mode delta   a in [-1, 1] times `action_limits` (robot units per unit; end-effector deltas)
        action_mode joint   a in [-1, 1] spread over `action_bounds` [lo, hi] (absolute joint targets);
                            without them, the ranges the robot's motor calibration gives (calibrated_bounds)

`state_keys`, `camera_keys`, `action_keys` pick and order a subset instead. `bind(features)` checks the
choice against what the robot declares and returns the resolved mapping; nothing maps onto simulator
quantities (the simulated robot `accrue_sim` declares its own 29 readings, accrue.sim.STATE_NAMES).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from accrue.errors import AccrueError

ACTION_MODES = ("delta", "joint")


def image_feature(camera: str) -> str:
    """The dataset and policy feature of a robot camera's frames: lerobot's `observation.images.<camera>`."""
    return f"observation.images.{camera}"


def is_camera(feature) -> bool:
    """lerobot declares a camera as its frame shape (h, w, 3); a scalar reading as `float`."""
    return isinstance(feature, (tuple, list)) and len(feature) == 3


@dataclass(frozen=True)
class RobotMapping:
    state_keys: tuple[str, ...] | None = None  # None: every scalar observation the robot declares
    camera_keys: tuple[str, ...] | None = None  # None: every camera it declares
    action_keys: tuple[str, ...] | None = None  # None: its action features
    action_mode: str = "delta"
    action_limits: tuple[float, ...] | None = None  # delta: robot units per unit of a (default 1)
    action_bounds: tuple[tuple[float, float], ...] | None = None  # joint: [lo, hi] per action key
    done_key: str | None = None  # optional observation key > 0.5 when the robot ends the episode itself
    # (camera, (top, left, height, width)): the region of that camera's frame read, resized to its declared size
    crop: tuple[tuple[str, tuple[int, int, int, int]], ...] = ()

    def __post_init__(self):
        if self.action_mode not in ACTION_MODES:
            raise AccrueError(f"robot.action_mode must be one of {', '.join(ACTION_MODES)} (got {self.action_mode!r})")
        if self.action_limits is not None and any(not (x > 0) for x in self.action_limits):
            raise AccrueError(f"robot.action_limits: must all be > 0 (got {list(self.action_limits)})")
        if self.action_bounds is not None and any(not (hi > lo) for lo, hi in self.action_bounds):
            raise AccrueError(f"robot.action_bounds: each [lo, hi] needs hi > lo (got {list(self.action_bounds)})")

    @classmethod
    def from_dict(cls, d: dict) -> "RobotMapping":
        opt = lambda k: tuple(d[k]) if d.get(k) else None  # noqa: E731
        bounds = d.get("action_bounds")
        return cls(
            state_keys=opt("state_keys"),
            camera_keys=tuple(d["camera_keys"]) if d.get("camera_keys") is not None else None,
            action_keys=opt("action_keys"),
            action_mode=d.get("action_mode") or "delta",
            action_limits=tuple(float(x) for x in d["action_limits"]) if d.get("action_limits") else None,
            action_bounds=tuple((float(lo), float(hi)) for lo, hi in bounds) if bounds else None,
            done_key=d.get("done_key"),
            crop=tuple((str(c), tuple(int(x) for x in box)) for c, box in (d.get("crop") or {}).items()),
        )

    # ------------------------------------------------------------------ against the robot's declaration
    def bind(self, observation_features: dict, action_features: dict, who: str, robot=None) -> "RobotMapping":
        """This mapping resolved against what `who` declares; one line naming the first misfit. `robot` (the
        lerobot Robot itself, where there is one) gives action_mode joint its bounds when the workflow
        sets none: its motors' calibrated ranges in the units it reads and takes (calibrated_bounds)."""
        scalars = [k for k, v in observation_features.items() if not is_camera(v) and k != self.done_key]
        cameras = [k for k, v in observation_features.items() if is_camera(v)]
        state = self.state_keys if self.state_keys is not None else tuple(scalars)
        cams = self.camera_keys if self.camera_keys is not None else tuple(cameras)
        acts = self.action_keys if self.action_keys is not None else tuple(action_features)
        for keys, have, what in ((state, scalars, "state_keys"), (cams, cameras, "camera_keys")):
            missing = [k for k in keys if k not in have]
            if missing:
                raise AccrueError(
                    f"{who}: observation has no {missing[0]!r} (robot.{what} wants {len(missing)} key(s) it "
                    f"lacks; it has {', '.join(list(have)[:6]) or 'none'}{'...' if len(have) > 6 else ''})"
                )
        missing = [k for k in acts if k not in action_features]
        if missing:
            raise AccrueError(
                f"{who}: action has no {missing[0]!r} (robot.action_keys; it has "
                f"{', '.join(list(action_features)[:6]) or 'none'})"
            )
        for camera, (top, left, height, width) in self.crop:
            if camera not in cams:
                raise AccrueError(f"robot.crop.{camera}: not one of the cameras read ({', '.join(cams) or 'none'})")
            h, w = tuple(observation_features[camera])[:2]
            if top + height > h or left + width > w:
                raise AccrueError(
                    f"robot.crop.{camera}: [top {top}, left {left}, height {height}, width {width}] reaches "
                    f"row {top + height}, column {left + width}, outside its {h} x {w} frame"
                )
        if not state:
            raise AccrueError(f"{who}: declares no scalar observation to use as q (robot.state_keys)")
        if not acts:
            raise AccrueError(f"{who}: declares no action key to act in (robot.action_keys)")
        bounds = self.action_bounds
        if self.action_mode == "joint" and bounds is None:
            bounds, lacking = calibrated_bounds(robot, acts)
            if lacking:
                raise AccrueError(
                    f"robot.action_bounds: action_mode joint needs one [lo, hi] per action key in the robot's "
                    f"units, and {who} gives no calibrated range for {', '.join(lacking)}: set robot.action_bounds "
                    f"for {', '.join(acts)}"
                )
        if self.action_mode == "joint" and len(bounds) != len(acts):
            raise AccrueError(
                f"robot.action_bounds: action_mode joint needs one [lo, hi] per action key ({', '.join(acts)}), "
                f"in the robot's units (got {len(bounds)})"
            )
        if self.action_limits is not None and len(self.action_limits) != len(acts):
            raise AccrueError(f"robot.action_limits: needs {len(acts)} entries, one per action key ({', '.join(acts)})")
        return replace(
            self, state_keys=tuple(state), camera_keys=tuple(cams), action_keys=tuple(acts), action_bounds=bounds
        )

    @property
    def action_dim(self) -> int:
        """d: the learner's chunks are H x d, one column per action key."""
        self._bound()
        return len(self.action_keys)

    def _bound(self) -> None:
        if self.state_keys is None or self.action_keys is None or self.camera_keys is None:
            raise AccrueError("robot mapping used before bind() resolved it against the robot's features")

    # ------------------------------------------------------------------ per observation / action
    def state(self, observation: dict) -> np.ndarray:
        self._bound()
        try:
            return np.array([float(observation[k]) for k in self.state_keys], dtype=np.float32)
        except KeyError as exc:
            raise AccrueError(f"robot observation lacks {exc.args[0]!r} (robot.state_keys)") from None

    def images(self, observation: dict) -> list[np.ndarray]:
        """The frames of camera_keys, (h, w, 3) uint8 each; a camera with a crop gives its region of interest,
        resized (bilinear) back to the frame's size, so the encoder and the base policy take it as a frame."""
        self._bound()
        try:
            frames = [np.asarray(observation[k], dtype=np.uint8) for k in self.camera_keys]
        except KeyError as exc:
            raise AccrueError(f"robot observation lacks camera {exc.args[0]!r} (robot.camera_keys)") from None
        boxes = dict(self.crop)
        return [crop_frame(f, boxes[k]) if k in boxes else f for k, f in zip(self.camera_keys, frames)]

    def done(self, observation: dict) -> bool:
        return self.done_key is not None and float(observation.get(self.done_key, 0.0)) > 0.5

    def _span(self) -> tuple[np.ndarray, np.ndarray]:
        """raw = centre + a * half, per action key."""
        n = len(self.action_keys)
        if self.action_mode == "joint":
            b = np.asarray(self.action_bounds, dtype=np.float64)
            return (b[:, 0] + b[:, 1]) / 2, (b[:, 1] - b[:, 0]) / 2
        half = np.asarray(self.action_limits or (1.0,) * n, dtype=np.float64)
        return np.zeros(n), half

    def action(self, normalised: np.ndarray) -> dict[str, float]:
        self._bound()
        a = np.clip(np.asarray(normalised, dtype=np.float64).reshape(len(self.action_keys)), -1.0, 1.0)
        centre, half = self._span()
        return {k: float(v) for k, v in zip(self.action_keys, centre + a * half)}

    def normalise(self, raw: np.ndarray) -> np.ndarray:
        """The inverse of action(), for recorded (T, A) robot actions (not clipped)."""
        self._bound()
        centre, half = self._span()
        return (np.asarray(raw, dtype=np.float64) - centre) / half


# ---------------------------------------------------------------------- units from the robot
_NORM_RANGES = {"range_m100_100": (-100.0, 100.0), "range_0_100": (0.0, 100.0)}


def crop_frame(frame: np.ndarray, box: tuple[int, int, int, int]) -> np.ndarray:
    """frame[top:top + height, left:left + width], resized (bilinear) to the frame's own (h, w)."""
    from PIL import Image

    top, left, height, width = box
    region = np.ascontiguousarray(frame[top : top + height, left : left + width])
    h, w = frame.shape[:2]
    if region.shape[:2] == (h, w):
        return region
    return np.asarray(Image.fromarray(region).resize((w, h), Image.Resampling.BILINEAR))


def _motor_buses(robot) -> list[tuple[str, object]]:
    """(key prefix, motor bus) of a lerobot robot: its own `bus`, and a bimanual robot's arms (`left_arm` ->
    keys `left_<motor>.pos`, lerobot's bi_so_follower naming)."""
    out = []
    bus = getattr(robot, "bus", None)
    if bus is not None and hasattr(bus, "motors"):
        out.append(("", bus))
    for name, part in sorted(vars(robot).items()) if robot is not None and hasattr(robot, "__dict__") else ():
        if name.endswith("_arm") and getattr(part, "bus", None) is not None and hasattr(part.bus, "motors"):
            out.append((name[: -len("_arm")] + "_", part.bus))
    return out


def _motor_range(bus, motor: str) -> tuple[float, float] | None:
    """[lo, hi] of one motor in the units the bus reads and takes (its MotorNormMode over its calibrated
    range_min..range_max, as lerobot's MotorsBus._normalize maps them), or None without a calibration."""
    spec = bus.motors.get(motor)
    calibration = (getattr(bus, "calibration", None) or {}).get(motor)
    if spec is None or calibration is None:
        return None
    mode = str(getattr(spec.norm_mode, "value", spec.norm_mode))
    if mode in _NORM_RANGES:
        return _NORM_RANGES[mode]
    if mode == "degrees":
        resolution = getattr(bus, "model_resolution_table", {}).get(spec.model)
        lo, hi = float(calibration.range_min), float(calibration.range_max)
        if not resolution or not hi > lo:
            return None
        half = (hi - lo) / 2 * 360.0 / (resolution - 1)
        return (-half, half)
    return None


def calibrated_bounds(robot, action_keys) -> tuple[tuple[tuple[float, float], ...] | None, list[str]]:
    """(the [lo, hi] of each action key from the robot's motor calibration, the keys that have none).
    A key `<motor>.pos` of a lerobot arm whose bus calibrates that motor: its normalisation mode's range
    (range_m100_100: [-100, 100]; range_0_100: [0, 100]; degrees: the calibrated range in degrees about
    its middle). Anything else (no bus, no calibration file yet, a key that is not a motor) lacks one."""
    found, lacking = [], []
    buses = _motor_buses(robot) if robot is not None else []
    for key in action_keys:
        span = None
        for prefix, bus in buses:
            if key.startswith(prefix) and key.endswith(".pos"):
                span = _motor_range(bus, key[len(prefix) : -len(".pos")])
                if span is not None:
                    break
        found.append(span)
        if span is None:
            lacking.append(key)
    return (None if lacking else tuple(found)), lacking
