"""lerobot's default video backend, decided without its torchcodec probe: accrue decodes with pyav.

lerobot 0.6 finds its default decoder (`DatasetConfig.video_backend`'s default, and `LeRobotDataset`'s and
`LeRobotDataset.create`'s when none is given) by importing torchcodec. Where FFmpeg's shared libraries are
absent that import fails, and lerobot logs the failure's whole text - a Python traceback per FFmpeg version
it tried - as a warning, then falls back to pyav. draccus computes that default while it parses
lerobot-train's flags even when `--dataset.video_backend=pyav` is given, so every fine-tune printed it.

accrue reads and writes every dataset with pyav (`video_backend="pyav"` at each LeRobotDataset it opens,
`--dataset.video_backend=pyav` to lerobot-train), so the probe answers a question nothing asks.
`use_pyav()` makes lerobot's default pyav wherever lerobot looks it up, before it is looked up: no import of
torchcodec, no warning.
"""

from __future__ import annotations

import dataclasses
import sys

VIDEO_BACKEND = "pyav"

# the lerobot modules that bind lerobot.utils.import_utils.get_safe_default_video_backend by name
_BINDERS = ("lerobot.configs.default", "lerobot.datasets.lerobot_dataset", "lerobot.datasets.video_utils")
_PROBE = "get_safe_default_video_backend"


def default_video_backend() -> str:
    """accrue's answer to lerobot's `get_safe_default_video_backend()`, without importing torchcodec."""
    return VIDEO_BACKEND


def use_pyav() -> None:
    """lerobot's default video backend is pyav from now on in this process, its torchcodec probe never run.

    Idempotent; call it before lerobot parses a training config or opens a dataset without naming a backend.
    The function is replaced where lerobot defines it (a later `from ... import` gets this one), in the
    modules that imported it already, and as the default factory of `DatasetConfig.video_backend` (draccus
    reads the field's factory while it parses flags)."""
    import lerobot.utils.import_utils as import_utils

    setattr(import_utils, _PROBE, default_video_backend)
    for name in _BINDERS:
        module = sys.modules.get(name)
        if module is not None and hasattr(module, _PROBE):
            setattr(module, _PROBE, default_video_backend)
    default = sys.modules.get("lerobot.configs.default")
    if default is not None:
        for f in dataclasses.fields(default.DatasetConfig):
            if f.name == "video_backend":
                f.default_factory = default_video_backend
