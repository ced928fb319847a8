"""lerobot's training, run in this process: its config parser, dataset metadata, policy and processor
factories, optimizer/scheduler factory, `update_policy` step and checkpoint writer.

What differs from `lerobot-train` is only what costs start-up and loading: no process start, and
batches come from the frame table (accrue/policy/frame_table.py) instead of DataLoader workers, for
training sets without cameras or episode-aware sampling (others go through lerobot's DataLoader).
Process-wide state lerobot touches (RNGs, torch threads, sys.argv) is restored afterwards, so later
steps in the same process see what they would have seen without the fine-tune.
"""

from __future__ import annotations

import contextlib
import random
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from accrue.errors import AccrueError
from accrue.policy.checkpoint import first_line
from accrue.policy.frame_table import build_frame_table, load_frame_table, save_frame_table, shuffled_batches

PRETRAINED_DIR = "pretrained_model"


@contextlib.contextmanager
def _process_state(threads: int | None) -> Iterator[None]:
    import torch

    saved = (random.getstate(), np.random.get_state(), torch.get_rng_state(), torch.get_num_threads())
    if threads:
        torch.set_num_threads(threads)
    try:
        yield
    finally:
        random.setstate(saved[0])
        np.random.set_state(saved[1])
        torch.set_rng_state(saved[2])
        torch.set_num_threads(saved[3])


def parse_train_config(args: list[str]):
    """A validated TrainPipelineConfig from lerobot-train's command-line flags, parsed by lerobot itself."""
    from accrue.policy.video_backend import use_pyav

    use_pyav()  # before draccus computes DatasetConfig's default decoder (lerobot's torchcodec probe)
    from lerobot.configs import parser
    from lerobot.configs.train import TrainPipelineConfig

    import accrue.policy.chunk_mlp  # noqa: F401 - registers accrue_chunk_mlp before draccus reads --policy.type

    def identity(cfg):
        return cfg

    identity.__annotations__ = {"cfg": TrainPipelineConfig}  # lerobot's wrapper reads the type from here
    saved = sys.argv
    sys.argv = ["lerobot-train", *args]  # validate() re-reads --policy.path from sys.argv
    try:
        cfg = parser.wrap()(identity)()
        cfg.validate()
    except (Exception, SystemExit) as exc:  # draccus reports bad flags by exiting
        raise AccrueError(f"lerobot's training config rejected the fine-tune settings: {first_line(exc)}") from None
    finally:
        sys.argv = saved
    return cfg


def delta_indices(policy_cfg) -> dict:
    """What of the policy config decides which frames a training item holds."""
    return {
        "action": policy_cfg.action_delta_indices,
        "observation": policy_cfg.observation_delta_indices,
        "reward": policy_cfg.reward_delta_indices,
    }


def uses_frame_table(meta, policy_cfg) -> bool:
    has_cameras = any(spec["dtype"] in ("image", "video") for spec in meta.features.values())
    return not has_cameras and not hasattr(policy_cfg, "drop_n_last_frames")


def _lerobot_dataset(cfg):
    from lerobot.datasets.factory import make_dataset

    return make_dataset(cfg)


def ensure_frame_table(cfg, root: Path) -> None:
    """Write the frame table of the training set at root (cfg.dataset.root) when it applies and is missing."""
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata

    meta = LeRobotDatasetMetadata(cfg.dataset.repo_id, root=root)
    deltas = delta_indices(cfg.policy)
    if uses_frame_table(meta, cfg.policy) and load_frame_table(root, deltas) is None:
        save_frame_table(root, *build_frame_table(_lerobot_dataset(cfg)), deltas)


def _batches(cfg, meta, table_dir: Path | None):
    """Endless training batches: from the frame table when it applies, else from lerobot's DataLoader."""
    import torch

    generator = torch.Generator().manual_seed(cfg.seed or 0)
    if uses_frame_table(meta, cfg.policy):
        deltas = delta_indices(cfg.policy)
        cached = load_frame_table(table_dir, deltas) if table_dir is not None else None
        if cached is None:
            cached = build_frame_table(_lerobot_dataset(cfg))
        return shuffled_batches(*cached, cfg.batch_size, generator)

    from lerobot.datasets.sampler import EpisodeAwareSampler
    from lerobot.scripts.lerobot_train import _dataloader_worker_kwargs
    from lerobot.utils.collate import lerobot_collate_fn
    from lerobot.utils.utils import cycle

    # lerobot-train 0.6's loader: an episode-aware sampler whose order is a function of the seed alone
    dataset = _lerobot_dataset(cfg)
    sampler = EpisodeAwareSampler(
        dataset.meta.episodes["dataset_from_index"],
        dataset.meta.episodes["dataset_to_index"],
        episode_indices_to_use=dataset.episodes,
        drop_n_last_frames=getattr(cfg.policy, "drop_n_last_frames", 0),
        shuffle=True,
        seed=cfg.seed if cfg.seed is not None else 0,
        absolute_to_relative_idx=dataset.absolute_to_relative_idx,
    )
    loader = torch.utils.data.DataLoader(
        dataset,
        num_workers=cfg.num_workers,
        batch_size=cfg.batch_size,
        shuffle=False,
        sampler=sampler,
        drop_last=False,
        collate_fn=lerobot_collate_fn if dataset.meta.has_language_columns else None,
        **_dataloader_worker_kwargs(cfg),
    )
    return cycle(loader)


def _processors(cfg, policy, meta, device):
    """lerobot-train's processor set-up: fresh dataset statistics, the checkpoint's steps otherwise."""
    from lerobot.policies.factory import make_pre_post_processors

    kwargs: dict = {"dataset_stats": meta.stats}
    if cfg.policy.pretrained_path is not None:
        features = {**policy.config.input_features, **policy.config.output_features}
        kwargs["preprocessor_overrides"] = {
            "device_processor": {"device": device.type},
            "normalizer_processor": {
                "stats": meta.stats,
                "features": features,
                "norm_map": policy.config.normalization_mapping,
            },
            "rename_observations_processor": {"rename_map": cfg.rename_map},
        }
        kwargs["postprocessor_overrides"] = {
            "unnormalizer_processor": {
                "stats": meta.stats,
                "features": policy.config.output_features,
                "norm_map": policy.config.normalization_mapping,
            },
        }
    return make_pre_post_processors(policy_cfg=cfg.policy, pretrained_path=cfg.policy.pretrained_path, **kwargs)


def _accelerator(device: str):
    from accelerate import Accelerator
    from accelerate.utils import DistributedDataParallelKwargs

    return Accelerator(
        step_scheduler_with_optimizer=False,
        kwargs_handlers=[DistributedDataParallelKwargs(find_unused_parameters=True)],
        cpu=device == "cpu",
    )


def train_in_process(
    cfg,
    out_dir: Path,
    log_lines: list[str],
    table_dir: Path | None = None,
    progress: Callable[[int, int], None] | None = None,
    threads: int | None = None,
    scrub: Callable[[object], None] | None = None,
) -> Path:
    """Train cfg's policy for cfg.steps and write lerobot's checkpoint under out_dir; return its pretrained dir.

    table_dir: where the frame table is read from or written to (None: built in memory).
    log_lines gets one deterministic line per cfg.log_freq steps (step, loss, grad norm, lr).
    scrub(cfg) runs before the train config is saved, to drop machine-specific paths from it.
    """
    import torch
    from lerobot.common.train_utils import save_checkpoint
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
    from lerobot.optim.factory import make_optimizer_and_scheduler
    from lerobot.policies.factory import make_policy
    from lerobot.scripts.lerobot_train import update_policy
    from lerobot.utils.logging_utils import AverageMeter, MetricsTracker
    from lerobot.utils.random_utils import set_seed

    with _process_state(threads):
        accelerator = _accelerator(cfg.policy.device)
        if cfg.seed is not None:
            set_seed(cfg.seed)
        meta = LeRobotDatasetMetadata(cfg.dataset.repo_id, root=cfg.dataset.root)
        batches = _batches(cfg, meta, table_dir)
        policy = make_policy(cfg=cfg.policy, ds_meta=meta, rename_map=cfg.rename_map)
        preprocessor, postprocessor = _processors(cfg, policy, meta, accelerator.device)
        optimizer, scheduler = make_optimizer_and_scheduler(cfg, policy)
        policy, optimizer, scheduler = accelerator.prepare(policy, optimizer, scheduler)
        meters = {name: AverageMeter(name, ":.3f") for name in ("loss", "grad_norm", "lr", "update_s")}
        tracker = MetricsTracker(cfg.batch_size, meta.total_frames, meta.total_episodes, meters, 0, accelerator)
        policy.train()
        for step in range(1, cfg.steps + 1):
            batch = preprocessor(next(batches))
            tracker, _ = update_policy(
                tracker, policy, batch, optimizer, cfg.optimizer.grad_clip_norm, accelerator, scheduler
            )
            if cfg.log_freq > 0 and (step % cfg.log_freq == 0 or step == cfg.steps):
                log_lines.append(
                    f"step:{step} loss:{tracker.loss.val:.6g} grad_norm:{tracker.grad_norm.val:.6g} "
                    f"lr:{tracker.lr.val:.6g}"
                )
                if progress is not None:
                    progress(step, cfg.steps)
        if scrub is not None:
            scrub(cfg)
        checkpoint_dir = out_dir / f"{cfg.steps:06d}"
        save_checkpoint(
            checkpoint_dir,
            cfg.steps,
            cfg,
            accelerator.unwrap_model(policy),
            optimizer,
            scheduler,
            preprocessor,
            postprocessor,
            num_processes=accelerator.num_processes,
            batch_size=cfg.batch_size,
        )
        accelerator.end_training()
        del policy, optimizer, batches
        if torch.cuda.is_available():
            torch.cuda.empty_cache()
    if progress is not None:
        progress(cfg.steps, cfg.steps)
    return checkpoint_dir / PRETRAINED_DIR
