"""Fine-tune a base policy on the demonstrations of tasks 1..k with lerobot's own training code, in-process."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Protocol

from accrue.errors import AccrueError
from accrue.policy.checkpoint import check_policy_type_known, input_shapes, read_checkpoint_config
from accrue.policy.from_scratch import scratch_config
from accrue.policy.instruction_embedding import DEFAULT_EMBEDDING_DIM, ENV_STATE_KEY
from accrue.policy.lerobot_train_run import run_lerobot_train
from accrue.policy.training_set import TRAINING_REPO_ID, build_training_set

FINETUNE_RECORD = "accrue_finetune.json"
WORK_DIR = "_work"
SUMMARY_FILE = "accrue_training_set.json"
TRAINING_SET_FORMAT = 2  # bump when build_training_set or the frame table writes different bytes


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
    num_workers: int = 2  # DataLoader processes, for training sets with cameras (others use the frame table)
    trainer: str = "in-process"  # or "lerobot-train": the subprocess, kept as the benchmark's reference
    keep_training_set: bool = False  # keep the merged dataset under out_dir/_work for inspection

    def check(self) -> None:
        if self.steps < 1 or self.batch_size < 1 or self.chunk_size < 1:
            raise AccrueError("fine-tune steps, batch size and chunk size must be >= 1")
        if not self.lr > 0:
            raise AccrueError(f"fine-tune lr must be > 0, got {self.lr}")
        if self.trainer not in ("in-process", "lerobot-train"):
            raise AccrueError(f"fine-tune trainer must be in-process or lerobot-train, got {self.trainer!r}")
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
        have = tuple(features[key]["shape"])
        if features[key].get("dtype") in ("image", "video") and len(have) == 3:
            have = (have[2], have[0], have[1])  # a dataset stores frames (h, w, c); a policy takes (c, h, w)
        if have != shape:
            raise AccrueError(
                f"the demonstrations' '{key}' has shape {list(features[key]['shape'])} but checkpoint "
                f"{init_dir} expects {list(shape)}"
            )


class TrainingSetCache(Protocol):
    """Where merged training sets are kept between fine-tunes (the store, for the finetune-base step).

    key: everything besides the demonstrations' identity that decides the set's bytes; the cache
    adds the demonstrations' identity itself (it knows their content ids)."""

    def find(self, key: dict) -> Path | None: ...

    def keep(self, key: dict, root: Path) -> None: ...


def _train_args(settings: FinetuneSettings, policy_flags: list[str], training_root: Path, train_dir: Path) -> list[str]:
    return [
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
        "--env_eval_freq=0",
        f"--save_freq={settings.steps}",
        f"--log_freq={max(1, settings.steps // 50)}",
        "--wandb.enable=false",
    ]


def _scrub_paths(cfg) -> None:
    """The saved train config keeps no path of this machine: the checkpoint's bytes are a function of
    its inputs (which inputs, by content id, is in the step record)."""
    cfg.dataset.root = None
    cfg.output_dir = None
    cfg.policy.pretrained_path = None


def _training_set(
    datasets: list[Path],
    work: Path,
    settings: FinetuneSettings,
    embedding_dim: int,
    use_images: bool,
    cfg,
    cache: TrainingSetCache | None,
) -> tuple[Path, dict]:
    """(root of the merged training set with its frame table, its summary), from the cache or built now."""
    from accrue.policy.train_inprocess import delta_indices, ensure_frame_table

    key = {
        "format": TRAINING_SET_FORMAT,
        "retention": settings.retention,
        "seed": settings.seed,
        "embedding_dim": embedding_dim,
        "use_images": use_images,
        "delta_indices": delta_indices(cfg.policy),
    }
    cached = cache.find(key) if cache is not None else None
    if cached is not None:
        return cached, json.loads((cached / SUMMARY_FILE).read_text(encoding="utf-8"))
    root = work / "training_set"
    summary = json.loads(
        build_training_set(datasets, root, settings.retention, settings.seed, embedding_dim, use_images).to_json()
    )
    summary.pop("root")
    (root / SUMMARY_FILE).write_text(json.dumps(summary, indent=2, sort_keys=True), encoding="utf-8")
    summary = json.loads((root / SUMMARY_FILE).read_text(encoding="utf-8"))  # the same dict a cache hit reads
    cfg.dataset.root = root
    ensure_frame_table(cfg, root)
    if cache is not None:
        cache.keep(key, root)
    return root, summary


def finetune(
    init: Path | str,
    datasets: list[Path],
    out_dir: Path,
    settings: FinetuneSettings = FinetuneSettings(),
    progress: Callable[[int, int], None] | None = None,
    training_sets: TrainingSetCache | None = None,
    labels: tuple[str, list[str]] | None = None,
) -> Path:
    """Train on D^1..D^k (the last dataset is the current task) and return out_dir, a lerobot checkpoint.

    init: a checkpoint directory to continue from, or a from-scratch name ("embedded-mlp", "embedded-act", "act",
    "diffusion"). out_dir must not exist or be empty. The work files stay in out_dir/_work when training
    fails. training_sets: a cache of merged training sets; labels: (init, datasets) as the record names
    them (default: their paths; the step passes its input roles, so that the record is machine-independent).
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
    datasets = [Path(p) for p in datasets]
    if settings.trainer == "lerobot-train":
        final, summary, log_text = _finetune_subprocess(
            datasets,
            work,
            settings,
            policy_flags,
            embedding_dim,
            use_images,
            progress,
            init_dir if init_is_dir else None,
        )
    else:
        from accrue.policy.train_inprocess import parse_train_config, train_in_process

        cfg = parse_train_config(_train_args(settings, policy_flags, work / "training_set", work / "train"))
        root, summary = _training_set(datasets, work, settings, embedding_dim, use_images, cfg, training_sets)
        if init_is_dir:
            _check_dataset_matches_checkpoint(init_dir, root)
        cfg.dataset.root = root
        log: list[str] = []
        final = train_in_process(
            cfg, work / "train", log, root, progress, threads=settings.torch_threads, scrub=_scrub_paths
        )
        log_text = "\n".join(log) + "\n"

    for item in sorted(final.iterdir()):
        shutil.copyfile(item, out_dir / item.name)
    (out_dir / "finetune.log").write_text(log_text, encoding="utf-8")
    init_label, dataset_labels = labels or (str(init), [str(p) for p in datasets])
    record = {
        "init": init_label,
        "datasets": dataset_labels,
        "settings": asdict(settings),
        "training_set": summary,
    }
    (out_dir / FINETUNE_RECORD).write_text(json.dumps(record, indent=2), encoding="utf-8")
    if not settings.keep_training_set:
        shutil.rmtree(work)
    return out_dir


def _finetune_subprocess(
    datasets: list[Path],
    work: Path,
    settings: FinetuneSettings,
    policy_flags: list[str],
    embedding_dim: int,
    use_images: bool,
    progress: Callable[[int, int], None] | None,
    init_dir: Path | None,
) -> tuple[Path, dict, str]:
    """The former way, kept as the reference the benchmark compares with: `lerobot-train` in a process."""
    training_root = work / "training_set"
    summary = json.loads(
        build_training_set(
            datasets, training_root, settings.retention, settings.seed, embedding_dim, use_images
        ).to_json()
    )
    summary.pop("root")
    if init_dir is not None:
        _check_dataset_matches_checkpoint(init_dir, training_root)
    train_dir = work / "train"
    log_path = work / "lerobot-train.log"
    run_lerobot_train(
        _train_args(settings, policy_flags, training_root, train_dir),
        log_path,
        settings.steps,
        progress,
        threads=settings.torch_threads,
        module="accrue.policy.lerobot_train_entry",
    )
    final = train_dir / "checkpoints" / "last" / "pretrained_model"
    if not final.is_dir():
        raise AccrueError(f"lerobot-train finished without a checkpoint at {final}; see the log at {log_path}")
    return final, summary, log_path.read_text(encoding="utf-8")
