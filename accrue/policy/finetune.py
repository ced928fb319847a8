"""Fine-tune a base policy on the demonstrations of tasks 1..k with lerobot's own training script."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

from accrue.errors import AccrueError
from accrue.policy.checkpoint import check_policy_type_known, input_shapes, read_checkpoint_config
from accrue.policy.from_scratch import scratch_config
from accrue.policy.instruction_embedding import DEFAULT_EMBEDDING_DIM, ENV_STATE_KEY
from accrue.policy.lerobot_train_run import run_lerobot_train
from accrue.policy.training_set import TRAINING_REPO_ID, build_training_set

FINETUNE_RECORD = "accrue_finetune.json"
WORK_DIR = "_work"


@dataclass(frozen=True)
class FinetuneSettings:
    steps: int = 2000
    batch_size: int = 32
    lr: float = 1e-4
    seed: int = 0
    retention: float = 1.0  # fraction of earlier tasks' demos kept (paper Table VI: 1.0 .. 0.05)
    chunk_size: int = 16  # from-scratch policies only; a checkpoint keeps its own
    embedding_dim: int = DEFAULT_EMBEDDING_DIM  # from-scratch only; a checkpoint keeps its own
    device: str = "cpu"
    torch_threads: int = 1  # small models train no slower on one thread, and a busy CPU stays usable
    num_workers: int = 2  # lerobot-train loader processes: loading bounds a small policy's step
    # (chunk MLP, 800 steps of 64 on 2 idle cores: 106 s with 0, 79 s with 2)
    keep_training_set: bool = False  # keep the merged dataset under out_dir/_work for inspection

    def check(self) -> None:
        if self.steps < 1 or self.batch_size < 1 or self.chunk_size < 1:
            raise AccrueError("fine-tune steps, batch size and chunk size must be >= 1")
        if not self.lr > 0:
            raise AccrueError(f"fine-tune lr must be > 0, got {self.lr}")
        if not 0.0 < self.retention <= 1.0:
            raise AccrueError(f"demo retention must be in (0, 1], got {self.retention}")


def _checkpoint_training_shape(init_dir: Path) -> tuple[list[str], int, bool]:
    """(policy flags, embedding dim, uses images) for continuing from a checkpoint."""
    config = read_checkpoint_config(init_dir)
    check_policy_type_known(config["type"], init_dir)
    shapes = input_shapes(config)
    embedding_dim = shapes[ENV_STATE_KEY][0] if ENV_STATE_KEY in shapes else 0
    uses_images = any(k.startswith("observation.image") for k in shapes)
    return [f"--policy.path={init_dir.resolve()}"], embedding_dim, uses_images


def _check_dataset_matches_checkpoint(init_dir: Path, training_root: Path) -> None:
    """A checkpoint keeps its input shapes; a dataset that disagrees would fail deep inside torch."""
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata

    shapes = input_shapes(read_checkpoint_config(init_dir))
    features = LeRobotDatasetMetadata(TRAINING_REPO_ID, root=training_root).features
    for key, shape in shapes.items():
        if key not in features:
            raise AccrueError(f"the demonstrations lack '{key}', which checkpoint {init_dir} takes as input")
        if tuple(features[key]["shape"]) != shape:
            raise AccrueError(
                f"the demonstrations' '{key}' has shape {list(features[key]['shape'])} but checkpoint "
                f"{init_dir} expects {list(shape)}"
            )


def finetune(
    init: Path | str,
    datasets: list[Path],
    out_dir: Path,
    settings: FinetuneSettings = FinetuneSettings(),
    progress: Callable[[int, int], None] | None = None,
) -> Path:
    """Train on D^1..D^k (the last dataset is the current task) and return out_dir, a lerobot checkpoint.

    init: a checkpoint directory to continue from, or a from-scratch name ("embedded-mlp", "embedded-act", "act",
    "diffusion"). out_dir must not exist or be empty. The log and work files stay in out_dir/_work
    when training fails.
    """
    settings.check()
    out_dir = Path(out_dir)
    if out_dir.exists() and any(p.name != WORK_DIR for p in out_dir.iterdir()):
        raise AccrueError(f"fine-tune output {out_dir} already exists and is not empty")
    # a lone _work dir is what a failed attempt leaves behind: start that attempt over
    init_is_dir = isinstance(init, Path) or Path(str(init)).is_dir() or "/" in str(init)
    if init_is_dir:
        init_dir = Path(init)
        policy_flags, embedding_dim, use_images = _checkpoint_training_shape(init_dir)
    else:
        scratch = scratch_config(str(init), settings.chunk_size)
        policy_flags = [f"--policy.type={scratch.policy_type}", *scratch.flags]
        embedding_dim, use_images = settings.embedding_dim, scratch.uses_images

    work = out_dir / WORK_DIR
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    training_root = work / "training_set"
    summary = build_training_set(
        [Path(p) for p in datasets], training_root, settings.retention, settings.seed, embedding_dim, use_images
    )
    if init_is_dir:
        _check_dataset_matches_checkpoint(init_dir, training_root)

    train_dir = work / "train"
    args = [
        f"--dataset.repo_id={TRAINING_REPO_ID}",
        f"--dataset.root={training_root}",
        "--dataset.video_backend=pyav",
        *policy_flags,
        f"--policy.device={settings.device}",
        "--policy.push_to_hub=false",
        f"--policy.optimizer_lr={settings.lr}",
        f"--output_dir={train_dir}",
        "--job_name=accrue_finetune",
        f"--steps={settings.steps}",
        f"--batch_size={settings.batch_size}",
        f"--seed={settings.seed}",
        f"--num_workers={settings.num_workers}",
        "--eval_freq=0",
        f"--save_freq={settings.steps}",
        f"--log_freq={max(1, settings.steps // 50)}",
        "--wandb.enable=false",
    ]
    log_path = work / "lerobot-train.log"
    run_lerobot_train(
        args,
        log_path,
        settings.steps,
        progress,
        threads=settings.torch_threads,
        module="accrue.policy.lerobot_train_entry",
    )

    final = train_dir / "checkpoints" / "last" / "pretrained_model"
    if not final.is_dir():
        raise AccrueError(f"lerobot-train finished without a checkpoint at {final}; see the log at {log_path}")
    for item in final.iterdir():
        shutil.copy2(item, out_dir / item.name)
    shutil.copy2(log_path, out_dir / "finetune.log")
    record = {
        "init": str(init),
        "datasets": [str(p) for p in datasets],
        "settings": asdict(settings),
        "training_set": json.loads(summary.to_json()),
    }
    (out_dir / FINETUNE_RECORD).write_text(json.dumps(record, indent=2), encoding="utf-8")
    if not settings.keep_training_set:
        shutil.rmtree(work)
    return out_dir
