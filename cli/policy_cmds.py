"""`accrue policy`: fine-tune a base policy on demonstrations, try a checkpoint's action chunks.

Only typer/rich at module level; torch and lerobot load inside the commands.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Optional

import typer

policy_app = typer.Typer(
    help="Base policies (lerobot checkpoints): fine-tune on demos, query chunks, measure success.", no_args_is_help=True
)

CheckpointArg = Annotated[Path, typer.Argument(help="A lerobot policy checkpoint directory.", show_default=False)]


def _console(stderr: bool = False):
    from rich.console import Console

    return Console(highlight=False, stderr=stderr)


@policy_app.command("finetune")
def finetune_cmd(
    demos: Annotated[
        list[Path], typer.Option("--demos", help="A task's LeRobotDataset; repeat in task order, current task last.")
    ],
    out: Annotated[Path, typer.Option("--out", help="Output checkpoint directory (must not exist or be empty).")],
    init: Annotated[
        str,
        typer.Option(
            "--init", help="Checkpoint dir to continue from, or embedded-mlp / embedded-act / act / diffusion."
        ),
    ] = "embedded-mlp",
    steps: Annotated[int, typer.Option("--steps")] = 2000,
    batch_size: Annotated[int, typer.Option("--batch-size")] = 32,
    lr: Annotated[float, typer.Option("--lr")] = 1e-4,
    seed: Annotated[int, typer.Option("--seed")] = 0,
    retention: Annotated[
        float, typer.Option("--retention", help="Fraction of earlier tasks' demos kept (0.05..1).")
    ] = 1.0,
    chunk_size: Annotated[int, typer.Option("--chunk-size", help="Actions per chunk (from-scratch policies).")] = 16,
    device: Annotated[str, typer.Option("--device")] = "cpu",
) -> None:
    """Fine-tune on the demos of tasks 1..k with lerobot-train; prints the checkpoint directory."""
    import time

    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from accrue.policy import FinetuneSettings, finetune

    settings = FinetuneSettings(
        steps=steps, batch_size=batch_size, lr=lr, seed=seed, retention=retention, chunk_size=chunk_size, device=device
    )
    init_value: Path | str = Path(init) if Path(init).is_dir() else init
    bar = Progress(
        TextColumn("fine-tune"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), console=_console(stderr=True)
    )
    task = bar.add_task("steps", total=steps)

    def show(done: int, total: int) -> None:
        if not bar.live.is_started:  # the bar appears only once training runs, not before an input error
            bar.start()
        bar.update(task, completed=done, total=total)

    started = time.perf_counter()
    try:
        checkpoint = finetune(init_value, demos, out, settings, progress=show)
    finally:
        bar.stop()
    _console(stderr=True).print(f"fine-tuned {steps} steps in {time.perf_counter() - started:.1f} s")
    typer.echo(str(checkpoint))


def _parse_state(text: str) -> list[float]:
    from accrue.errors import AccrueError

    try:
        return [float(v) for v in text.replace(",", " ").split()]
    except ValueError as exc:
        raise AccrueError(f"--state must be numbers separated by commas, got {text!r}") from exc


@policy_app.command("chunk")
def chunk_cmd(
    checkpoint: CheckpointArg,
    instruction: Annotated[
        Optional[str], typer.Option("--instruction", help="Instruction text (default: the task's).")
    ] = None,
    task: Annotated[
        Optional[str], typer.Option("--task", help="Sim task id: use its instruction and a reset observation.")
    ] = None,
    state: Annotated[
        Optional[str], typer.Option("--state", help="Comma-separated state vector instead of a sim reset.")
    ] = None,
    horizon: Annotated[Optional[int], typer.Option("--horizon", help="Chunk length H (default: the policy's).")] = None,
    seed: Annotated[int, typer.Option("--seed")] = 0,
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable output.")] = False,
) -> None:
    """Print the reference action chunk a checkpoint proposes for one observation."""
    import numpy as np

    from accrue.errors import AccrueError
    from accrue.policy import BasePolicy

    if task is None and (instruction is None or state is None):
        raise AccrueError("give --task, or both --instruction and --state")
    policy = BasePolicy.load(checkpoint, seed=seed)
    if state is not None:
        obs = {"state": np.asarray([_parse_state(state)], dtype=np.float32)}
    else:
        from accrue.sim import make_vec_env

        obs = make_vec_env(
            task, num_envs=1, seed=seed, obs_mode="state+image" if policy.image_keys else "state"
        ).reset()
    if instruction is None:
        from accrue.sim import get_task

        instruction = get_task(task).instruction
    chunk = policy.reference_chunk(obs, instruction, horizon)[0]
    if as_json:
        typer.echo(json.dumps({"instruction": instruction, "chunk": chunk.round(6).tolist()}))
        return
    from rich.table import Table

    table = Table(title=f"{policy.policy_type} chunk for: {instruction}")
    for name in ("h", "dx", "dy", "dz", "droll", "dpitch", "dyaw")[: chunk.shape[1] + 1]:
        table.add_column(name, justify="right")
    for h, row in enumerate(chunk):
        table.add_row(str(h), *(f"{v:+.3f}" for v in row))
    _console().print(table)


@policy_app.command("eval")
def eval_cmd(
    checkpoint: CheckpointArg,
    task: Annotated[list[str], typer.Option("--task", help="Sim task id; repeat for several.")],
    episodes: Annotated[int, typer.Option("--episodes")] = 50,
    horizon: Annotated[int, typer.Option("--horizon", help="Steps executed per chunk before re-planning.")] = 8,
    seed: Annotated[int, typer.Option("--seed", help="Env seed (use one the demos were not made with).")] = 10_000,
) -> None:
    """Success rate of the base policy alone (no RL actor) on sim tasks."""
    from accrue.policy import BasePolicy
    from accrue.policy.rollout import evaluate_success

    policy = BasePolicy.load(checkpoint)
    for task_id in task:
        result = evaluate_success(policy, task_id, episodes=episodes, horizon=horizon, seed=seed)
        typer.echo(
            f"{task_id}\tsuccess {result.rate:.3f} ({result.successes}/{result.episodes})\tmean steps {result.mean_steps:.1f}"
        )


def register(app: typer.Typer) -> None:
    app.add_typer(policy_app, name="policy")
