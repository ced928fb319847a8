"""The base policy pi_base through lerobot: load a checkpoint, get reference chunks, fine-tune on D^1..D^k."""

from accrue.policy.base_policy import BasePolicy
from accrue.policy.finetune import FinetuneSettings, finetune
from accrue.policy.from_scratch import EMBEDDED_DEFAULT
from accrue.policy.instruction_embedding import embed_instruction
from accrue.policy.retention import retained_episodes

__all__ = ["BasePolicy", "FinetuneSettings", "finetune", "EMBEDDED_DEFAULT", "embed_instruction", "retained_episodes"]
