"""A stand-in reference policy built from the scripted expert, for exercising RL where no competent
learned base policy is at hand (on CPU the embedded ACT reaches only a few percent on these tasks).

`ScriptedReference(known_bias)` answers `reference_chunk(obs, instruction, horizon)` like
accrue.policy.BasePolicy. Per chunk it asks a fresh (hence stateless: no search) scripted expert for
one action and holds it as a chunk: the first step moves the target, the remaining steps keep the
vertical command. The expert knows only the fraction `known_bias` of its fixture's socket-estimate
bias, so the reference misses the hole by a systematic, task-specific offset: exactly the kind of
local refinement the actor is meant to learn. It is not a learned policy and is never fine-tuned.
"""

from __future__ import annotations

import numpy as np

from accrue.errors import AccrueError

NAME = "scripted-reference"


def parse_spec(text: str) -> float | None:
    """'scripted-reference' or 'scripted-reference:F' -> F (default 0.0); None for anything else."""
    name, _, value = text.partition(":")
    if name != NAME:
        return None
    try:
        fraction = float(value) if value else 0.0
    except ValueError:
        raise AccrueError(f"base policy {text!r}: expected {NAME}[:F] with F in [0, 1]") from None
    if not 0.0 <= fraction <= 1.0:
        raise AccrueError(f"base policy {text!r}: the known bias fraction must be in [0, 1]")
    return fraction


class ScriptedReference:
    def __init__(self, known_bias: float = 0.0):
        self.known_bias = float(known_bias)

    def _task(self, instruction: str):
        from accrue.sim import get_task, list_tasks

        for task_id in list_tasks():
            if get_task(task_id).instruction == instruction:
                return get_task(task_id)
        raise AccrueError(f"scripted reference: no task has the instruction {instruction!r}")

    def reference_chunk(self, obs: dict, instruction: str, horizon: int) -> np.ndarray:
        from accrue.sim import make_expert

        task = self._task(instruction)
        correction = -np.asarray(task.estimate_bias, dtype=float) * self.known_bias
        action = make_expert(task, quality=1.0, seed=0, correction=correction).act(obs["state"])
        chunk = np.zeros((len(action), horizon, action.shape[1]), dtype=np.float32)
        chunk[:, 0] = action
        chunk[:, 1:, 2] = action[:, None, 2]
        return chunk
