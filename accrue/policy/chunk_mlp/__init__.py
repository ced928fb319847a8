"""`accrue_chunk_mlp`: a small state-only chunk policy for lerobot, accrue's embedded base policy.

An MLP from (observation.state, observation.environment_state) to an H-step action chunk, trained by
lerobot-train with lerobot's own datasets, processors and checkpoint format. It is registered with lerobot
as a third-party policy type when this package is imported (accrue imports it before any lerobot policy
is created, loaded or trained; lerobot-train runs through `accrue.policy.lerobot_train_entry`).

Why not ACT: on the quickstart's kind of demonstrations (60, three tasks, 800 steps from scratch), a
2.7M-parameter state-only ACT plateaued at an L1 loss near 0.27 and reached 0.10-0.40 success per task,
where this MLP reached 0.46-0.54 (scripts/base_policy_table.py measures it stage by stage). The chunk is
predicted from one observation, like ACT's.
"""

from accrue.policy.chunk_mlp.configuration_chunk_mlp import POLICY_TYPE, ChunkMLPConfig
from accrue.policy.chunk_mlp.modeling_chunk_mlp import ChunkMLPPolicy

__all__ = ["POLICY_TYPE", "ChunkMLPConfig", "ChunkMLPPolicy"]
