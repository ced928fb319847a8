"""Named from-scratch policy configs, expressed as lerobot-train `--policy.*` flags.

`embedded-mlp` is accrue's built-in base policy: the state-only chunk MLP `accrue_chunk_mlp`
(accrue/policy/chunk_mlp, a lerobot policy type accrue registers) conditioned on the task through the
hashed instruction embedding. It fine-tunes on two CPU cores in a minute or two and leaves head-room for
RL, as the paper's base policies do (paper: success roughly 0.35-0.76 before RL); the figures are in
scripts/base_policy_table.py's output and the README.

`embedded-act` is the small state-only ACT that came first; on the quickstart's demonstrations it
reached only 0.10-0.40 success after as long a fine-tune (measured), so it is no longer the default.
"""

from __future__ import annotations

from dataclasses import dataclass

from accrue.errors import AccrueError

EMBEDDED_DEFAULT = "embedded-mlp"
EMBEDDED_ACT = "embedded-act"
SCRATCH_NAMES = (EMBEDDED_DEFAULT, EMBEDDED_ACT, "act", "diffusion")


@dataclass(frozen=True)
class ScratchConfig:
    policy_type: str
    flags: tuple[str, ...]  # extra `--policy.x=y` flags for lerobot-train
    uses_images: bool  # whether camera features go into the training set


def scratch_config(name: str, chunk_size: int) -> ScratchConfig:
    if name == EMBEDDED_DEFAULT:
        from accrue.policy.chunk_mlp import POLICY_TYPE

        return ScratchConfig(
            POLICY_TYPE,
            (
                f"--policy.chunk_size={chunk_size}",
                f"--policy.n_action_steps={chunk_size}",
            ),
            uses_images=False,
        )
    if name == EMBEDDED_ACT:
        return ScratchConfig(
            "act",
            (
                "--policy.pretrained_backbone_weights=null",
                f"--policy.chunk_size={chunk_size}",
                f"--policy.n_action_steps={chunk_size}",
                "--policy.dim_model=256",  # 128 learned the precise xy servo too slowly (measured)
                "--policy.n_heads=4",
                "--policy.dim_feedforward=1024",
                "--policy.n_encoder_layers=2",
                "--policy.n_decoder_layers=1",
                "--policy.use_vae=false",  # scripted experts are unimodal; the VAE only slows CPU training
                "--policy.dropout=0.0",  # imitation of a precise scripted controller; dropout only blurs it
            ),
            uses_images=False,
        )
    if name == "act":
        return ScratchConfig(
            "act",
            (
                "--policy.pretrained_backbone_weights=null",  # the default backbone downloads ResNet weights
                f"--policy.chunk_size={chunk_size}",
                f"--policy.n_action_steps={chunk_size}",
            ),
            uses_images=True,
        )
    if name == "diffusion":
        # The U-Net needs a horizon divisible by 8 that covers n_obs_steps (2) + the executed chunk.
        horizon = max(16, -(-(chunk_size + 1) // 8) * 8)
        return ScratchConfig(
            "diffusion",
            (
                f"--policy.horizon={horizon}",
                f"--policy.n_action_steps={chunk_size}",
                f"--policy.drop_n_last_frames={horizon - chunk_size - 1}",
            ),
            uses_images=True,
        )
    raise AccrueError(f"unknown policy init '{name}': give a checkpoint directory or one of {', '.join(SCRATCH_NAMES)}")
