"""Run one simulated episode and record it for viewing: a rerun .rrd file, optionally an MCAP log.

What the recording holds (timeline `step`, one tick per control step):
  world/ee              plug-tip frame (transform + origin point), robot frame, metres
  world/socket          true socket pose (z = 0 plane), world/socket_estimate the noisy estimate the policy sees
  wrench/fx..tz         wrist force (N) and torque (N m) as scalars
  action/dx..dyaw       the normalised action taken
  reward, return        per-step reward and the return so far
  camera/front          the rendered camera image (with images=True)
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from accrue.errors import AccrueError

POLICIES = ("expert", "random")
WRENCH_NAMES = ("fx", "fy", "fz", "tx", "ty", "tz")


@dataclass(frozen=True)
class WatchResult:
    task_id: str
    policy: str
    seed: int
    steps: int
    success: bool
    episode_return: float
    rrd_path: Path
    mcap_path: Path | None


def default_rrd_path(task_id: str, policy: str, seed: int) -> Path:
    return Path(f"watch-{task_id.replace('/', '_')}-{policy}-seed{seed}.rrd")


def _policy(name: str, task_id: str, seed: int):
    if name == "expert":
        from accrue.sim import make_expert

        return make_expert(task_id, quality=1.0, seed=seed).act
    if name == "random":
        rng = np.random.default_rng(seed)
        return lambda state: rng.uniform(-1.0, 1.0, (len(state), 6)).astype(np.float32)
    raise AccrueError(f"unknown policy {name!r}; choose one of {', '.join(POLICIES)}")


def _log_rerun_step(
    rl,
    ee: np.ndarray,
    socket: np.ndarray,
    estimate: np.ndarray,
    wrench: np.ndarray,
    action: dict[str, float],
    reward: float,
    ret: float,
    image: np.ndarray | None,
) -> None:
    rl.pose("world/ee", ee[:3], ee[3:], color=(230, 120, 20))
    rl.pose("world/socket", socket[:3], socket[3:], color=(40, 160, 60))
    rl.pose("world/socket_estimate", estimate[:3], estimate[3:], radius=0.002, color=(120, 120, 220))
    rl.scalars("wrench", dict(zip(WRENCH_NAMES, map(float, wrench))))
    rl.scalars("action", action)
    rl.scalar("reward", reward)
    rl.scalar("return", ret)
    if image is not None:
        rl.image("camera/front", image)


def watch_episode(
    task_id: str,
    policy: str = "expert",
    seed: int = 0,
    out: Path | None = None,
    images: bool = False,
    mcap_dir: Path | None = None,
) -> WatchResult:
    """Run one episode of `task_id` with the expert or a random policy; write it to `out` (.rrd)."""
    from accrue.logs.mcap_episodes import EpisodeRecorder
    from accrue.logs.rerun_log import RerunLog
    from accrue.logs.sim_fields import state_fields, yaw_pose
    from accrue.sim import ACTION_NAMES, STATE_NAMES, get_task, make_vec_env

    spec = get_task(task_id)
    act = _policy(policy, task_id, seed)
    out = Path(out) if out is not None else default_rrd_path(task_id, policy, seed)
    env = make_vec_env(task_id, num_envs=1, seed=seed, obs_mode="state+image" if images else "state")
    recorder = (
        EpisodeRecorder(mcap_dir, control_hz=spec.control_hz, state_names=list(STATE_NAMES), camera="front")
        if mcap_dir
        else None
    )
    rec_id = f"watch-{task_id}-{policy}-seed{seed}"
    mcap_path = None
    try:
        with RerunLog(out, recording_id=rec_id, force=True) as rl:
            rl.text("episode", f"{task_id} ({spec.instruction}), policy {policy}, seed {seed}")
            obs = env.reset()
            if recorder:
                recorder.start(0, {"task_id": task_id, "instruction": spec.instruction, "seed": seed, "policy": policy})
            ret, t, success, truncated = 0.0, 0, False, False
            while True:
                state = obs["state"]
                action = np.asarray(act(state), dtype=np.float32).reshape(1, 6)
                res = env.step(action)
                reward = float(res.reward[0])
                ret += reward
                fields = state_fields(state[0])
                ee, estimate, wrench = fields["ee_pose"], fields["socket_estimate"], fields["wrench"]
                sx, sy, syaw = env.true_socket_pose()[0]
                socket = yaw_pose(sx, sy, 0.0, syaw)
                image = obs["image"][0] if images else None

                rl.set_step(t)
                _log_rerun_step(
                    rl, ee, socket, estimate, wrench, dict(zip(ACTION_NAMES, map(float, action[0]))), reward, ret, image
                )
                if recorder:
                    recorder.log_step(
                        0,
                        t,
                        state[0],
                        action[0],
                        reward=reward,
                        image=image,
                        ee_pose=ee,
                        socket_pose=socket,
                        wrench=wrench,
                    )
                t += 1
                obs = res.obs
                if bool(res.terminated[0] or res.truncated[0]):
                    success, truncated = bool(res.success[0]), bool(res.truncated[0])
                    break
            rl.text("episode", f"{'success' if success else 'no success'} after {t} steps, return {ret:g}")
            if recorder:
                mcap_path = recorder.end(0, success=success, truncated=truncated)
    finally:
        if recorder:
            recorder.close()
        env.close()
    return WatchResult(
        task_id=task_id,
        policy=policy,
        seed=seed,
        steps=t,
        success=success,
        episode_return=ret,
        rrd_path=out,
        mcap_path=mcap_path,
    )
