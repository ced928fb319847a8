"""Record every episode of a vectorised accrue.sim loop as MCAP, from what the loop already has.

    logger = VecEpisodeLogger(EpisodeRecorder(dir, control_hz=spec.control_hz), env.num_envs,
                              {"task_id": task_id, "policy": "actor@stage2"})
    obs = env.reset(); logger.begin()
    while ...:
        res = env.step_chunk(chunks, gamma)                 # or env.step(actions)
        logger.log(obs["state"], chunks, res, reference=ref)  # seals the episodes that ended
        if res.done.any(): obs = env.reset(res.done); logger.begin(res.done)
        else: obs = res.obs

Inside an action chunk only the first step has an observed state, so `/state`, poses and the
wrench are logged on that step; every executed step gets its action and reward.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from accrue.errors import AccrueError
from accrue.logs.mcap_episodes import EpisodeRecorder


def _sim_state_fields(state: np.ndarray) -> dict[str, np.ndarray]:
    from accrue.logs.sim_fields import state_fields

    f = state_fields(state)
    return {"ee_pose": f["ee_pose"], "socket_pose": f["socket_estimate"], "wrench": f["wrench"]}


class VecEpisodeLogger:
    """Starts, fills and seals one MCAP episode per env of a vectorised loop."""

    def __init__(
        self,
        recorder: EpisodeRecorder,
        num_envs: int,
        metadata: Mapping[str, Any] | None = None,
        fields: Callable[[np.ndarray], dict[str, Any]] | None = _sim_state_fields,
    ) -> None:
        self.recorder = recorder
        self.num_envs = int(num_envs)
        self.metadata = dict(metadata or {})
        self.fields = fields
        self.t = np.zeros(self.num_envs, dtype=np.int64)
        self.recording = np.zeros(self.num_envs, dtype=bool)

    def begin(self, mask: np.ndarray | None = None, metadata: Mapping[str, Any] | None = None) -> None:
        """New episodes started in the envs of `mask` (all when None): call right after env.reset(mask)."""
        ids = range(self.num_envs) if mask is None else np.flatnonzero(np.asarray(mask, dtype=bool))
        for i in ids:
            self.recorder.start(int(i), {**self.metadata, **(metadata or {})})
            self.t[i] = 0
            self.recording[i] = True

    def log(
        self,
        states: np.ndarray,
        actions: np.ndarray,
        result: Any,
        reference: np.ndarray | None = None,
        images: np.ndarray | None = None,
    ) -> list[Path]:
        """Log one env.step / env.step_chunk result; returns the episode files sealed by it.

        `states` (N, D) and `images` (N, h, w, 3) are the observation the actions were chosen
        from, `actions` (N, 6) or (N, H, 6), `reference` the (N, H, 6) reference chunks.
        """
        acts = np.asarray(actions, dtype=np.float32)
        acts = acts[:, None, :] if acts.ndim == 2 else acts
        if acts.shape[0] != self.num_envs:
            raise AccrueError(f"actions are for {acts.shape[0]} envs, the logger has {self.num_envs}")
        per_step = np.asarray(getattr(result, "rewards", np.asarray(result.reward)[:, None]), dtype=float)
        steps = np.asarray(getattr(result, "steps", np.ones(self.num_envs, dtype=np.int64)))
        done = np.asarray(result.terminated, dtype=bool) | np.asarray(result.truncated, dtype=bool)
        sealed: list[Path] = []
        for i in np.flatnonzero(self.recording):
            for h in range(int(steps[i])):
                first = h == 0
                extra = self.fields(states[i]) if first and self.fields is not None else {}
                self.recorder.log_step(
                    int(i),
                    int(self.t[i]),
                    state=states[i] if first else None,
                    action=acts[i, h],
                    reference=reference[i] if first and reference is not None else None,
                    reward=float(per_step[i, h]),
                    image=images[i] if first and images is not None else None,
                    **extra,
                )
                self.t[i] += 1
            if done[i]:
                sealed.append(
                    self.recorder.end(
                        int(i),
                        success=bool(np.asarray(result.success)[i]),
                        truncated=bool(np.asarray(result.truncated)[i]),
                    )
                )
                self.recording[i] = False
        return sealed

    def close(self) -> None:
        """Drop the episodes still running (they did not end, so they are not logs)."""
        self.recorder.close()
        self.recording[:] = False
