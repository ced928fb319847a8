"""Merge the demonstrations of tasks 1..k into one local LeRobotDataset that lerobot-train reads.

Frames are re-written with lerobot's own writer rather than aggregated file-by-file, because the
merged set also needs (a) only the retained episodes of earlier tasks and (b) the instruction
embedding as `observation.environment_state` for policies without language input.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from accrue.errors import AccrueError
from accrue.policy.demo_sources import ACTION_KEY, STATE_KEY, DemoSource, check_compatible, open_demo_source
from accrue.policy.instruction_embedding import ENV_STATE_KEY, embed_instruction
from accrue.policy.retention import retained_episodes

TRAINING_REPO_ID = "local/accrue_finetune"


@dataclass
class TrainingSetSummary:
    root: str
    episodes_per_dataset: list[list[int]] = field(default_factory=list)  # kept source episode indices
    instructions: list[str] = field(default_factory=list)
    total_frames: int = 0
    image_keys: list[str] = field(default_factory=list)
    embedding_dim: int = 0

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=2)


def _features(source: DemoSource, embedding_dim: int, image_keys: list[str]) -> dict:
    state_dim = source.states[0].shape[1]
    action_dim = source.actions[0].shape[1]
    features = {
        STATE_KEY: {"dtype": "float32", "shape": (state_dim,), "names": None},
        ACTION_KEY: {"dtype": "float32", "shape": (action_dim,), "names": None},
    }
    if embedding_dim > 0:
        features[ENV_STATE_KEY] = {"dtype": "float32", "shape": (embedding_dim,), "names": None}
    for key in image_keys:
        shape = tuple(source.dataset.meta.features[key]["shape"])
        features[key] = {"dtype": "image", "shape": shape, "names": ["height", "width", "channels"]}
    return features


def _image_hwc_uint8(tensor) -> np.ndarray:
    """LeRobotDataset returns images as float CHW in [0, 1]; the writer takes HWC uint8."""
    array = tensor.numpy() if hasattr(tensor, "numpy") else np.asarray(tensor)
    if array.dtype != np.uint8:
        array = np.clip(np.rint(array * 255.0), 0, 255).astype(np.uint8)
    if array.ndim == 3 and array.shape[0] in (1, 3) and array.shape[-1] not in (1, 3):
        array = np.transpose(array, (1, 2, 0))
    return array


def build_training_set(
    datasets: list[Path],
    out_root: Path,
    retention: float,
    seed: int,
    embedding_dim: int,
    use_images: bool,
) -> TrainingSetSummary:
    """Write the merged dataset at out_root (must not exist). The last dataset is the current task."""
    if not datasets:
        raise AccrueError("fine-tuning needs at least one demonstration dataset")
    sources = [open_demo_source(Path(p)) for p in datasets]
    check_compatible(sources)
    image_keys: list[str] = []
    if use_images:
        image_keys = sources[0].image_keys
        for src in sources[1:]:
            if src.image_keys != image_keys:
                raise AccrueError(
                    f"dataset {src.root}: cameras {src.image_keys} differ from {sources[0].root} ({image_keys})"
                )

    import datasets as hf_datasets
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from accrue.policy.video_backend import VIDEO_BACKEND

    hf_datasets.disable_progress_bars()  # one "Map" bar per saved episode otherwise
    writer = LeRobotDataset.create(
        repo_id=TRAINING_REPO_ID,
        root=out_root,
        fps=sources[0].fps,
        features=_features(sources[0], embedding_dim, image_keys),
        use_videos=False,
        video_backend=VIDEO_BACKEND,  # named: lerobot's default is found by a torchcodec probe (video_backend.py)
    )
    summary = TrainingSetSummary(root=str(out_root), image_keys=image_keys, embedding_dim=embedding_dim)
    last = len(sources) - 1
    for position, src in enumerate(sources):
        keep = retained_episodes(src.num_episodes, retention, seed, position, is_current=position == last)
        summary.episodes_per_dataset.append(keep)
        for ep in keep:
            instruction = src.instruction_of_episode[ep]
            if instruction not in summary.instructions:
                summary.instructions.append(instruction)
            embedding = embed_instruction(instruction, embedding_dim) if embedding_dim > 0 else None
            start, _ = src.frame_ranges[ep]
            for t in range(len(src.states[ep])):
                frame = {STATE_KEY: src.states[ep][t], ACTION_KEY: src.actions[ep][t], "task": instruction}
                if embedding is not None:
                    frame[ENV_STATE_KEY] = embedding
                if image_keys:
                    item = src.dataset[start + t]
                    for key in image_keys:
                        frame[key] = _image_hwc_uint8(item[key])
                writer.add_frame(frame)
            writer.save_episode()
            summary.total_frames += len(src.states[ep])
    writer.finalize()
    _canonical_json(out_root / "meta" / "stats.json")
    return summary


def _canonical_json(path: Path) -> None:
    """lerobot writes stats.json keys in an order that varies between runs; sorted, the same set gives the same bytes."""
    if path.is_file():
        path.write_text(
            json.dumps(json.loads(path.read_text(encoding="utf-8")), indent=4, sort_keys=True), encoding="utf-8"
        )
