"""The learner's state s and the base policy's observation, for a batch of simulator observations.

    s = (E(I), q)            the paper's actor-critic input (Sec. IV-A): frozen encoder features ‖ state
    s = (E(I), q, e(ℓ))      with `task_features` > 0: the frozen embedding of the task's instruction appended

Task features are a stand-in (docs/DEPARTURES.md): the paper's s carries no instruction — a camera shows
which part is in the gripper and ã carries the task. Our state-only simulator has no camera, so the
instruction's embedding stands in for what the image would show. Every method, the no-reference ablation
included, sees exactly the same s.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from accrue.errors import AccrueError

FeatureFn = Callable[[dict], np.ndarray]


def state_features(obs: dict) -> np.ndarray:
    """s for state observations with no image encoder: the sim's state vector itself."""
    return np.asarray(obs["state"], dtype=np.float32)


def encoder_features(encoder_spec: str) -> FeatureFn:
    """s = (E(I), q): frozen encoder features of the image (if any) ‖ the sim state vector."""
    if encoder_spec == "none":
        return state_features
    from accrue.encoders import make_encoder

    encoder = make_encoder(encoder_spec)

    def features(obs: dict) -> np.ndarray:
        if "image" not in obs:
            raise AccrueError(f"encoder {encoder_spec} needs image observations: set obs_mode: state+image")
        return np.concatenate([encoder.encode(obs["image"]), state_features(obs)], axis=1).astype(np.float32)

    return features


def with_task_features(features: FeatureFn, task_id: str, dim: int) -> FeatureFn:
    """`features` with the frozen hashed embedding of the task's instruction appended (the same text
    embedding the base policy is conditioned on), or `features` itself when dim is 0."""
    if dim <= 0:
        return features
    from accrue.policy.instruction_embedding import embed_instructions
    from accrue.sim import get_task

    code = embed_instructions([get_task(task_id).instruction], dim)[0].astype(np.float32)

    def with_task(obs: dict) -> np.ndarray:
        s = features(obs)
        return np.concatenate([s, np.broadcast_to(code, (len(s), dim))], axis=1)

    return with_task


def per_task_features(encoder_spec: str, task_features: int, task_ids: list[str]) -> dict[str, FeatureFn]:
    """task id -> its s(obs), sharing one frozen encoder."""
    base = encoder_features(encoder_spec)
    return {t: with_task_features(base, t, task_features) for t in task_ids}


def observation_from_state(s: np.ndarray, encoder_spec: str) -> dict:
    """The base policy's observation recovered from stored learner states (for fresh reference chunks at
    retained states). Only state-only runs can: with an image encoder the memory keeps E(I), not I."""
    if encoder_spec != "none":
        raise AccrueError(
            "learner.distill_inputs fresh/both needs state observations: the retained memory "
            f"keeps encoder features, not the images the base policy reads (encoder {encoder_spec})"
        )
    from accrue.sim import STATE_DIM

    return {"state": np.ascontiguousarray(np.asarray(s, dtype=np.float32)[:, :STATE_DIM])}
