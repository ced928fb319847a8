"""The learner's state s and the base policy's observation, for a batch of simulator observations.

    s = (E(I), q)            the paper's actor-critic input (Sec. IV-A): frozen encoder features ‖ state; on
                             a robot, E(I_1) ‖ ... ‖ E(I_m) over its cameras (robot.camera_keys' order)
    s = (E(I), q, e(ℓ))      with `task_features` > 0: the frozen embedding of the task's instruction appended
    s = (E(I), q, h, e(ℓ), g)   opt-in: h = the last `history` control steps (wrist force/torque, socket
                             estimate relative to the tip, action; observation.HISTORY_NAMES), g = the task's
                             geometry descriptor (`task_descriptor: geometry`)

The wrist force/torque is in q already; h gives s the memory a search needs (how long the plug has pushed
without sinking), which q alone cannot carry. g describes the part by numbers a task never seen still lands
among (clearance, depth, chamfer, 1/symmetry), unlike a hashed instruction, and has a fixed known scale:
it comes last, and the learner's normaliser passes those columns through unchanged (`fixed_tail`,
docs/DEPARTURES.md), so a descriptor constant during stage 1 is not blown up into noise at stage 2.

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


def camera_frames(obs: dict) -> list[np.ndarray]:
    """The observation's frames, one (B, h, w, 3) batch per camera: a robot's every camera in its
    camera_keys order (`images`, accrue.robot.bridge), or the simulator's one (`image`)."""
    if "images" in obs:
        return list(obs["images"])
    return [obs["image"]] if "image" in obs else []


def encoder_features(encoder_spec: str) -> FeatureFn:
    """s = (E(I_1), ..., E(I_m), q): the frozen encoder's features of each camera's frame (one encoder,
    its per-frame cache shared) ‖ the state vector."""
    if encoder_spec == "none":
        return state_features
    from accrue.encoders import make_encoder

    encoder = make_encoder(encoder_spec)

    def features(obs: dict) -> np.ndarray:
        frames = camera_frames(obs)
        if not frames:
            raise AccrueError(f"encoder {encoder_spec} needs image observations: set obs_mode: state+image")
        parts = [encoder.encode(f) for f in frames]
        return np.concatenate([*parts, state_features(obs)], axis=1).astype(np.float32)

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


DESCRIPTORS = ("none", "geometry")
# the geometry descriptor's columns and their fixed scale: (value - centre) / scale, so the built-in parts
# land within about ±2 and a new part of similar size lands among them
GEOMETRY_NAMES = ("clearance", "depth", "chamfer", "inv_symmetry")
_GEOMETRY_CENTRE = np.array([0.25e-3, 14e-3, 0.6e-3, 0.0])
_GEOMETRY_SCALE = np.array([0.05e-3, 4e-3, 0.1e-3, 1.0])


def geometry_descriptor(task_id: str) -> np.ndarray:
    """The task's part geometry at its fixed scale; inv_symmetry = 1/n of an n-fold fit (0 = round)."""
    from accrue.sim import get_task

    spec = get_task(task_id)
    n = int(spec.yaw_symmetry)
    raw = np.array([spec.clearance, spec.depth, spec.chamfer, 1.0 / n if n > 0 else 0.0])
    return ((raw - _GEOMETRY_CENTRE) / _GEOMETRY_SCALE).astype(np.float32)


def descriptor_dim(descriptor: str) -> int:
    """Columns the descriptor appends (the learner's fixed-scale tail)."""
    if descriptor not in DESCRIPTORS:
        raise AccrueError(f"task_descriptor must be one of {', '.join(DESCRIPTORS)}, got {descriptor!r}")
    return len(GEOMETRY_NAMES) if descriptor == "geometry" else 0


def with_history(features: FeatureFn, steps: int) -> FeatureFn:
    """`features` with the last `steps` control steps of obs["history"] appended (itself when steps is 0)."""
    if steps <= 0:
        return features
    from accrue.sim.observation import HISTORY_DIM, HISTORY_STEPS

    if steps > HISTORY_STEPS:
        raise AccrueError(f"history: at most {HISTORY_STEPS} control steps, got {steps}")
    width = steps * HISTORY_DIM

    def with_h(obs: dict) -> np.ndarray:
        if "history" not in obs:
            raise AccrueError("history > 0 needs observations with a history (the simulator's envs have one)")
        return np.concatenate([features(obs), np.asarray(obs["history"], dtype=np.float32)[:, :width]], axis=1)

    return with_h


def with_descriptor(features: FeatureFn, task_id: str, descriptor: str) -> FeatureFn:
    """`features` with the task descriptor appended last (itself for "none")."""
    if descriptor_dim(descriptor) == 0:
        return features
    code = geometry_descriptor(task_id)

    def with_g(obs: dict) -> np.ndarray:
        s = features(obs)
        return np.concatenate([s, np.broadcast_to(code, (len(s), len(code)))], axis=1)

    return with_g


def per_task_features(
    encoder_spec: str, task_features: int, task_ids: list[str], history: int = 0, descriptor: str = "none"
) -> dict[str, FeatureFn]:
    """task id -> its s(obs), sharing one frozen encoder. The defaults give today's s."""
    base = with_history(encoder_features(encoder_spec), history)
    return {t: with_descriptor(with_task_features(base, t, task_features), t, descriptor) for t in task_ids}


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
