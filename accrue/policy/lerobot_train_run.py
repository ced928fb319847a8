"""Run `lerobot-train` in a subprocess on a local dataset, fully offline, reporting step progress.

A subprocess isolates draccus' argv parsing, lerobot's logging setup and torch state from the
caller; its log goes to a file whose path is named in any error.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

from accrue.errors import AccrueError

OFFLINE_ENV = {
    "HF_HUB_OFFLINE": "1",
    "HF_DATASETS_OFFLINE": "1",
    "TRANSFORMERS_OFFLINE": "1",
    "WANDB_MODE": "disabled",
}

# lerobot logs e.g. "step:200 smpl:1K ep:12 ..." with K/M suffixes for large numbers.
_STEP = re.compile(r"\bstep:(\d+(?:\.\d+)?)([KMB]?)\b")
_SUFFIX = {"": 1, "K": 1_000, "M": 1_000_000, "B": 1_000_000_000}


def parse_step(line: str) -> int | None:
    match = _STEP.search(line)
    if match is None:
        return None
    return int(float(match.group(1)) * _SUFFIX[match.group(2)])


def run_lerobot_train(
    args: list[str],
    log_path: Path,
    total_steps: int,
    progress: Callable[[int, int], None] | None = None,
    threads: int | None = None,
    module: str = "lerobot.scripts.lerobot_train",
) -> None:
    """Run lerobot's training entry point (`module`) with `args`; raise AccrueError naming the log on failure."""
    command = [sys.executable, "-m", module, *args]
    env = {**os.environ, **OFFLINE_ENV}
    if threads:
        env.update(OMP_NUM_THREADS=str(threads), MKL_NUM_THREADS=str(threads))
    log_path.parent.mkdir(parents=True, exist_ok=True)
    with open(log_path, "w", encoding="utf-8") as log:
        log.write(" ".join(command) + "\n")
        log.flush()
        proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
        assert proc.stdout is not None
        try:
            for line in proc.stdout:
                log.write(line)
                step = parse_step(line)
                if step is not None and progress is not None:
                    progress(min(step, total_steps), total_steps)
            code = proc.wait()
        except BaseException:
            proc.kill()
            proc.wait()
            raise
    if code != 0:
        raise AccrueError(f"lerobot-train failed (exit {code}); see the log at {log_path}")
    if progress is not None:
        progress(total_steps, total_steps)
