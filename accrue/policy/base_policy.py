"""The base policy pi_base seen only through its input-output interface: observation + instruction in,
an H-step action chunk out (paper Sec. III-A). Backed by any lerobot checkpoint in a local directory."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from accrue.errors import AccrueError
from accrue.policy.checkpoint import (
    NEEDS_EXTRAS,
    check_policy_type_known,
    first_line,
    input_shapes,
    read_checkpoint_config,
)
from accrue.policy.demo_sources import STATE_KEY
from accrue.policy.instruction_embedding import ENV_STATE_KEY, embed_instructions

# policies whose predict_action_chunk returns the whole chunk of one observation, with no queue
ONE_PASS_CHUNK_TYPES = ("act", "accrue_chunk_mlp")


def _load_lerobot_parts(checkpoint_dir: Path, policy_type: str, device: str):
    """(policy, preprocessor, postprocessor); loading errors become one-line AccrueErrors."""
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    try:
        config = PreTrainedConfig.from_pretrained(checkpoint_dir)
        config.device = device
        policy_cls = get_policy_class(policy_type)
        policy = policy_cls.from_pretrained(checkpoint_dir, config=config)
        pre, post = make_pre_post_processors(
            config,
            pretrained_path=str(checkpoint_dir),
            preprocessor_overrides={"device_processor": {"device": device}},
            postprocessor_overrides={"device_processor": {"device": "cpu"}},
        )
    except Exception as exc:  # noqa: BLE001 - third-party loaders raise anything; the user needs one line
        needs = NEEDS_EXTRAS.get(policy_type)
        hint = f"; policy type '{policy_type}' needs {needs}" if needs else ""
        raise AccrueError(f"cannot load policy checkpoint {checkpoint_dir}: {first_line(exc)}{hint}") from exc
    policy.eval()
    return config, policy, pre, post


class BasePolicy:
    """A frozen lerobot policy that returns reference action chunks in the env's action space."""

    def __init__(self, checkpoint_dir: Path, config, policy, preprocessor, postprocessor, device: str, seed: int):
        self.checkpoint_dir = checkpoint_dir
        self.config = config
        self.policy = policy
        self.preprocessor = preprocessor
        self.postprocessor = postprocessor
        self.device = device
        self.seed = seed
        shapes = {k: v.shape for k, v in config.input_features.items()}
        self.state_dim = int(shapes[STATE_KEY][0]) if STATE_KEY in shapes else 0
        self.instruction_dim = int(shapes[ENV_STATE_KEY][0]) if ENV_STATE_KEY in shapes else 0
        self.image_keys = sorted(k for k in shapes if k.startswith("observation.image"))
        self.action_dim = int(config.output_features["action"].shape[0])

    @classmethod
    def load(cls, checkpoint_dir: Path | str, device: str = "cpu", seed: int = 0) -> "BasePolicy":
        checkpoint_dir = Path(checkpoint_dir)
        raw = read_checkpoint_config(checkpoint_dir)
        policy_type = raw["type"]
        check_policy_type_known(policy_type, checkpoint_dir)
        if not input_shapes(raw):
            raise AccrueError(f"policy checkpoint {checkpoint_dir}: config.json lists no input_features")
        config, policy, pre, post = _load_lerobot_parts(checkpoint_dir, policy_type, device)
        return cls(checkpoint_dir, config, policy, pre, post, device, seed)

    @property
    def policy_type(self) -> str:
        return self.config.type

    @property
    def max_horizon(self) -> int:
        """The longest chunk one call can return without re-planning on a stale observation."""
        if self.policy_type in ONE_PASS_CHUNK_TYPES:
            return int(self.config.chunk_size)
        return int(self.config.n_action_steps)

    def _batch(self, obs: dict, instructions: list[str]) -> dict:
        import torch

        if "state" not in obs:
            raise AccrueError("observation batch has no 'state' entry")
        state = np.asarray(obs["state"], dtype=np.float32)
        if state.ndim != 2 or state.shape[1] != self.state_dim:
            raise AccrueError(
                f"observation 'state' has shape {list(state.shape)}; policy {self.checkpoint_dir} expects (B, {self.state_dim})"
            )
        batch_size = state.shape[0]
        if len(instructions) != batch_size:
            raise AccrueError(f"got {len(instructions)} instructions for a batch of {batch_size} observations")
        batch = {STATE_KEY: torch.from_numpy(state), "task": list(instructions)}
        if self.instruction_dim:
            batch[ENV_STATE_KEY] = torch.from_numpy(embed_instructions(instructions, self.instruction_dim))
        for key, images in self._frames(obs).items():
            images = np.asarray(images)
            if images.ndim != 4 or images.shape[0] != batch_size or images.shape[-1] != 3:
                raise AccrueError(f"observation {key} must be (B, h, w, 3) uint8, got {list(images.shape)}")
            batch[key] = torch.from_numpy(np.ascontiguousarray(images)).permute(0, 3, 1, 2).float() / 255.0
        return batch

    def _frames(self, obs: dict) -> dict:
        """The policy's image inputs from the observation's cameras: `observation.images.<camera>` is that
        camera's frame (by name, from a robot's `cameras`); a policy with one image input and no camera of its
        name (the simulator's `observation.image`) reads the first camera."""
        if not self.image_keys:
            return {}
        if "image" not in obs:
            raise AccrueError(f"policy {self.checkpoint_dir} needs camera images; the observation has no 'image'")
        named = dict(zip(obs.get("cameras") or (), obs.get("images") or ()))
        prefix = "observation.images."
        out = {}
        for key in self.image_keys:
            camera = key[len(prefix) :] if key.startswith(prefix) else None
            if camera in named:
                out[key] = named[camera]
            elif len(self.image_keys) == 1:
                out[key] = obs["image"]
            else:
                raise AccrueError(
                    f"policy {self.checkpoint_dir} takes {len(self.image_keys)} cameras ({', '.join(self.image_keys)}); "
                    f"the robot has no camera {camera or key!r} (its cameras: {', '.join(named) or 'one, unnamed'})"
                )
        return out

    def _normalised_chunk(self, batch: dict, horizon: int):
        import torch

        if self.policy_type in ONE_PASS_CHUNK_TYPES:  # one forward pass; no internal queue is read or written
            return self.policy.predict_action_chunk(batch)[:, :horizon]
        # Queue-based policies (Diffusion, VLAs): start from empty queues so the chunk depends only
        # on this observation, then pop the first `horizon` actions of the one chunk it plans.
        self.policy.reset()
        actions = [self.policy.select_action(batch) for _ in range(horizon)]
        self.policy.reset()
        return torch.stack(actions, dim=1)

    def reference_chunk(self, obs: dict, instruction: str | list[str], horizon: int | None = None) -> np.ndarray:
        """(B, H, d) float32 actions in [-1, 1]; a pure function of (checkpoint, obs, instruction, seed)."""
        import torch

        from accrue.torch_rng import seeded_torch_rng

        horizon = self.max_horizon if horizon is None else int(horizon)
        if not 1 <= horizon <= self.max_horizon:
            raise AccrueError(
                f"horizon {horizon} is outside 1..{self.max_horizon}, the chunk policy {self.checkpoint_dir} "
                "plans per call; fine-tune with a larger chunk size"
            )
        state = np.asarray(obs.get("state", np.zeros((0, 0))))
        instructions = (
            [instruction] * (state.shape[0] if state.ndim == 2 else 0)
            if isinstance(instruction, str)
            else list(instruction)
        )
        batch = self.preprocessor(self._batch(obs, instructions))
        # diffusion noise etc. is drawn from a per-call seeded stream on the policy's device
        with torch.no_grad(), seeded_torch_rng(self.seed, self.device):
            chunk = self._normalised_chunk(batch, horizon)
        actions = self.postprocessor(chunk)
        out = actions.detach().to("cpu", torch.float32).numpy()
        return np.clip(out, -1.0, 1.0)
