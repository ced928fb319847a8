"""lerobot config of the `accrue_chunk_mlp` policy (module name follows lerobot's plugin convention:
configuration_X -> modeling_X (class XPolicy) and processor_X (make_<type>_pre_post_processors))."""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs.policies import PreTrainedConfig
from lerobot.configs.types import NormalizationMode
from lerobot.optim.optimizers import AdamWConfig

POLICY_TYPE = "accrue_chunk_mlp"


@PreTrainedConfig.register_subclass(POLICY_TYPE)
@dataclass
class ChunkMLPConfig(PreTrainedConfig):
    n_obs_steps: int = 1
    chunk_size: int = 4  # actions predicted per observation
    n_action_steps: int = 4  # actions executed per call of select_action's queue
    hidden_dims: tuple[int, ...] = (256, 256)

    normalization_mapping: dict[str, NormalizationMode] = field(
        default_factory=lambda: {
            "STATE": NormalizationMode.MEAN_STD,
            "ENV": NormalizationMode.MEAN_STD,
            # actions are already in [-1, 1]; per-dimension standardisation would weight the L1 loss towards
            # the near-constant dimensions (tilt, the round peg's yaw) and away from the xy servo that decides
            # success (measured on the quickstart's 60 demos, 800 steps: 0.34/0.28/0.44 with MEAN_STD,
            # 0.54/0.46/0.54 without)
            "ACTION": NormalizationMode.IDENTITY,
        }
    )

    optimizer_lr: float = 1e-3
    optimizer_weight_decay: float = 1e-4

    def __post_init__(self):
        super().__post_init__()
        if self.n_obs_steps != 1:
            raise ValueError(f"accrue_chunk_mlp reads one observation step, got n_obs_steps={self.n_obs_steps}")
        if not 1 <= self.n_action_steps <= self.chunk_size:
            raise ValueError(f"n_action_steps must be in 1..chunk_size ({self.chunk_size}), got {self.n_action_steps}")
        if not self.hidden_dims or min(self.hidden_dims) < 1:
            raise ValueError(f"hidden_dims must be positive layer widths, got {self.hidden_dims}")

    def get_optimizer_preset(self) -> AdamWConfig:
        return AdamWConfig(lr=self.optimizer_lr, weight_decay=self.optimizer_weight_decay)

    def get_scheduler_preset(self) -> None:
        return None

    def validate_features(self) -> None:
        if self.robot_state_feature is None:
            raise ValueError("accrue_chunk_mlp needs observation.state among the input features")
        if self.image_features:
            raise ValueError("accrue_chunk_mlp is state-only; use act or diffusion for camera observations")
        if self.action_feature is None:
            raise ValueError("accrue_chunk_mlp needs an 'action' output feature")

    @property
    def observation_delta_indices(self) -> None:
        return None

    @property
    def action_delta_indices(self) -> list[int]:
        return list(range(self.chunk_size))

    @property
    def reward_delta_indices(self) -> None:
        return None

    @property
    def input_dim(self) -> int:
        dims = [self.robot_state_feature.shape[0]]
        if self.env_state_feature is not None:
            dims.append(self.env_state_feature.shape[0])
        return sum(dims)

    @property
    def action_dim(self) -> int:
        return self.action_feature.shape[0]
