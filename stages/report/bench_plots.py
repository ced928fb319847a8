"""Figures of a bench report (matplotlib object API, Agg canvas, no pyplot):

    plot_metric_bars(agg, path)          one panel per metric: per method, the mean over its runs with
                                         its 95% bootstrap CI as an error bar; "—" where undefined
    plot_stage_curves(means, path)       one panel per stage position k: per method, the mean success of
                                         the task learned in stage k (solid) and of the earlier tasks
                                         (dashed) against stage k's env steps, with 95% bootstrap bands

`means` is stages.bench.curves.mean_stage_curves' result: per method, per stage k, the grid and a mean
with its CI at every grid point for the current task and for the earlier tasks.
"""

from __future__ import annotations

import math
from pathlib import Path

from stages.report.plots import _figure, _save
from stages.report.tables import ARROWS, TABLE_METRICS


def method_colours(methods: list[str]) -> dict[str, tuple]:
    from matplotlib import colormaps

    cmap = colormaps["tab10" if len(methods) <= 10 else "tab20"]
    return {m: cmap(i % cmap.N) for i, m in enumerate(methods)}


def plot_metric_bars(agg: dict, path: Path) -> Path:
    methods = [m["method"] for m in agg["methods"]]
    colours = method_colours(methods)
    fig = _figure(max(10.0, 2.2 * len(TABLE_METRICS) + 0.35 * len(methods) * len(TABLE_METRICS) / 2), 3.8)
    axes = fig.subplots(1, len(TABLE_METRICS), squeeze=False)[0]
    for ax, name in zip(axes, TABLE_METRICS):
        for i, m in enumerate(agg["methods"]):
            s = m["metrics"][name]
            if s["mean"] is None:
                ax.text(i, 0.02, "—", ha="center", va="bottom", color="0.5")
                continue
            err = [[s["mean"] - s["ci_low"]], [s["ci_high"] - s["mean"]]]
            ax.bar(i, s["mean"], color=colours[m["method"]], yerr=err, capsize=3, ecolor="0.2")
        ax.set_xticks(range(len(methods)), methods, rotation=45, ha="right", fontsize=8)
        ax.set_title(f"{name} {ARROWS[name]}", fontsize=10)
        ax.set_ylim(min(0.0, *(m["metrics"][name]["ci_low"] or 0 for m in agg["methods"])) - 0.02, 1.02)
        ax.grid(True, axis="y", alpha=0.3)
    pct = round(agg["confidence"] * 100)
    fig.suptitle(f"mean over runs (orderings × seeds), {pct}% bootstrap CI", fontsize=11)
    fig.tight_layout()
    return _save(fig, path)


def plot_stage_curves(means: dict[str, list[dict]], path: Path) -> Path | None:
    """None when no run has curves."""
    from matplotlib.lines import Line2D
    from matplotlib.ticker import EngFormatter

    if not means:
        return None
    K = max(len(stages) for stages in means.values())
    methods = list(means)
    colours = method_colours(methods)
    ncols = min(K, 3)
    nrows = math.ceil(K / ncols)
    fig = _figure(4.3 * ncols, 3.3 * nrows + 0.8)
    axes = fig.subplots(nrows, ncols, squeeze=False, sharey=True)
    for k in range(K):
        ax = axes[k // ncols][k % ncols]
        ax.set_ylim(-0.03, 1.03)
        ax.grid(True, alpha=0.3)
        ax.set_title(f"stage {k + 1}", fontsize=10)
        for method, stages in means.items():
            if len(stages) <= k:
                continue
            grid = stages[k]["grid"]
            for key, style in (("current", "-"), ("earlier", "--")):
                points = stages[k][key]
                if points is None:
                    continue
                mean, lo, hi = ([p[f] for p in points] for f in ("mean", "ci_low", "ci_high"))
                ax.plot(grid, mean, color=colours[method], ls=style, lw=2 if key == "current" else 1.3)
                ax.fill_between(grid, lo, hi, color=colours[method], alpha=0.15 if key == "current" else 0.08)
        ax.xaxis.set_major_formatter(EngFormatter(sep=""))
        ax.set_xlabel(f"env steps in stage {k + 1}")
        if k % ncols == 0:
            ax.set_ylabel("success rate")
    for k in range(K, nrows * ncols):
        axes[k // ncols][k % ncols].set_visible(False)
    handles = [Line2D([], [], color=colours[m], lw=2, label=m) for m in methods]
    handles += [
        Line2D([], [], color="0.3", lw=2, label="task of this stage"),
        Line2D([], [], color="0.3", lw=1.3, ls="--", label="earlier tasks (mean)"),
    ]
    fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 5), fontsize=8.5, frameon=False)
    fig.suptitle("mean success per stage over orderings × seeds (bands: 95% bootstrap CI)", fontsize=11)
    fig.tight_layout(rect=(0, 0.05 + 0.03 * math.ceil(len(handles) / 5), 1, 1))
    return _save(fig, path)
