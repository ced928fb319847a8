"""The `accrue_chunk_mlp` network: normalised (state ‖ task embedding) -> MLP -> (chunk_size, action_dim)."""

from __future__ import annotations

from collections import deque

import torch
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_STATE
from torch import Tensor, nn

from accrue.policy.chunk_mlp.configuration_chunk_mlp import POLICY_TYPE, ChunkMLPConfig


class ChunkMLPPolicy(PreTrainedPolicy):
    config_class = ChunkMLPConfig
    name = POLICY_TYPE

    def __init__(self, config: ChunkMLPConfig, **kwargs):
        super().__init__(config)
        config.validate_features()
        layers: list[nn.Module] = []
        width = config.input_dim
        for hidden in config.hidden_dims:
            layers += [nn.Linear(width, hidden), nn.ReLU()]
            width = hidden
        layers.append(nn.Linear(width, config.chunk_size * config.action_dim))
        self.net = nn.Sequential(*layers)
        self.reset()

    def get_optim_params(self) -> dict:
        return self.parameters()

    def reset(self) -> None:
        self._queue: deque[Tensor] = deque(maxlen=self.config.n_action_steps)

    def _inputs(self, batch: dict[str, Tensor]) -> Tensor:
        parts = [batch[OBS_STATE]]
        if self.config.env_state_feature is not None:
            parts.append(batch[OBS_ENV_STATE])
        return torch.cat(parts, dim=-1)

    @torch.no_grad()
    def predict_action_chunk(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        """(B, chunk_size, action_dim) actions (in the processors' action space) for one observation per row."""
        self.eval()
        return self._chunk(batch)

    def _chunk(self, batch: dict[str, Tensor]) -> Tensor:
        out = self.net(self._inputs(batch))
        return out.view(out.shape[0], self.config.chunk_size, self.config.action_dim)

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        """One action per call, re-planning every n_action_steps (lerobot's queue convention)."""
        self.eval()
        if not self._queue:
            chunk = self._chunk(batch)[:, : self.config.n_action_steps]
            self._queue.extend(chunk.transpose(0, 1))
        return self._queue.popleft()

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        """L1 between the predicted and demonstrated chunks, padded steps past an episode's end excluded."""
        pred = self._chunk(batch)
        err = (pred - batch[ACTION]).abs()
        pad = batch.get("action_is_pad")
        if pad is not None:
            keep = (~pad).unsqueeze(-1).to(err.dtype)
            loss = (err * keep).sum() / (keep.sum() * err.shape[-1]).clamp(min=1.0)
        else:
            loss = err.mean()
        return loss, {"l1_loss": loss.item()}
