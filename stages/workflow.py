"""Workflow files: a YAML task sequence with its method, base policy, learner settings and budgets.

    wf = load_workflow(Path("workflows/quickstart.yaml"))   # raises StageError, one line

Every mistake becomes one line naming the file, the field and the problem, e.g.
`workflows/x.yaml: learner.batch_size: must be a positive integer (got -3)`.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Literal, Optional

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from accrue import tracking as _tracking
from accrue.methods import METHODS
from stages.errors import StageError

_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$")


class _Strict(BaseModel):
    # inf/nan pass `gt=0` and fail minutes later; refuse them here, naming the field
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    @field_validator("*", mode="before")
    @classmethod
    def _no_bool_numbers(cls, value: Any, info: Any) -> Any:
        """YAML's `true` would be read as the number 1: a number field takes numbers only."""
        if isinstance(value, bool) and _is_number_type(cls.model_fields[info.field_name].annotation):
            raise ValueError(f"must be a number, not {str(value).lower()}")
        return value


def _is_number_type(annotation: Any) -> bool:
    import types
    import typing

    if annotation in (int, float):
        return True
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(annotation) if a is not type(None)]
        return bool(args) and all(a in (int, float) for a in args)
    return False


class BasePolicySpec(_Strict):
    """Where π_base starts and how it is fine-tuned on the cumulative demos D^1..D^k each stage."""

    init: str = "embedded-mlp"  # "embedded-mlp", "embedded-act", a lerobot checkpoint dir, or an artifact id/ref
    finetune: bool = True
    finetune_steps: int = Field(200, gt=0)
    batch_size: int = Field(16, gt=0)
    lr: float = Field(1e-4, gt=0)
    demos_per_task: int = Field(10, gt=0)
    demos: dict[str, str] = {}  # task id -> artifact id/ref of recorded demos (else the expert's)
    demo_quality: float = Field(1.0, ge=0, le=1)  # scripted expert's quality when it records demos
    demo_search: bool = True  # False: the demonstrator never searches (Markovian demos)
    demo_bias_known: float = Field(1.0, ge=0, le=1)  # fraction of each fixture's estimate bias it corrects
    demo_retention: float = Field(1.0, gt=0, le=1)  # fraction of earlier tasks' demos kept (paper Table VI)


class Budgets(_Strict):
    """Per-stage interaction budget and evaluation grid (paper Sec. V-A: shared budget, uniform grid)."""

    env_steps: int = Field(gt=0)
    eval_every: int = Field(gt=0)
    eval_episodes: int = Field(10, gt=0)  # the selection set: each stage's best checkpoint is chosen on it
    report_episodes: int = Field(0, ge=0)  # a disjoint set the chosen checkpoint is reported on (0 = none)
    # True: score every earlier task at every grid point (retention curves in the plots); False: only at
    # each stage's chosen checkpoint, which is all the continual metrics read (the same metrics, fewer episodes)
    full_curves: bool = False
    warmup_episodes: int = Field(2, ge=0)
    num_envs: int = Field(8, gt=0)
    retained_episodes: int = Field(20, ge=0)  # N: episodes per task kept in B^{<k+1} at handoff
    checkpoint_every: int = Field(0, ge=0)  # env steps between intra-step checkpoints (0 = at eval points)
    log_episodes: int = Field(1, ge=0)  # evaluation episodes per task recorded to MCAP (0 = none)

    @model_validator(mode="after")
    def _grid(self) -> "Budgets":
        if self.eval_every > self.env_steps:
            raise ValueError(f"eval_every must be <= env_steps ({self.env_steps}) (got {self.eval_every})")
        return self


class HoldSpec(_Strict):
    """When the actor stops acting for want of a learner (stages.steps.robot_session.LearnerHold)."""

    # robot time (s) the actor may act while the learner does not answer; past it the episode in progress
    # is discarded and the robot held (no commands)
    staleness_s: float = Field(30.0, gt=0)
    wait_s: float = Field(300.0, ge=0)  # wall time (s) held for the learner to come back before the step ends


class InterventionSpec(_Strict):
    """The operator takes over through a lerobot Teleoperator (beyond the paper; absent = off, the paper).
    A session setting (accrue.robot.teleop): the steps it drives are marked and counted, never keyed."""

    teleop: str  # a lerobot TeleoperatorConfig registry name: keyboard_ee, gamepad, so101_leader, accrue_sim_expert
    config: dict[str, Any] = {}  # that teleoperator config's fields
    imports: list[str] = []  # modules registering a third-party teleoperator type
    # events: the teleop's own IS_INTERVENTION (a held button or key); key: the operator's `i` toggles it
    signal: Literal["events", "key"] = "events"
    action_map: dict[str, str] = {}  # robot action key -> teleop action key (default: the same names)
    action_scale: dict[str, float] = {}  # robot action key -> factor on the teleop's value (robot units)
    # a teleop call (events, action, feedback) slower than this ends the episode as a fault (never a hang)
    timeout_s: float = Field(1.0, gt=0)


class ResetPoseSpec(_Strict):
    """A fixed joint pose the arm is driven to before each episode (accrue.robot.bridge.ResetPose)."""

    pose: dict[str, float] = Field(min_length=1)  # action key -> target, in the robot's action units
    tolerance: float = Field(gt=0)  # reached when every key of the pose reads within this of its target
    max_steps: int = Field(200, gt=0)  # control steps to reach it, each moving at most robot.safety.max_step


class ScriptedSpec(_Strict):
    """The scripted operator (accrue.robot.operator.ScriptedOperator): labels from the robot's own success."""

    delay_s: float = Field(0.0, ge=0)  # wall time it takes to answer each label
    mistakes: list[int] = []  # episode indices it labels wrongly
    corrects: list[int] = []  # of those, the ones it re-labels at the next reset
    abort_before: Optional[int] = None  # it aborts the session before this episode index


class SuccessClassifierSpec(_Strict):
    """A success classifier learned from the operator's labels (accrue.robot.success_classifier; beyond the
    paper, HIL-SERL's reward classifier): a logistic head on E(I) of each episode's last frame, in warmup and
    train. Keyed in those steps only when enabled (its labels become rewards); evaluate-all stays the operator's."""

    enabled: bool = False
    # operator labels (of both outcomes, held-out ones not counted; train counts those of the stage's warmup,
    # which it starts from) before it proposes or labels anything
    min_labels: int = Field(8, ge=2)
    propose: bool = True  # the operator sees its proposal and confirms or overrules it (below auto_label_above)
    # it labels alone (by: classifier, p in episode.json) when max(p, 1 - p) is above this; none: never alone
    auto_label_above: Optional[float] = Field(None, ge=0, le=1)
    # share of operator-labelled episodes it is never shown nor trained on: its precision and recall in the report
    holdout: float = Field(0.25, ge=0, lt=1)
    # spot check: every N-th episode it would label alone goes to the operator anyway (blind) and joins the
    # held-out set, so that set keeps growing once it labels most episodes; none: off
    audit_every: Optional[int] = Field(10, ge=1)
    state: bool = False  # q of the last frame beside E(I) in its input


class RobotSpec(_Strict):
    """A lerobot robot runs warmup, train and evaluate-all (paper Sec. V-C; accrue/robot, stages/steps/hw_*).
    The fields from `operator` down are session settings: they do not enter any cache key."""

    type: str  # a lerobot RobotConfig registry name, e.g. accrue_sim
    config: dict[str, Any] = {}  # that robot config's fields
    # {task id: {field: value}}: fields of the robot's config that differ per task (a scene, a fixture, a
    # camera), merged over `config` wherever the robot is built for that task (stages.steps.robot_session)
    task_config: dict[str, dict[str, Any]] = {}
    imports: list[str] = []  # modules registering a third-party robot type
    # s = (E(I_1), ..., E(I_m), q) and actions from the robot's own lerobot features (accrue.robot.mapping):
    # by default q is every scalar observation it declares, I_1..I_m its cameras in declared order, a its
    # action keys (the learner's chunks are H x their number); these pick and order a subset
    state_keys: Optional[list[str]] = None
    camera_keys: Optional[list[str]] = None
    action_keys: Optional[list[str]] = None
    action_mode: Literal["delta", "joint"] = "delta"  # end-effector deltas, or absolute joint targets
    action_limits: Optional[list[float]] = None  # delta: robot units per unit of normalised action, per key
    # joint: [lo, hi] per action key, robot units (unset: the ranges of the robot's motor calibration)
    action_bounds: Optional[list[list[float]]] = None
    done_key: Optional[str] = None  # observation key > 0.5 when the robot ends an episode itself
    # action_mode joint: driven to before each episode, through robot.safety's max_step and joint_bounds
    reset_pose: Optional[ResetPoseSpec] = None
    # {camera: [top, left, height, width]}: the region of its frame (pixels) the encoder and the base policy
    # read, resized back to the frame size the robot declares
    crop: dict[str, list[int]] = {}
    control_hz: Optional[float] = Field(None, gt=0)  # default: the task's
    episode_steps: Optional[int] = Field(None, gt=0)  # default: the task's max_steps
    # workspace_min_m/max_m [x,y,z], max_speed_m_s, max_force_n, max_torque_nm (where q shows pose and
    # wrench); joint_bounds {key: [lo, hi]} and max_step {key: units per control step} on the commands sent
    safety: dict[str, Any] = {}
    stop_window: int = Field(20, gt=0)  # the running-success window ...
    stop_successes: int = Field(19, gt=0)  # ... and the successes in it that end the stage (19/20)
    budget_s: float = Field(3600.0, gt=0)  # RL robot time per stage (s) when the stop rule is not reached
    max_episodes: int = Field(1000, gt=0)
    retention_trials: int = Field(20, ge=0)  # evaluate-all: operator-labelled trials per earlier task
    checkpoint_every: int = Field(200, gt=0)  # learner updates between sealed learner checkpoints
    publish_every: int = Field(20, gt=0)  # learner updates between weight snapshots for the actor
    operator: Literal["terminal", "scripted", "page"] = "terminal"
    operator_name: str = ""
    scripted: ScriptedSpec = ScriptedSpec()
    operator_page: dict[str, Any] = {}  # page: listen HOST:PORT (default 127.0.0.1:0), insecure (off loopback)
    learner_address: Optional[str] = None  # host:port of `accrue robot learner` (two hosts); none: local process
    link: Optional[dict[str, Any]] = None  # token_file, tls {cert, key, ca} (accrue.robot.link_auth)
    hold: HoldSpec = HoldSpec()
    intervention: Optional[InterventionSpec] = None  # operator takeover (beyond the paper); None: off
    success_classifier: SuccessClassifierSpec = SuccessClassifierSpec()  # learned labels (beyond the paper); off
    handoff_wait_s: float = Field(120.0, ge=0)  # train: wait for the learner's updates before the handoff
    clock: float = Field(1.0, ge=0)  # accrue_sim only: k times real time (0 = as fast as it goes)
    faults: dict[str, Any] = {}  # accrue_sim only: disconnect_after_steps, late_observation_steps...
    timeouts: dict[str, float] = {}  # connect_s, observation_s, action_s, reconnect_attempts

    @model_validator(mode="after")
    def _consistent(self) -> "RobotSpec":
        if self.stop_successes > self.stop_window:
            raise ValueError(f"stop_successes must be <= stop_window ({self.stop_window}) (got {self.stop_successes})")
        self._check_reset_and_crop()
        if self.type != "accrue_sim" and (self.clock != 1.0 or self.faults):
            raise ValueError(
                f"clock and faults apply to the simulated robot (type accrue_sim) only (got type {self.type!r})"
            )
        return self

    def _check_reset_and_crop(self) -> None:
        if self.reset_pose is not None:
            if self.action_mode != "joint":
                raise ValueError("reset_pose needs action_mode joint (a pose in the robot's joint targets)")
            steps = self.safety.get("max_step") or {}
            unlimited = [k for k in self.reset_pose.pose if k not in steps]
            if unlimited:
                raise ValueError(
                    f"reset_pose: {unlimited[0]!r} has no safety.max_step, which limits the reset's motion; set one"
                )
        for camera, box in self.crop.items():
            if len(box) != 4 or box[0] < 0 or box[1] < 0 or box[2] <= 0 or box[3] <= 0:
                raise ValueError(
                    f"crop.{camera}: needs [top, left, height, width] in pixels, top and left >= 0, "
                    f"height and width > 0 (got {box})"
                )
            if self.camera_keys is not None and camera not in self.camera_keys:
                raise ValueError(f"crop.{camera}: not one of camera_keys ({', '.join(self.camera_keys)})")


class WandbSpec(_Strict):
    """Weights & Biases, used only when asked for here (docs/TRACKING.md); offline needs no network.
    Defaults and modes are accrue.tracking's (WANDB_DEFAULTS, WANDB_MODES)."""

    project: str = _tracking.WANDB_DEFAULTS["project"]
    mode: Literal[_tracking.WANDB_MODES] = _tracking.WANDB_DEFAULTS["mode"]  # type: ignore[valid-type]
    entity: Optional[str] = _tracking.WANDB_DEFAULTS["entity"]


class TrackingSpec(_Strict):
    """Where train steps, robot sessions and bench cells write their scalars (accrue.tracking, whose
    defaults these are). Nothing here enters a cache key: event files sit beside the store's audit log,
    never in its objects."""

    tensorboard: bool = _tracking.DEFAULT_TENSORBOARD
    wandb: Optional[WandbSpec] = None
    # learner updates between two loss/Q points (eval points are all written)
    every: int = Field(_tracking.DEFAULT_EVERY, gt=0)


class Workflow(_Strict):
    name: str
    description: str = ""
    tasks: list[str] = Field(min_length=1)
    method: Literal[METHODS]  # type: ignore[valid-type]
    seed: int = Field(0, ge=0)
    horizon: int = Field(8, gt=0)  # action chunk length H
    obs_mode: Literal["state", "state+image"] = "state"
    encoder: str = "none"  # "none" or "dinov2-small:/path/weights.safetensors"
    # size of a frozen embedding of the task's instruction appended to the learner's s (0 = none): in
    # state-only runs nothing else tells the actor which part is in the gripper (a camera would)
    task_features: int = Field(0, ge=0, le=256)
    # opt-in learner inputs (accrue.learner_inputs): the last `history` control steps of wrist force/torque,
    # relative socket pose and action in s (at most accrue.sim.observation.HISTORY_STEPS = 8), and a task
    # descriptor with a fixed scale that lands in distribution for an unseen part ("geometry")
    history: int = Field(0, ge=0, le=8)
    task_descriptor: Literal["none", "geometry"] = "none"
    base_policy: BasePolicySpec = BasePolicySpec()
    learner: dict[str, Any] = {}  # LearnerConfig fields (accrue.learner.config)
    budgets: Budgets
    robot: Optional[RobotSpec] = None  # a robot instead of the simulator (hardware steps)
    tracking: TrackingSpec = TrackingSpec()  # TensorBoard / W&B scalars; outside every cache key

    @field_validator("name")
    @classmethod
    def _name(cls, v: str) -> str:
        if not _NAME_RE.match(v):
            raise ValueError("must be letters, digits, '.', '_' or '-' (it names refs)")
        return v

    @field_validator("tasks")
    @classmethod
    def _tasks(cls, v: list[str]) -> list[str]:
        dup = sorted({t for t in v if v.count(t) > 1})
        if dup:
            raise ValueError(f"task {dup[0]} appears twice")
        return v

    @property
    def num_stages(self) -> int:
        return len(self.tasks)

    def task(self, stage: int) -> str:
        """Task of stage k (1-based, as in the paper)."""
        self.check_stage(stage)
        return self.tasks[stage - 1]

    def check_stage(self, stage: int) -> int:
        if not 1 <= stage <= len(self.tasks):
            raise StageError(f"workflow {self.name} has stages 1..{len(self.tasks)} (got --stage {stage})")
        return stage

    def learner_settings(self) -> dict[str, Any]:
        """The learner section with the workflow's method and seed filled in."""
        return {"method": self.method, "seed": self.seed, **self.learner}


# ------------------------------------------------------------------------- loading
_PHRASES = {
    "greater_than": "must be > {gt}",
    "greater_than_equal": "must be >= {ge}",
    "less_than": "must be < {lt}",
    "less_than_equal": "must be <= {le}",
    "missing": "required field is missing",
    "extra_forbidden": "unknown field",
    "too_short": "must not be empty",
    "literal_error": "must be one of {expected}",
}


def _format_error(err: dict) -> str:
    from artifacts.errors import quote

    loc = (
        ".".join(
            str(p) if re.fullmatch(r"[\w/.+-]{1,100}", str(p)) else quote(p, 60)  # a key may be anything
            for p in err["loc"]
        )
        or "(top level)"
    )
    phrase = _PHRASES.get(err["type"])
    msg = phrase.format(**(err.get("ctx") or {})) if phrase else err["msg"]
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, ") :]
    elif not phrase:
        msg = msg[:1].lower() + msg[1:]
    if err["type"] not in ("missing", "extra_forbidden") and "(got" not in msg:
        msg += f" (got {quote(err.get('input'))})"  # bounded: an alias bomb must not become the message
    return f"{loc}: {msg}"


def parse_workflow(data: Any, source: str, default_name: str = "workflow") -> Workflow:
    if not isinstance(data, dict):
        raise StageError(f"{source}: expected a mapping of workflow fields, got {type(data).__name__}")
    data = {"name": default_name, **data}
    try:
        wf = Workflow.model_validate(data)
    except ValidationError as exc:
        errors = exc.errors()
        more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
        raise StageError(f"{source}: {_format_error(errors[0])}{more}") from None
    _check_learner(wf, source)
    _check_robot(wf, source)
    return wf


def _check_robot(wf: Workflow, source: str) -> None:
    """The learner's address and the page's listen address are refused at load, in one line, when malformed."""
    if wf.robot is None:
        return
    from accrue.errors import AccrueError
    from accrue.robot.link_auth import is_loopback, parse_address, validate_link_section

    r = wf.robot
    try:
        if r.learner_address is not None:
            parse_address(r.learner_address, "robot.learner_address")
        unknown = sorted(set(r.operator_page) - {"listen", "insecure"})
        if unknown:
            raise AccrueError(f"robot.operator_page: unknown key {unknown[0]!r} (known: listen, insecure)")
        insecure = r.operator_page.get("insecure", False)
        if not isinstance(insecure, bool):
            raise AccrueError(f"robot.operator_page.insecure: expected true or false, got {insecure!r}")
        if "listen" in r.operator_page:
            host, _ = parse_address(r.operator_page["listen"], "robot.operator_page.listen", allow_zero=True)
            # the page is plain HTTP and carries the link token: off loopback only when asked for
            if not is_loopback(host) and not insecure:
                raise AccrueError(
                    f"robot.operator_page.listen: {r.operator_page['listen']} is not loopback and the page "
                    "sends the link token in plain HTTP; use an SSH tunnel, or set operator_page.insecure: "
                    "true (a trusted LAN only)"
                )
        validate_link_section(r.link, "robot.link")
        if r.task_config:
            _check_task_config(wf)
        if r.success_classifier.enabled:
            _check_classifier(wf)
    except AccrueError as exc:
        raise StageError(f"{source}: {exc}") from None


def _check_classifier(wf: Workflow) -> None:
    """The success classifier reads the frozen encoder's features of the robot's cameras: both must be there."""
    from accrue.errors import AccrueError

    r = wf.robot
    if wf.encoder == "none":
        raise AccrueError(
            "robot.success_classifier: needs camera features, and encoder is none; set encoder (a frozen image "
            "encoder, docs/robots.md) or turn the classifier off"
        )
    no_cameras = r.camera_keys == [] or (
        r.type == "accrue_sim" and r.camera_keys is None and not r.config.get("render_cameras")
    )
    if no_cameras:
        raise AccrueError(
            "robot.success_classifier: needs a robot with cameras (robot.camera_keys, or config.render_cameras "
            "on accrue_sim); turn the classifier off or give it a camera"
        )


def _check_task_config(wf: Workflow) -> None:
    """robot.task_config names the workflow's tasks and fields of the robot's config class, with values the
    class takes over robot.config (importing the robot's modules, so only when the section is there): a bad
    value is refused at load, not when that task's stage first builds the robot."""
    import dataclasses

    from accrue.errors import AccrueError
    from accrue.robot.robot_types import config_class, decode_config

    r = wf.robot
    for task in r.task_config:
        if task not in wf.tasks:
            raise AccrueError(f"robot.task_config: {task!r} is not one of the workflow's tasks ({', '.join(wf.tasks)})")
    cls = config_class("robot", r.type, tuple(r.imports), where="robot", type_key="type")
    fields = sorted(f.name for f in dataclasses.fields(cls))
    for task, overrides in r.task_config.items():
        unknown = sorted(set(overrides) - set(fields))
        if unknown:
            raise AccrueError(
                f"robot.task_config.{task}: {unknown[0]!r} is not a field of {cls.__name__}, robot.type "
                f"{r.type}'s config (fields: {', '.join(fields)})"
            )
        if r.type == "accrue_sim" and "task" in overrides:  # robot_session.robot_config_for sets it per stage
            raise AccrueError(f"robot.task_config.{task}: task is the stage's own task on accrue_sim; leave it out")
        decode_config(cls, {**r.config, **overrides}, f"robot.task_config.{task}")


def _check_learner(wf: Workflow, source: str) -> None:
    """The learner section is checked by the learner's own config class, so the two never drift."""
    LearnerConfig = _learner_config_class()
    if LearnerConfig is None:
        return
    from accrue.errors import AccrueError

    if "method" in wf.learner and wf.learner["method"] != wf.method:
        raise StageError(
            f"{source}: learner.method: differs from the workflow's method "
            f"{wf.method!r} (got {wf.learner['method']!r}); set it once, at the top"
        )
    try:
        LearnerConfig.from_dict(wf.learner_settings())
    except AccrueError as exc:
        raise StageError(f"{source}: {exc}") from None
    except TypeError as exc:
        raise StageError(f"{source}: learner: {exc}") from None


def _learner_config_class():
    """accrue.learner.config.LearnerConfig without importing accrue.learner (whose __init__ pulls in
    torch, seconds of start-up): the config module itself only needs accrue.errors."""
    import importlib.util
    import sys

    if "accrue.learner.config" in sys.modules:
        return sys.modules["accrue.learner.config"].LearnerConfig
    try:
        package = importlib.util.find_spec("accrue.learner")
    except ImportError:
        return None
    if package is None or not package.submodule_search_locations:
        return None
    path = Path(next(iter(package.submodule_search_locations))) / "config.py"
    spec = importlib.util.spec_from_file_location("_accrue_learner_config", path)
    if spec is None or spec.loader is None or not path.is_file():
        return None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while building the class
    spec.loader.exec_module(module)
    return module.LearnerConfig


def _unique_keys_loader():
    """yaml.SafeLoader that refuses a key given twice in one mapping (safe_load keeps the last)."""
    import yaml

    class UniqueKeyLoader(yaml.SafeLoader):
        pass

    def mapping(loader: yaml.SafeLoader, node: yaml.MappingNode, deep: bool = False) -> dict:
        seen: set = set()
        for key_node, _ in node.value:
            key = loader.construct_object(key_node, deep=deep)
            try:
                duplicate = key in seen
                seen.add(key)
            except TypeError:  # an unhashable key: the constructor below refuses it
                continue
            if duplicate:
                from artifacts.errors import quote

                raise yaml.constructor.ConstructorError(
                    None, None, f"duplicate key {quote(key, 100)}", key_node.start_mark
                )
        return loader.construct_mapping(node, deep=deep)

    UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, mapping)
    return UniqueKeyLoader


def load_workflow(path: Path | str) -> Workflow:
    import yaml

    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise StageError(f"{path}: no such workflow file") from None
    except IsADirectoryError:
        raise StageError(f"{path}: is a directory, not a workflow file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise StageError(f"{path}: cannot read ({exc.__class__.__name__})") from None
    try:
        data = yaml.load(text, Loader=_unique_keys_loader())  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise StageError(f"{path}: YAML syntax error at {where}{problem}") from None
    return parse_workflow(data, str(path), default_name=path.stem)
