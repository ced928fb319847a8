"""One episode on the robot, chunk by chunk at the control rate, and the chunk transitions it leaves.

    out = run_episode(bridge, settings, reference, policy, features, recorder, metadata, operator)

`reference(obs) -> (1, H, d)` is π_base's chunk (d = the robot's action keys) and `features(obs) -> (1, F)` the
learner's s = (E(I_1), ..., E(I_m), q), both of the bridge's observation batch ({"state": q, "images": one per
camera, ...}, RobotBridge.observation), so E(I) is computed here on the actor host once per chunk start and
stored with the transition; `policy(s, ref, fresh) -> (1, H, d)` what is executed (the reference itself for warmup and base-policy trials, the actor's refinement in training).
The episode ends when the robot says it is done (`mapping.done_key`), at the step limit, when the state
leaves the safety envelope, when the operator ends it, or when the robot faults (disconnect, timeout):
a faulted or unsafe episode is never a success. Rewards come later, from the operator's label
(`chunk_rewards`): sparse, 1 on the last three control steps of a successful episode.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from accrue.robot.bridge import ResetPose, RobotBridge, RobotFault
from accrue.robot.safety import SafetyEnvelope

SUCCESS_REWARD_STEPS = 3  # the sim's convention, kept on hardware so the two are comparable


@dataclass(frozen=True)
class EpisodeSettings:
    horizon: int
    max_steps: int
    control_hz: float
    clock: float = 1.0  # 1: real time; k > 1: k times faster; 0: as fast as the robot answers
    safety: SafetyEnvelope = SafetyEnvelope()
    late_after_s: float | None = None  # an observation slower than this is noted as late (default 2 periods)
    reset: ResetPose | None = None  # robot.reset_pose: driven to before the episode's first step (None: off)


@dataclass
class EpisodeOutcome:
    s: np.ndarray  # (T + 1, D) learner states at each chunk start, and the last one
    ref: np.ndarray  # (T + 1, H, d)
    action: np.ndarray  # (T, H, d) executed chunks
    steps: np.ndarray  # (T,) control steps of each chunk actually executed
    control_steps: int
    end: str  # done | time-limit | safety | fault | operator | abort
    reason: str = ""
    faults: list[str] = field(default_factory=list)
    wall_s: float = 0.0
    robot_time_s: float = 0.0  # control steps / control rate: the time the robot spent acting
    limited: int = 0  # commands the action envelope clipped (joint bounds, rate limits)
    intervention: np.ndarray | None = None  # (T, H) control steps the teleop drove (None: interventions off)

    @property
    def can_succeed(self) -> bool:
        return self.end in ("done", "time-limit", "operator")


def chunk_rewards(steps: np.ndarray, success: bool, gamma: float) -> np.ndarray:
    """R^(H) per chunk from the label: per-step reward 1 on the last SUCCESS_REWARD_STEPS control steps."""
    steps = np.asarray(steps, dtype=np.int64)
    total = int(steps.sum())
    out = np.zeros(len(steps), dtype=np.float32)
    if not success or total == 0:
        return out
    t0 = 0
    for i, n in enumerate(steps):
        for h in range(int(n)):
            if t0 + h >= total - SUCCESS_REWARD_STEPS:
                out[i] += gamma**h
        t0 += int(n)
    return out


def run_episode(
    bridge: RobotBridge,
    settings: EpisodeSettings,
    reference: Callable,
    policy: Callable,
    features: Callable,
    recorder,
    metadata: dict,
    poll: Callable[[], str | None] = lambda: None,
    intervene=None,
) -> EpisodeOutcome:
    """Drive one episode; never raises for a robot fault (the outcome says so). With `intervene`
    (accrue.robot.teleop.Intervention), a control step the operator takes over executes the teleop's action
    in place of the chunk's, and that step is marked in the outcome's `intervention`; a poll answer
    "intervene" toggles the takeover (signal: key) from the next control step."""
    from accrue.errors import AccrueError
    from accrue.sim.observation import STATE_NAMES, decode_state

    H, width = settings.horizon, bridge.mapping.action_dim
    period = 0.0 if settings.clock <= 0 else 1.0 / (settings.control_hz * settings.clock)
    late_after = settings.late_after_s or max(2.0 / settings.control_hz, 0.05)
    S, R, A, N, faults = [], [], [], [], []
    marks: list[np.ndarray] = []  # per chunk: which control steps the teleop drove
    end, reason, t = "time-limit", "", 0
    started = time.monotonic()
    recorder.start(0, metadata)
    state = None
    bridge.new_episode()
    if intervene is not None:
        intervene.new_episode(int(metadata.get("index", -1)))
    limited_before = bridge.limited
    try:
        if settings.reset is not None:  # its control steps are no episode's: not in t, not in robot time
            bridge.move_to(settings.reset, period)
            bridge.new_episode()  # the episode's rate limits start from where the reset left the arm
        state, done = bridge.observe()
        names = bridge.mapping.state_keys
        sim_state = tuple(names) == STATE_NAMES  # pose and wrench to log are readable by name
        while True:
            obs = bridge.observation()
            s, ref = features(obs), reference(obs)
            if np.shape(ref)[-1] != width:  # before the robot is sent anything
                raise AccrueError(
                    f"the base policy's chunks have {np.shape(ref)[-1]} actions per step and the robot takes {width} "
                    f"({', '.join(bridge.mapping.action_keys)}): fine-tune it on this robot's demos, or pick "
                    f"{np.shape(ref)[-1]} keys with robot.action_keys"
                )
            S.append(s[0])
            R.append(ref[0])
            if done:
                end = "done"
                break
            if t >= settings.max_steps:
                break
            chunk = np.array(policy(s, ref, np.array([t == 0])), dtype=np.float32)[
                0
            ]  # a copy: steps may be the human's
            mark = np.zeros(H, dtype=bool)
            executed = 0
            for h in range(H):
                tick = time.monotonic()
                if intervene is not None:
                    human = intervene.step(bridge.last_observation(), bridge.mapping)
                    if human is not None:  # the executed (and stored) action is the human's
                        chunk[h], mark[h] = human, True
                if not bridge.act(chunk[h]):
                    faults.append(f"command dropped at step {t}")
                state, done = bridge.observe()
                if bridge.last_latency_s > late_after:
                    faults.append(f"late observation at step {t}: {bridge.last_latency_s:.2f} s")
                frames = bridge.frames()
                extra = {"image": frames[0]} if frames else {}
                if sim_state:
                    d = decode_state(state[None])
                    extra |= {"ee_pose": d["pos"][0], "wrench": np.concatenate([d["force"][0], d["torque"][0]])}
                recorder.log_step(0, t, state, chunk[h], reference=ref[0] if h == 0 else None, **extra)
                executed += 1
                t += 1
                why = settings.safety.violation(state, names)
                if why:
                    end, reason = "safety", why
                    break
                if done or t >= settings.max_steps:
                    break
                wait = period - (time.monotonic() - tick)
                if wait > 0:
                    time.sleep(wait)
            A.append(chunk)
            N.append(executed)
            marks.append(mark)
            if end == "safety":
                break
            command = poll()
            if command == "intervene" and intervene is not None:
                intervene.toggle()
            if command in ("end", "abort"):
                end, reason = ("operator", "ended by the operator") if command == "end" else ("abort", "aborted")
                break
    except RobotFault as exc:
        end, reason = "fault", f"{exc.kind}: {exc}"
        faults.append(reason)
    if len(S) == len(A) and len(A):  # ended inside a chunk (fault, safety): the last observation closes it
        last = bridge.observation()  # the last one that arrived (a fault leaves the one before it)
        S.append(features(last)[0])
        R.append(reference(last)[0])
    return EpisodeOutcome(
        s=np.asarray(S, dtype=np.float32),
        ref=np.asarray(R, dtype=np.float32).reshape(len(R), H, width),
        action=np.asarray(A, dtype=np.float32).reshape(len(A), H, width),
        steps=np.asarray(N, dtype=np.int64),
        control_steps=t,
        end=end,
        reason=reason,
        faults=faults,
        wall_s=time.monotonic() - started,
        robot_time_s=t / settings.control_hz,
        limited=bridge.limited - limited_before,
        intervention=None if intervene is None else np.asarray(marks, dtype=bool).reshape(len(marks), H),
    )


def transitions(out: EpisodeOutcome, success: bool, gamma: float, episode: int) -> dict:
    """The episode's chunk transitions as arrays (what is sealed and what the learner ingests)."""
    T = len(out.action)
    done = np.zeros(T, dtype=bool)
    ended = np.zeros(T, dtype=bool)
    if T:
        ended[-1] = True
        done[-1] = bool(success)  # a success terminates; a failure is a truncation (it bootstraps)
    return {
        "s": out.s[: T + 1] if T else out.s[:0],
        "ref": out.ref[: T + 1] if T else out.ref[:0],
        "action": out.action,
        "steps": out.steps,
        "reward": chunk_rewards(out.steps, success, gamma),
        "done": done,
        "ended": ended,
        "episode": np.array(episode, dtype=np.int64),
    } | ({} if out.intervention is None else {"intervention": out.intervention})


def relabelled(arrays: dict, success: bool, gamma: float) -> dict:
    """The same transitions under a corrected label."""
    out = dict(arrays)
    out["reward"] = chunk_rewards(arrays["steps"], success, gamma)
    done = np.zeros(len(arrays["action"]), dtype=bool)
    if len(done):
        done[-1] = bool(success)
    out["done"] = done
    return out


def intervention_count(arrays: dict) -> int:
    """Control steps the teleop drove in one episode's transitions (0 where interventions were off)."""
    marks = arrays.get("intervention")
    if marks is None:
        return 0
    steps = np.asarray(arrays["steps"], dtype=np.int64)
    return int(sum(np.asarray(marks[i][: steps[i]]).sum() for i in range(len(steps))))


def chunk_interventions(arrays: dict) -> np.ndarray:
    """Per chunk transition of one episode: whether the teleop drove any of its control steps (HIL-SERL's
    intervention flag, per chunk; all False where interventions were off)."""
    marks = arrays.get("intervention")
    if marks is None:
        return np.zeros(len(arrays["action"]), dtype=bool)
    return np.asarray(marks, dtype=bool).reshape(len(arrays["action"]), -1).any(axis=1)


def intervention_rows(episodes: list[dict]) -> np.ndarray:
    """Per chunk transition that replay_from_episodes appends after the warmup rows, in the same order: its
    `chunk_interventions` flag (the replay's `intervention` column for those rows)."""
    rows = [chunk_interventions(e) for e in episodes if len(e["action"])]
    return np.concatenate(rows) if rows else np.zeros(0, dtype=bool)


def replay_from_episodes(warm, episodes: list[dict], task_index: int):
    """B^k: the warmup buffer followed by each episode's rows, in the order given; a row's `intervention` is
    set where the operator drove any control step of its chunk."""
    from accrue.learner import ReplayBuffer

    parts = [warm]
    for e in episodes:
        if len(e["action"]) == 0:
            continue
        b = ReplayBuffer(warm.state_dim, warm.horizon, warm.action_dim)
        b.add(
            e["s"][:-1],
            e["action"],
            e["ref"][:-1],
            e["reward"],
            e["s"][1:],
            e["ref"][1:],
            e["done"],
            task_index,
            int(e["episode"]),
            ended=e["ended"],
            intervention=chunk_interventions(e),
        )
        parts.append(b)
    return ReplayBuffer.concat(parts) if len(parts) > 1 else warm
