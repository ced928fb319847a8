"""Every item lerobot's dataset yields for a policy, stacked once, and the batches drawn from it.

A small state-only policy trains faster than `LeRobotDataset.__getitem__` can serve it (the
fine-tune used to be bound by loading: 800 steps of 64 took ~80 s on two cores). The items are the
dataset's own (its delta-timestamp queries, padding masks, task strings), fetched once per training
set and kept beside it; batches are what `DataLoader(shuffle=True, drop_last=False)` collates.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import torch

from accrue.errors import AccrueError

TABLE_FILE = "accrue_frames.safetensors"
TABLE_INFO = "accrue_frames.json"


def build_frame_table(dataset) -> tuple[dict[str, torch.Tensor], list[str]]:
    """(tensor key -> all items stacked, every item's task string) of a LeRobotDataset."""
    if len(dataset) == 0:
        raise AccrueError("the merged training set has no frames")
    columns: dict[str, list] = {}
    tasks: list[str] = []
    for i in range(len(dataset)):
        item = dataset[i]
        for key, value in item.items():
            if isinstance(value, torch.Tensor):
                columns.setdefault(key, []).append(value)
        tasks.append(str(item.get("task", "")))
    return {key: torch.stack(values).contiguous() for key, values in columns.items()}, tasks


def save_frame_table(directory: Path, table: dict[str, torch.Tensor], tasks: list[str], deltas: dict) -> None:
    from safetensors.torch import save_file

    directory.mkdir(parents=True, exist_ok=True)
    save_file(table, str(directory / TABLE_FILE))
    info = {"tasks": tasks, "delta_indices": deltas}
    (directory / TABLE_INFO).write_text(json.dumps(info, sort_keys=True), encoding="utf-8")


def load_frame_table(directory: Path, deltas: dict) -> tuple[dict[str, torch.Tensor], list[str]] | None:
    """The stored table, or None when there is none for these delta indices."""
    from safetensors.torch import load_file

    if not (directory / TABLE_FILE).is_file() or not (directory / TABLE_INFO).is_file():
        return None
    info = json.loads((directory / TABLE_INFO).read_text(encoding="utf-8"))
    if info.get("delta_indices") != json.loads(json.dumps(deltas)):
        return None
    return load_file(str(directory / TABLE_FILE)), list(info["tasks"])


def shuffled_batches(
    table: dict[str, torch.Tensor], tasks: list[str], batch_size: int, generator: torch.Generator
) -> Iterator[dict]:
    """Endless batches, each epoch a fresh permutation; the last batch of an epoch may be short."""
    n = len(tasks)
    while True:
        order = torch.randperm(n, generator=generator)
        for start in range(0, n, batch_size):
            index = order[start : start + batch_size]
            batch: dict = {key: column[index] for key, column in table.items()}
            batch["task"] = [tasks[i] for i in index.tolist()]
            yield batch
