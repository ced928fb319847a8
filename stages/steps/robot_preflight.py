"""What a robot workflow is checked for before any step runs (`accrue run`, `accrue stage run`) and what
`accrue robot check` adds on the robot itself (docs/robot-preflight.md).

`preflight(wf, source, store, tasks)` builds the robot of each task the run reaches - its lerobot type, its
config fields, never connected - and checks, in one `WORKFLOW: key: ...` line each:

- `robot.type` / `robot.imports`: a lerobot robot type this machine knows (its driver's SDK installed);
- `robot.config` / `robot.task_config.<task>`: fields of that type's config class, with values it takes;
- `robot.state_keys`, `robot.camera_keys`, `robot.action_keys`, `robot.action_bounds`/`action_limits`,
  `robot.safety`: against the features the robot declares (`observation_features`, `action_features`);
- `obs_mode` and `base_policy.init` against the robot's cameras and readings: a base policy that takes a
  camera image needs one on the robot (and obs_mode state+image), one that takes q needs as many readings;
- `robot.learner_address`: a name that resolves, and a link token to send (robot.link.token_file, or the
  store's).

A typo anywhere there is found in seconds, before finetune-base (which can take hours), and nothing moves.
`observe_once(...)` is `accrue robot check`'s part: it connects, reads one observation, checks it against
the bounds the workflow states, and disconnects - never sending an action.
"""

from __future__ import annotations

import dataclasses
import socket
import threading
from dataclasses import dataclass, field
from pathlib import Path

from stages.errors import StageError
from stages.workflow import Workflow

RESOLVE_TIMEOUT_S = 5.0


@dataclass
class RobotChecked:
    """What the preflight found for one task's robot."""

    task: str
    config_class: str
    mapping: object  # accrue.robot.mapping.RobotMapping, bound to the robot's features
    observation_features: dict
    action_features: dict
    make: object = None  # the function building this task's robot (accrue.robot.robot_types.lerobot_factory)


@dataclass
class Preflight:
    robots: list[RobotChecked] = field(default_factory=list)
    policy_inputs: dict | None = None  # the base policy's input shapes, where they can be known before a step
    learner: str | None = None  # "HOST:PORT (resolves to ...)" or None (the actor starts its own learner)


def _fail(source: str, line: str) -> StageError:
    return StageError(f"{source}: {line}")


def step_config(wf: Workflow, stage: int, phase: str = "warmup") -> dict:
    """The keyed robot config of a robot step of stage `stage`, as bind_robot gives it (robot_config_for reads it)."""
    from stages.steps.robot_plan import robot_config

    r = wf.robot
    robot = robot_config(wf)
    per_task = {t: dict(r.task_config[t]) for t in wf.tasks[:stage] if t in r.task_config}
    if per_task:
        robot["task_config"] = per_task
    return {"robot": robot, "seed": wf.seed, "stage": stage, "phase": phase}


def preflight(wf: Workflow, source: str, store, stages: tuple[int, int] | None = None) -> Preflight:
    """Every check above for the tasks of stages first..last (default: all); a StageError line on the first
    failure. Builds each task's robot (a lerobot Robot object) but never connects it."""
    from accrue.errors import AccrueError

    if wf.robot is None:
        return Preflight()
    first, last = stages or (1, wf.num_stages)
    out = Preflight()
    try:
        for k in range(first, last + 1):
            out.robots.append(_check_robot(wf, k))
        out.policy_inputs = _check_policy(wf, store, out.robots[0])
        out.learner = _check_learner(wf, store)
    except AccrueError as exc:
        raise _fail(source, str(exc)) from None
    return out


def _check_robot(wf: Workflow, stage: int) -> RobotChecked:
    """Stage `stage`'s task's robot: type, config fields and values, and the keys against its features."""
    from accrue.errors import AccrueError
    from accrue.robot.bridge import ResetPose
    from accrue.robot.mapping import RobotMapping
    from accrue.robot.robot_types import config_class, lerobot_factory
    from accrue.robot.safety import ActionEnvelope, SafetyEnvelope
    from stages.steps.robot_session import robot_config_for

    r, task = wf.robot, wf.task(stage)
    cls = config_class("robot", r.type, tuple(r.imports), where="robot", type_key="type")
    fields = sorted(f.name for f in dataclasses.fields(cls))
    own = {**r.config, **r.task_config.get(task, {})}
    for key in own:
        if key not in fields:
            where = f"robot.task_config.{task}" if key in r.task_config.get(task, {}) else "robot.config"
            raise AccrueError(
                f"{where}: {key!r} is not a field of {cls.__name__}, robot.type {r.type}'s config "
                f"(fields: {', '.join(f for f in fields if f != 'id')})"
            )
    keyed = step_config(wf, stage)
    config = robot_config_for(keyed, task)
    where = "robot.config" if task not in r.task_config else f"robot.config with robot.task_config.{task}"
    make = lerobot_factory("robot", r.type, config, tuple(r.imports), where="robot", type_key="type")
    try:
        robot = make()
    except AccrueError:
        raise
    except Exception as exc:  # noqa: BLE001 - the robot's own constructor refused its config
        text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise AccrueError(f"{where}: robot.type {r.type} refused it ({text})") from None
    try:
        obs, act = dict(robot.observation_features), dict(robot.action_features)
    except Exception as exc:  # noqa: BLE001 - a driver that cannot say what it reads without its hardware
        text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise AccrueError(f"robot.type {r.type}: cannot read the features it declares ({text})") from None
    mapping = RobotMapping.from_dict(keyed["robot"]).bind(obs, act, f"robot.type {r.type}", robot=robot)
    SafetyEnvelope.from_dict(r.safety).check_names(mapping.state_keys)
    ActionEnvelope.from_dict(r.safety).check_keys(mapping.action_keys)
    reset = ResetPose.from_dict(keyed["robot"].get("reset_pose"))
    if reset is not None:
        reset.check(mapping, obs, ActionEnvelope.from_dict(r.safety))
    if wf.obs_mode == "state+image" and not mapping.camera_keys:
        raise AccrueError(
            f"obs_mode: state+image needs a camera, and robot.type {r.type} declares none"
            + (
                " (robot.camera_keys is empty)"
                if r.camera_keys is not None
                else " (its cameras are set in robot.config)"
            )
        )
    return RobotChecked(task, cls.__name__, mapping, obs, act, make)


def _policy_input_shapes(wf: Workflow, store) -> tuple[str, dict | None]:
    """(what base_policy.init is, its input shapes or None where they are decided by the demos or unknown)."""
    from accrue.errors import AccrueError
    from accrue.policy.checkpoint import input_shapes, read_checkpoint_config
    from accrue.policy.from_scratch import SCRATCH_NAMES, scratch_config
    from accrue.scripted_reference import parse_spec

    init = wf.base_policy.init
    if parse_spec(init) is not None:
        return "scripted", None
    if init in SCRATCH_NAMES:
        images = scratch_config(init, wf.horizon).uses_images
        return "scratch", {"observation.image": None} if images else None
    path = Path(init).expanduser()
    if path.is_dir():
        try:
            return "checkpoint", input_shapes(read_checkpoint_config(path))
        except AccrueError as exc:
            raise AccrueError(f"base_policy.init: {exc}") from None
    return "artifact", _stored_input_shapes(store, init)


def _policy_action_width(init: str) -> int | None:
    """The width of the actions a checkpoint directory's policy outputs (its config.json), or None."""
    from accrue.policy.checkpoint import read_checkpoint_config

    shape = (read_checkpoint_config(Path(init).expanduser()).get("output_features") or {}).get("action", {})
    return int(shape["shape"][0]) if shape.get("shape") else None


def _stored_input_shapes(store, init: str) -> dict | None:
    """The input shapes in the config.json of the stored policy `init` (an artifact id or ref), else None."""
    import json

    from accrue.policy.checkpoint import CONFIG_FILE, input_shapes
    from artifacts.errors import StoreError
    from artifacts.manifests import read_artifact, read_tree
    from artifacts.resolve import resolve

    try:
        manifest = read_artifact(store, resolve(store, init))
        entries = {e["path"]: e["id"] for e in read_tree(store, manifest["content"])}
        if CONFIG_FILE not in entries:
            return None
        return input_shapes(json.loads(store.read_bytes(entries[CONFIG_FILE])))
    except (StoreError, ValueError, KeyError, TypeError):
        return None  # the plan says what is wrong with it, in its own line


def _check_policy(wf: Workflow, store, robot: RobotChecked) -> dict | None:
    """The base policy's inputs against the robot: a camera for a policy that takes images (and obs_mode
    state+image), as many readings in q as its observation.state."""
    from accrue.errors import AccrueError
    from accrue.policy.demo_sources import STATE_KEY

    kind, shapes = _policy_input_shapes(wf, store)
    if not shapes:
        return shapes
    init, r, m = wf.base_policy.init, wf.robot, robot.mapping
    images = [k for k in shapes if k.startswith("observation.image")]
    if images and not m.camera_keys:
        raise AccrueError(
            f"base_policy.init {init} takes a camera image ({images[0]}), and robot.type {r.type} declares no "
            "camera"
            + (
                " (robot.camera_keys is empty)"
                if r.camera_keys is not None
                else " (its cameras are set in robot.config)"
            )
        )
    if images and wf.obs_mode != "state+image":
        raise AccrueError(
            f"obs_mode: {wf.obs_mode}, but base_policy.init {init} takes a camera image ({images[0]}): "
            "set obs_mode: state+image"
        )
    named = [k[len("observation.images.") :] for k in images if k.startswith("observation.images.")]
    missing = [c for c in named if c not in m.camera_keys]
    if len(images) > 1 and missing:
        raise AccrueError(
            f"base_policy.init {init} takes the cameras {', '.join(images)}, and the robot has no camera "
            f"{missing[0]!r} (robot.camera_keys: {', '.join(m.camera_keys) or 'none'})"
        )
    width = _policy_action_width(init) if kind == "checkpoint" else None
    if width is not None and width != len(m.action_keys):
        raise AccrueError(
            f"base_policy.init {init} acts in {width} dimensions, and the robot takes {len(m.action_keys)} action "
            f"keys ({', '.join(m.action_keys)}): fine-tune it on this robot's demos, or pick {width} with "
            "robot.action_keys"
        )
    state = shapes.get(STATE_KEY)
    if kind != "scratch" and state and state[0] != len(m.state_keys):
        raise AccrueError(
            f"robot.state_keys: the robot's q has {len(m.state_keys)} readings ({', '.join(m.state_keys[:6])}"
            f"{'...' if len(m.state_keys) > 6 else ''}), and base_policy.init {init} takes an "
            f"{STATE_KEY} of {state[0]}"
        )
    return shapes


def resolve_host(host: str, port: int, timeout_s: float = RESOLVE_TIMEOUT_S) -> str:
    """The first address `host` resolves to; OSError (its strerror) when it does not, within timeout_s."""
    bare = host[1:-1] if host.startswith("[") and host.endswith("]") else host
    found: dict = {}

    def lookup() -> None:
        try:
            found["addr"] = socket.getaddrinfo(bare, port, type=socket.SOCK_STREAM)[0][4][0]
        except OSError as exc:
            found["error"] = exc

    worker = threading.Thread(target=lookup, daemon=True)
    worker.start()
    worker.join(timeout_s)
    if "addr" in found:
        return found["addr"]
    if "error" in found:
        exc = found["error"]
        raise OSError(exc.errno, exc.strerror or str(exc))
    raise OSError(0, f"no answer from the name service within {timeout_s:g} s")


def _check_learner(wf: Workflow, store) -> str | None:
    """robot.learner_address resolves, and there is a token to send it (robot.link.token_file or the store's)."""
    from accrue.errors import AccrueError
    from accrue.robot.link_auth import TOKEN_FILE, parse_address, read_token_file, validate_link_section

    r = wf.robot
    if r.learner_address is None:
        return None
    host, port = parse_address(r.learner_address, "robot.learner_address")
    try:
        addr = resolve_host(host, port)
    except OSError as exc:
        raise AccrueError(
            f"robot.learner_address: the name {host!r} does not resolve ({exc.strerror}); give the learner "
            "host's name or IP address"
        ) from None
    link = validate_link_section(r.link, "robot.link")
    if "token_file" in link:
        read_token_file(link["token_file"], "robot.link.token_file")
    else:
        token = Path(store.root) / TOKEN_FILE
        if not token.is_file():
            raise AccrueError(
                f"robot.learner_address: no link token to send the learner: the store has none yet ({token}); "
                "make it with `accrue robot token --out FILE` and start the learner with --token-file FILE "
                "(or set robot.link.token_file to the learner's token)"
            )
        read_token_file(token, f"store {store.root}")
    return f"{r.learner_address} ({addr})" if addr != host.strip("[]") else r.learner_address


@dataclass
class Observed:
    """One observation of the robot (`accrue robot check`): what it read and what is outside the bounds."""

    connect_s: float
    state: dict[str, float]
    cameras: dict[str, tuple]
    findings: list[str]


def observe_once(wf: Workflow, robot: RobotChecked, connect_s: float = 60.0) -> Observed:
    """Connect the robot of `robot.task`, read one observation, disconnect; never send an action.

    The observation is checked against what the workflow states: every reading of q finite, within
    robot.safety (its workspace, speed, force and torque where q shows them; its joint_bounds) and, with
    action_mode joint, each commanded key's reading within robot.action_bounds; every camera frame of the
    shape the robot declares. Each finding is one line naming the key; a robot that cannot be connected or
    read is an AccrueError line."""
    import math
    import time

    import numpy as np

    from accrue.errors import AccrueError
    from accrue.robot.bridge import RobotBridge, RobotFault, Timeouts
    from accrue.robot.safety import ActionEnvelope, SafetyEnvelope

    r = wf.robot
    safety, actions = SafetyEnvelope.from_dict(r.safety), ActionEnvelope.from_dict(r.safety)
    # a first connect also loads the driver's libraries (a simulator: tens of seconds on a busy machine)
    timeouts = dataclasses.replace(
        Timeouts.from_dict(r.timeouts), connect_s=max(connect_s, r.timeouts.get("connect_s", 0))
    )
    bridge = RobotBridge(robot.make, robot.mapping, timeouts, safety=safety, actions=actions)
    started = time.monotonic()
    try:
        bridge.connect()
        took = time.monotonic() - started
        bridge.observe()
        obs = bridge.last_observation()
    except RobotFault as exc:
        raise AccrueError(f"robot.type {r.type} (task {robot.task}): {exc}") from None
    finally:
        bridge.disconnect()
    m = bridge.mapping
    state = {k: float(obs[k]) for k in m.state_keys}
    findings = [f"robot.state_keys: {k} reads {v} (not a number)" for k, v in state.items() if not math.isfinite(v)]
    violation = safety.violation(np.array(list(state.values())), m.state_keys)
    if violation:
        findings.append(f"robot.safety: {violation}")
    bounds = dict(actions.bounds)
    where = dict.fromkeys(bounds, "robot.safety.joint_bounds")
    if m.action_mode == "joint":
        for key, (lo, hi) in zip(m.action_keys, m.action_bounds):
            bounds.setdefault(key, (lo, hi))
            where.setdefault(key, "robot.action_bounds")
    for key, (lo, hi) in bounds.items():
        if key in obs and not lo <= float(obs[key]) <= hi:
            findings.append(f"{where[key]}: {key} reads {float(obs[key]):.4g}, outside [{lo:g}, {hi:g}]")
    cameras = {}
    for key in m.camera_keys:
        frame = np.asarray(obs.get(key))
        cameras[key] = tuple(frame.shape)
        declared = tuple(int(s) for s in robot.observation_features[key])
        if frame.shape != declared:
            findings.append(
                f"robot.camera_keys: {key} gave a frame of shape {list(frame.shape)}, declared {list(declared)}"
            )
    return Observed(took, state, cameras, findings)


def reach_learner(wf: Workflow, store, timeout_s: float = 5.0) -> str:
    """`Hello` to robot.learner_address with the link token (and TLS): what answered, in one line; an
    AccrueError line for a learner that refuses this actor or does not answer."""
    from accrue.errors import AccrueError
    from accrue.robot.learner_client import refusal_line
    from accrue.robot.link_auth import link_auth_for
    from accrue.robot.transport import PROTOCOL, LinkRefused, Peer, PeerDown

    r = wf.robot
    auth = link_auth_for(r.model_dump(), store.root)
    peer = Peer(r.learner_address, auth.token, tls_ca=auth.tls_ca)
    try:
        hello, _ = peer.call("Hello", {"protocol": PROTOCOL}, timeout=timeout_s)
    except LinkRefused as exc:
        raise AccrueError(f"robot.learner_address: {refusal_line(r.learner_address, exc, auth)}") from None
    except PeerDown as exc:
        raise AccrueError(f"robot.learner_address: the learner does not answer ({exc})") from None
    finally:
        peer.close()
    return (
        f"the learner at {r.learner_address} answered (accrue {hello.get('accrue')}, protocol {hello.get('protocol')})"
    )
