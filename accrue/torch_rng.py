"""Seeded torch randomness for one block, leaving the caller's generators as they were."""

from collections.abc import Iterator
from contextlib import contextmanager

import torch


@contextmanager
def seeded_torch_rng(seed: int, device: torch.device | str = "cpu") -> Iterator[None]:
    """Inside the block, torch's global generators for the CPU and for `device` start from `seed`; after it,
    they are restored. Why not `fork_rng` + `torch.manual_seed`: manual_seed reseeds every GPU (or queues
    that for when CUDA starts), and `fork_rng(devices=[])` restores only the CPU's, so a GPU's stream would
    silently restart at the seed each time a learner is built or the base policy is called."""
    device = torch.device(device)
    gpus = [torch.cuda.current_device() if device.index is None else device.index] if device.type == "cuda" else []
    with torch.random.fork_rng(devices=gpus):
        torch.random.default_generator.manual_seed(seed)
        for index in gpus:
            torch.cuda.default_generators[index].manual_seed(seed)
        yield
