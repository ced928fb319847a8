"""The report's PNG figures, drawn with matplotlib's object API (no pyplot, no global state):

plot_curves(run, summary, path)        one panel per stage: success of every task seen so far
                                       against that stage's env steps, best checkpoint e* marked
plot_matrix(summary, path)             the success matrix c[i][j] as an annotated heat map
plot_base_vs_rl(run, summary, path)    per task, π_base alone vs π_base + RL actor (evaluate-all)
"""

from __future__ import annotations

import math
from pathlib import Path

from stages.report.data import RunData

DPI = 120


def _figure(width: float, height: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=DPI)
    FigureCanvasAgg(fig)
    return fig


def _save(fig, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI, bbox_inches="tight")
    return path


def task_colours(tasks: list[str]) -> dict[str, tuple]:
    from matplotlib import colormaps

    cmap = colormaps["tab10" if len(tasks) <= 10 else "tab20"]
    return {t: cmap(i % cmap.N) for i, t in enumerate(tasks)}


def plot_curves(run: RunData, summary: dict, path: Path) -> Path:
    from matplotlib.lines import Line2D
    from matplotlib.ticker import EngFormatter

    wf = run.workflow
    K = wf.num_stages
    ncols = min(K, 3)
    nrows = math.ceil(K / ncols)
    fig = _figure(4.3 * ncols, 3.4 * nrows + 0.9)
    axes = fig.subplots(nrows, ncols, squeeze=False, sharey=True)
    colours = task_colours(wf.tasks)
    for k in range(1, nrows * ncols + 1):
        ax = axes[(k - 1) // ncols][(k - 1) % ncols]
        if k > K:
            ax.set_visible(False)
            continue
        ax.set_ylim(-0.03, 1.03)
        ax.grid(True, alpha=0.3)
        ax.set_title(f"stage {k}: {wf.tasks[k - 1]}", fontsize=10)
        if (k - 1) % ncols == 0:
            ax.set_ylabel("success rate")
        if k > run.stages_done:
            ax.text(0.5, 0.5, "not run yet", transform=ax.transAxes, ha="center", va="center", fontsize=12, color="0.5")
            ax.set_xticks([])
            continue
        sc = run.curves[k - 1]
        chosen = summary["best_checkpoint"][k - 1]["index"]
        for task in sc.task_ids:
            new = task == wf.tasks[k - 1]
            if None in sc.success[task]:  # an earlier task scored at e* alone (no full_curves): one mark there
                at_chosen = (sc.report or sc.success)[task][chosen]
                ax.plot([sc.grid[chosen]], [at_chosen], color=colours[task], marker="D", ms=6, ls="", zorder=4)
                continue
            ax.plot(
                sc.grid,
                sc.success[task],
                color=colours[task],
                lw=2.4 if new else 1.4,
                ls="-" if new else "--",
                marker="o" if new else None,
                ms=3.5,
                zorder=3 if new else 2,
            )
        best = summary["best_checkpoint"][k - 1]["env_steps"]
        ax.axvline(best, color="0.35", ls=":", lw=1.2)
        ax.xaxis.set_major_formatter(EngFormatter(sep=""))
        ax.set_xlabel(f"env steps in stage {k}")
    tasks = [Line2D([], [], color=colours[t], lw=2, label=t) for t in wf.tasks[: run.stages_done]]
    styles = [
        Line2D([], [], color="0.3", lw=2.4, marker="o", ms=3.5, label="task learned in this stage"),
        Line2D([], [], color="0.3", lw=1.4, ls="--", label="earlier task (retention, with full_curves)"),
        Line2D([], [], color="0.3", marker="D", ms=6, ls="", label="earlier task at e*"),
        Line2D([], [], color="0.35", lw=1.2, ls=":", label="e*: earliest best checkpoint"),
    ]
    legend_rows = math.ceil(len(tasks) / 6) + 1
    fig.legend(
        handles=tasks,
        loc="lower center",
        ncol=min(len(tasks), 6),
        fontsize=9,
        frameon=False,
        bbox_to_anchor=(0.5, 0.045 / nrows),
    )
    fig.legend(handles=styles, loc="lower center", ncol=4, fontsize=8.5, frameon=False, bbox_to_anchor=(0.5, 0.0))
    episodes = run.curves[0].episodes_per_point
    fig.suptitle(f"{wf.name} ({wf.method}): success during each stage, {episodes} episodes per point", fontsize=12)
    fig.tight_layout(rect=(0, 0.06 * legend_rows / nrows, 1, 1))
    return _save(fig, path)


def plot_matrix(summary: dict, path: Path) -> Path:
    import numpy as np

    c = np.array([[np.nan if v is None else v for v in row] for row in summary["success_matrix"]])
    m = c.shape[0]
    tasks = summary["tasks"][:m]
    side = 1.2 + 1.1 * m
    fig = _figure(side + 1.6, side)
    ax = fig.add_subplot()
    image = ax.imshow(np.ma.masked_invalid(c), cmap="YlGn", vmin=0.0, vmax=1.0)
    ax.set_facecolor("0.93")
    for i in range(m):
        for j in range(m):
            if np.isnan(c[i, j]):
                ax.text(j, i, "—", ha="center", va="center", color="0.6", fontsize=10)
            else:
                ax.text(
                    j,
                    i,
                    f"{c[i, j]:.2f}",
                    ha="center",
                    va="center",
                    fontsize=11,
                    color="white" if c[i, j] > 0.6 else "black",
                    fontweight="bold" if i == j else None,
                )
    ax.set_xticks(
        range(m),
        [f"{j + 1}: {t}" for j, t in enumerate(tasks)],
        rotation=30 if m > 2 else 0,
        ha="right" if m > 2 else "center",
        fontsize=9,
    )
    ax.set_yticks(range(m), [f"after stage {i + 1}" for i in range(m)], fontsize=9)
    ax.set_xlabel("task j")
    partial = "" if m == summary["stages_total"] else f" (stages 1..{m} of {summary['stages_total']})"
    ax.set_title(f"success matrix c[i][j]{partial}\nat stage i's earliest best checkpoint", fontsize=10)
    fig.colorbar(image, ax=ax, fraction=0.046, pad=0.04, label="success rate")
    return _save(fig, path)


def plot_base_vs_rl(run: RunData, summary: dict, path: Path) -> Path | None:
    """None when no stage has a committed evaluate-all yet."""
    import numpy as np

    ev = run.latest_eval()
    if ev is None:
        return None
    tasks = ev.task_ids
    x = np.arange(len(tasks))
    width = 0.38
    fig = _figure(max(4.5, 1.4 * len(tasks) + 2.0), 4.0)
    ax = fig.add_subplot()
    base = [ev.base_success[t] for t in tasks]
    after = [ev.success[t] for t in tasks]
    bars_base = ax.bar(x - width / 2, base, width, color="0.7", label=f"π_base (stage {ev.stage})")
    bars_rl = ax.bar(x + width / 2, after, width, color="tab:blue", label="π_base + RL actor (after RL)")
    for bars in (bars_base, bars_rl):
        ax.bar_label(bars, fmt="%.2f", fontsize=8, padding=2)
    ax.set_xticks(x, tasks, rotation=20 if len(tasks) > 3 else 0, ha="right" if len(tasks) > 3 else "center")
    ax.set_ylim(0, 1.12)
    ax.set_ylabel("success rate")
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(loc="upper left", fontsize=8, ncol=2, frameon=False)
    ax.set_title(
        f"{summary['workflow']}: deployment success after stage {ev.stage} ({ev.episodes} episodes per task)",
        fontsize=10,
    )
    return _save(fig, path)
