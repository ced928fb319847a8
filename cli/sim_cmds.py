"""`accrue sim`: list the simulated tasks, record expert demonstrations, watch one episode.

Only typer/rich at module level; the simulator, lerobot and rerun are imported inside commands.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Optional

import typer

sim_app = typer.Typer(
    help="Simulated insertion tasks: list them, record expert demos, watch an episode.", no_args_is_help=True
)

TaskArg = Annotated[str, typer.Argument(help="Task id, e.g. plugs/cross (see `accrue sim tasks`).", show_default=False)]
SeedOpt = Annotated[int, typer.Option("--seed", min=0, help="Seed of the env (and expert / random policy).")]


def _console(stderr: bool = False):
    from rich.console import Console

    return Console(highlight=False, stderr=stderr)


def _sim():
    from accrue.sim import demos

    return demos._sim_api()


def _noise(spec) -> dict | None:
    """The task's per-episode and per-step noise settings in display units (None: the spec declares none)."""
    r = getattr(spec, "randomisation", None)
    if r is None:
        return None
    bias = getattr(spec, "estimate_bias", (0.0, 0.0, 0.0))
    deg = 180.0 / 3.141592653589793
    return {
        "estimate_bias_mm_deg": [round(bias[0] * 1e3, 3), round(bias[1] * 1e3, 3), round(bias[2] * deg, 3)],
        "estimate_xy_mm": round(r.estimate_xy * 1e3, 3),
        "estimate_yaw_deg": round(r.estimate_yaw * deg, 3),
        "in_hand_xy_mm": round(r.in_hand_xy * 1e3, 3),
        "in_hand_yaw_deg": round(r.in_hand_yaw * deg, 3),
        "obs_pos_mm": round(r.obs_pos * 1e3, 3),
        "obs_force_n": round(r.obs_force, 3),
        "friction": [round(float(f), 3) for f in r.friction],
    }


def _task_row(s) -> dict:
    row = {
        "family": s.family,
        "task_id": s.task_id,
        "instruction": s.instruction,
        "clearance_mm": round(float(s.clearance) * 1e3, 3),
        "max_steps": int(s.max_steps),
        "control_hz": float(s.control_hz),
    }
    if hasattr(s, "role"):  # a real TaskSpec: its role in the benchmark, success depth and noise
        row.update(
            role=s.role,
            depth_mm=round(float(s.depth) * 1e3, 3),
            success_depth_mm=round(float(s.success_depth) * 1e3, 3),
            chamfer_mm=round(float(s.chamfer) * 1e3, 3),
            yaw_symmetry=int(s.yaw_symmetry),
            noise=_noise(s),
        )
    return row


def _noise_text(noise: dict | None) -> str:
    if noise is None:
        return ""
    bx, by, byaw = noise["estimate_bias_mm_deg"]
    bias = f"bias ({bx:+.1f}, {by:+.1f}) mm {byaw:+.1f}°" if any((bx, by, byaw)) else "no bias"
    text = f"{bias}; est σ {noise['estimate_xy_mm']:.2f} mm {noise['estimate_yaw_deg']:.1f}°"
    if noise["in_hand_xy_mm"] or noise["in_hand_yaw_deg"]:
        text += f"; in-hand σ {noise['in_hand_xy_mm']:.2f} mm {noise['in_hand_yaw_deg']:.1f}°"
    return text + f"; F σ {noise['obs_force_n']:.1f} N; μ {noise['friction'][0]:.2f}-{noise['friction'][1]:.2f}"


@sim_app.command("tasks")
def tasks_cmd(
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable output.")] = False,
    family: Annotated[
        Optional[str], typer.Option("--family", help="Only this family (e.g. contact, nist, plugs).")
    ] = None,
) -> None:
    """List the tasks: family, role in the benchmark (shared-skill / negative-control), id, clearance,
    success depth, time limit and noise settings (--json adds the instruction)."""
    from accrue.errors import AccrueError

    sim = _sim()
    specs = [sim.get_task(t) for t in sim.list_tasks()]
    if family is not None:
        specs = [s for s in specs if s.family == family]
        if not specs:
            families = sorted({s.family for s in (sim.get_task(t) for t in sim.list_tasks())})
            raise AccrueError(f"no task family {family!r}; families: {', '.join(families)}")
    rows = [_task_row(s) for s in specs]
    if as_json:
        typer.echo(json.dumps(rows, indent=2))
        return
    from rich.table import Table

    table = Table(title=f"{len(rows)} simulated tasks")
    for name, justify in (
        ("family", "left"),
        ("role", "left"),
        ("task id", "left"),
        ("clearance", "right"),
        ("success depth", "right"),
        ("max steps", "right"),
        ("noise", "left"),
    ):
        table.add_column(name, justify=justify)
    for r in rows:
        depth = f"{r['success_depth_mm']:.1f}/{r['depth_mm']:.0f} mm" if "depth_mm" in r else ""
        table.add_row(
            r["family"],
            r.get("role", ""),
            r["task_id"],
            f"{r['clearance_mm']:.2f} mm",
            depth,
            f"{r['max_steps']} ({r['max_steps'] / r['control_hz']:.1f} s)",
            _noise_text(r.get("noise")),
        )
    _console().print(table)


@sim_app.command("demos")
def demos_cmd(
    task: TaskArg,
    episodes: Annotated[int, typer.Option("--episodes", "-n", min=1, help="Episodes to write.")] = ...,
    out: Annotated[
        Path, typer.Option("--out", "-o", help="New (or empty) dataset directory.", show_default=False)
    ] = ...,
    seed: SeedOpt = 0,
    quality: Annotated[float, typer.Option("--quality", min=0.0, max=1.0, help="Expert quality (1 = best).")] = 1.0,
    images: Annotated[bool, typer.Option("--images", help="Also record the wrist camera (video).")] = False,
    keep_failures: Annotated[bool, typer.Option("--keep-failures", help="Keep failed expert episodes too.")] = False,
    search: Annotated[
        bool,
        typer.Option(
            "--search/--no-search",
            help="--no-search: an expert that never searches (acts on the current observation only).",
        ),
    ] = True,
    bias_known: Annotated[
        float,
        typer.Option(
            "--bias-known", min=0.0, max=1.0, help="Fraction of the fixture's estimate bias the expert corrects."
        ),
    ] = 1.0,
    num_envs: Annotated[
        Optional[int], typer.Option("--num-envs", min=1, help="Parallel envs (default min(N, 8)).")
    ] = None,
    max_attempts: Annotated[
        Optional[int], typer.Option("--max-attempts", min=1, help="Most expert episodes to run (default max(3N, N+8)).")
    ] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Record scripted-expert demonstrations as a LeRobotDataset v3 (loads with lerobot offline)."""
    from artifacts.placement import refuse_inside_store

    refuse_inside_store(out, "--out")  # before the simulator's slow imports
    from accrue.sim.demos import write_demos

    summary = write_demos(
        task,
        episodes,
        out,
        seed=seed,
        quality=quality,
        obs_mode="state+image" if images else "state",
        only_successful=not keep_failures,
        progress=not quiet,
        num_envs=num_envs,
        max_attempts=max_attempts,
        search=search,
        bias_known=bias_known,
    )
    con = _console()
    con.print(f"wrote {summary.episodes} episodes ({summary.frames} frames) of {summary.task_id} to {summary.root}")
    con.print(
        f"expert success rate: {summary.expert_success_rate:.0%} "
        f"({summary.successes} of {summary.attempts} episodes, quality {summary.quality:g})"
    )
    if not summary.complete:
        _console(stderr=True).print(
            f"[yellow]warning:[/] only {summary.episodes} of {summary.requested} episodes written "
            f"(attempt bound reached); raise --max-attempts or --quality"
        )
        raise typer.Exit(1)


@sim_app.command("watch")
def watch_cmd(
    task: TaskArg,
    policy: Annotated[str, typer.Option("--policy", help="expert or random.")] = "expert",
    seed: SeedOpt = 0,
    out: Annotated[
        Optional[Path],
        typer.Option(
            "--out",
            "-o",
            help="Recording file (.rrd); default ./watch-<task>-<policy>-seed<S>.rrd.",
            show_default=False,
        ),
    ] = None,
    images: Annotated[bool, typer.Option("--images", help="Also log the wrist camera.")] = False,
    mcap: Annotated[
        Optional[Path],
        typer.Option("--mcap", help="Also record the episode as MCAP in this directory.", show_default=False),
    ] = None,
) -> None:
    """Run one episode and write a rerun recording of it (open with `rerun FILE.rrd`)."""
    from accrue.errors import AccrueError
    from accrue.logs.episode_watch import watch_episode
    from artifacts.placement import refuse_inside_store

    if out is not None and out.is_dir():
        raise AccrueError(f"--out {out}: is a directory; give the recording's file name (e.g. {out}/watch.rrd)")
    for option, path in (("--out", out), ("--mcap", mcap)):
        if path is not None:
            refuse_inside_store(path, option)

    result = watch_episode(task, policy=policy, seed=seed, out=out, images=images, mcap_dir=mcap)
    con = _console()
    outcome = "[green]success[/]" if result.success else "[red]no success[/]"
    con.print(
        f"{task} with the {policy} policy (seed {seed}): {outcome} after {result.steps} steps, "
        f"return {result.episode_return:g}"
    )
    con.print(f"recording: {result.rrd_path}" + (f"\nepisode log: {result.mcap_path}" if result.mcap_path else ""))


def register(app: typer.Typer) -> None:
    app.add_typer(sim_app, name="sim")
