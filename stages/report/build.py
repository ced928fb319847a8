"""Write a workflow's report: read the committed run, compute its numbers, draw its figures.

    summary = write_report(store, wf, out_dir)

Returns summary.summarize(...)'s dict plus "files" (name -> path written, or None when there was
nothing to draw) and "out_dir". A run with nothing committed raises StageError (one line).
"""

from __future__ import annotations

from pathlib import Path

from artifacts.store import DEFAULT_DIRNAME, Store
from stages.report.data import load_run
from stages.report.plots import plot_base_vs_rl, plot_curves, plot_matrix
from stages.report.recording import write_recording
from stages.report.summary import summarize
from stages.workflow import Workflow

FILES = {
    "curves": "curves.png",
    "success_matrix": "success_matrix.png",
    "base_vs_rl": "base_vs_rl.png",
    "recording": "report.rrd",
    "summary": "report.json",
}


def default_out_dir(wf: Workflow, store: Store | None = None) -> Path:
    """runs/<workflow>/report for the default store (./.accrue); `<store>-report/<workflow>` beside any
    other, so the reports of two stores never overwrite each other."""
    if store is None or store.root == (Path.cwd() / DEFAULT_DIRNAME).absolute():
        return Path("runs") / wf.name / "report"
    return store.root.parent / f"{store.root.name}-report" / wf.name


def write_report(store: Store, wf: Workflow, out_dir: Path | None = None) -> dict:
    import json

    run = load_run(store, wf)
    summary = summarize(run)
    out = Path(out_dir) if out_dir is not None else default_out_dir(wf, store)
    out.mkdir(parents=True, exist_ok=True)
    base_vs_rl = plot_base_vs_rl(run, summary, out / FILES["base_vs_rl"])
    if base_vs_rl is None:  # a stale figure from an earlier report would contradict this one
        (out / FILES["base_vs_rl"]).unlink(missing_ok=True)
    files = {
        "curves": plot_curves(run, summary, out / FILES["curves"]),
        "success_matrix": plot_matrix(summary, out / FILES["success_matrix"]),
        "base_vs_rl": base_vs_rl,
        "recording": write_recording(run, out / FILES["recording"]),
        "summary": out / FILES["summary"],
    }
    summary["out_dir"] = str(out)
    summary["files"] = {name: None if p is None else str(p) for name, p in files.items()}
    tmp = out / (FILES["summary"] + ".tmp")
    tmp.write_text(json.dumps(summary, indent=2) + "\n")
    tmp.replace(out / FILES["summary"])
    return summary
