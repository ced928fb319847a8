"""The report of a hardware workflow (paper Sec. V-C): Fig. 4 and Table III.

    summary = write_hardware_report(store, wf, out_dir, single_task=None)

Fig. 4 (`fig4.png`): per stage, the running success over the last `stop_window` episodes against the
cumulative robot interaction time for RL (demonstration collection excluded), warmup rollouts of the base
policy shaded grey at the left, dashed while fewer than `stop_window` episodes exist, the stop rule's
line (stop_successes / stop_window: 0.95 for the default 19/20) and a dotted line where it was reached.
With `single_task` (a Single-task workflow of the same task sequence, run in the same store) its curves
are drawn too, and the robot time saved is shaded and given. Every stage's stop rule is in report.json.
Table III (`table3.md`): successes over the retention trials on each earlier task after each later stage.
With robot.intervention (beyond the paper), `interventions.md`: the intervention rate per block of
`stop_window` consecutive train episodes of each stage, and the sliding rate over the last `stop_window`
episodes at the stage's end (what the operator page and TensorBoard show); both are accrue.robot.teleop's
window_rate.
With robot.success_classifier, `classifier.md`: its precision and recall (stages.report.classifier).
`report.json` holds every number shown.
"""

from __future__ import annotations

import json
from pathlib import Path

from artifacts.store import Store
from stages.errors import StageError
from stages.report.classifier import CLASSIFIER_FILE, classifier_markdown, stage_classifiers
from stages.report.data import read_step_file
from stages.runner import step_ref
from stages.workflow import RobotSpec, Workflow

REPORT_FILES = {"fig4": "fig4.png", "table3": "table3.md", "summary": "report.json"}
INTERVENTIONS_FILE = "interventions.md"  # with robot.intervention only


def stage_curves(store: Store, wf: Workflow) -> dict[int, dict]:
    """stage -> the committed hardware train curve (curve.json with "hardware": true)."""
    out = {}
    for k in range(1, wf.num_stages + 1):
        found = read_step_file(store, step_ref(wf.name, k, "train"), "train")
        if found is None:
            break
        data = found[0]
        if not data.get("hardware"):
            raise StageError(f"workflow {wf.name}: stage {k}'s train record is not a hardware run")
        out[k] = data
    return out


def step_episodes(store: Store, wf: Workflow, k: int, step: str) -> list[dict] | None:
    """The sealed episode records (episode.json, in index order) of stage k's committed hardware `step`;
    None when it has not committed."""
    from artifacts.manifests import read_artifact, read_tree
    from artifacts.refs import read_ref

    record_id = read_ref(store, step_ref(wf.name, k, step))
    if record_id is None:
        return None
    artifact = (store.read_json(record_id).get("outputs") or {}).get("episodes")
    if artifact is None:
        return []
    manifest = read_artifact(store, artifact)
    files = sorted(
        (e["path"], e["id"]) for e in read_tree(store, manifest["content"]) if e["path"].endswith("episode.json")
    )
    return [json.loads(store.read_bytes(oid)) for _, oid in files]


def stage_interventions(store: Store, wf: Workflow) -> dict[int, dict]:
    """stage -> its interventions (robot.intervention, beyond the paper), read from the sealed episode
    records: for train, the intervention rate (intervened control steps / control steps, teleop.window_rate)
    per block of `stop_window` consecutive episodes ("windows"), and the sliding one over the last
    `stop_window` episodes at the stage's end ("sliding_rate", the page's and TensorBoard's last value); for
    warmup (the operator may take over there too), its episodes as one block ("warmup"). Stages run without
    interventions are left out."""
    size = wf.robot.stop_window if wf.robot is not None else 20
    out = {}
    for k in range(1, wf.num_stages + 1):
        train = step_episodes(store, wf, k, "train")
        if train is None:
            break
        warm = [e for e in step_episodes(store, wf, k, "warmup") or [] if e.get("phase") == "warmup"]
        train = [e for e in train if e.get("phase") == "train"]
        row = intervention_rates(train, size) if any("interventions" in e for e in train) else None
        if any("interventions" in e for e in warm):
            block = intervention_rates(warm, max(1, len(warm)))["windows"]
            row = row or {"window": size, "windows": [], "intervened_steps": 0}
            row["warmup"] = block[0] if block else None
        if row is not None:
            out[k] = row
    return out


def intervention_rates(eps: list[dict], size: int) -> dict:
    """The train episodes' (episode.json records, in order) intervention rates: per block of `size`
    consecutive episodes, and sliding over the last `size` at the end; both teleop.window_rate."""
    from accrue.robot.teleop import window_rate

    counts = [(e.get("interventions", 0), e["control_steps"]) for e in eps]
    windows = []
    for i in range(0, len(eps), size):
        block, block_counts = eps[i : i + size], counts[i : i + size]
        windows.append(
            {
                "episodes": f"{block[0]['index']}-{block[-1]['index']}",
                "intervened_steps": sum(n for n, _ in block_counts),
                "control_steps": sum(n for _, n in block_counts),
                "episodes_with_interventions": sum(bool(n) for n, _ in block_counts),
                "rate": round(window_rate(block_counts, len(block_counts)), 4),
            }
        )
    return {
        "window": size,
        "windows_are": f"blocks of {size} consecutive train episodes",
        "windows": windows,
        "sliding_rate": round(window_rate(counts, size), 4),
        "intervened_steps": sum(n for n, _ in counts),
    }


def interventions_markdown(rows: dict[int, dict]) -> str:
    lines = [
        "# Interventions (robot.intervention; beyond the paper)",
        "",
        "Intervention rate: control steps the operator drove through the teleoperator / all control steps",
        "(accrue.robot.teleop.window_rate). The table gives it for each stage's warmup episodes and per block",
        "of consecutive train episodes; the",
        "operator page and TensorBoard show it sliding, over the last episodes, whose value at each stage's",
        "end is listed below the table.",
        "",
        "| stage | block of episodes | intervened steps | control steps | episodes with interventions | rate |",
        "|---|---|---|---|---|---|",
    ]
    for k, row in sorted(rows.items()):
        warm = [("warmup ", row["warmup"])] if row.get("warmup") else []
        for what, w in [*warm, *(("", w) for w in row["windows"])]:
            lines.append(
                f"| {k} | {what}{w['episodes']} | {w['intervened_steps']} | {w['control_steps']} | "
                f"{w['episodes_with_interventions']} | {100 * w['rate']:.1f}% |"
            )
    lines.append("")
    for k, row in sorted(rows.items()):
        if "sliding_rate" in row:
            lines.append(
                f"- stage {k}: per block of {row['window']}; sliding over the last {row['window']} at the "
                f"end: {100 * row['sliding_rate']:.1f}%"
            )
    return "\n".join(lines) + "\n"


def retention_table(store: Store, wf: Workflow) -> dict[int, dict[str, list[bool]]]:
    """after stage k -> {earlier task: trial labels}."""
    out = {}
    for k in range(2, wf.num_stages + 1):
        found = read_step_file(store, step_ref(wf.name, k, "evaluate-all"), "evaluate-all")
        if found is not None:
            out[k] = found[0].get("trials", {})
    return out


def running_success(curve: dict) -> tuple[list[float], list[float], list[bool]]:
    """(x = warmup time + cumulative RL robot time, running success, full window?) per RL episode."""
    t0 = float(curve.get("warmup_robot_time_s", 0.0))
    xs, ys, full = [], [], []
    for e in curve["episodes"]:
        xs.append(t0 + e["cum_robot_time_s"])
        ys.append(e["window_success"] / e["window_size"])
        full.append(e["window_size"] >= curve["stop_window"])
    return xs, ys, full


def stop_rule(curve: dict, wf: Workflow) -> dict:
    """{"successes", "window"}: the stop rule the stage's train step ran with (its curve.json), else the
    workflow's robot.stop_successes / robot.stop_window."""
    r = wf.robot if wf.robot is not None else RobotSpec.model_construct()  # its defaults
    return {
        "successes": int(curve.get("stop_successes", r.stop_successes)),
        "window": int(curve.get("stop_window", r.stop_window)),
    }


def stage_summary(curve: dict, wf: Workflow) -> dict:
    return {
        "stop_rule": stop_rule(curve, wf),
        "warmup_robot_time_s": curve.get("warmup_robot_time_s", 0.0),
        "rl_robot_time_s": curve["rl_robot_time_s"],
        "reached_robot_time_s": curve["reached_robot_time_s"],
        "episodes": curve["train_episodes"],
        "successes": curve["train_successes"],
        "stopped": curve["stopped"],
        "updates": curve.get("updates"),
    }


def plot_fig4(curves: dict[int, dict], wf: Workflow, path: Path, other: dict[int, dict] | None = None) -> Path:
    from stages.report.plots import _figure, _save

    n = max(len(curves), 1)
    fig = _figure(4.2 * n, 3.4)
    axes = fig.subplots(1, n, squeeze=False)[0]
    for ax, (k, curve) in zip(axes, sorted(curves.items())):
        runs = [("ACCRUE" if wf.method == "accrue" else wf.method, curve, "tab:blue")]
        if other and k in other and k > 1:  # stage 1 is shared by both conditions
            runs.append(("Single-task", other[k], "tab:orange"))
        ax.axvspan(0, curve.get("warmup_robot_time_s", 0.0), color="0.85", label="warmup (base policy)")
        for name, c, colour in runs:
            xs, ys, full = running_success(c)
            split = next((i for i, f in enumerate(full) if f), len(xs))
            ax.plot(xs[: split + 1], ys[: split + 1], "--", color=colour, lw=1)
            ax.plot(xs[split:], ys[split:], "-", color=colour, lw=1.5, label=name)
            if c["reached_robot_time_s"] is not None:
                ax.axvline(c.get("warmup_robot_time_s", 0.0) + c["reached_robot_time_s"], color=colour, ls=":", lw=1)
        if len(runs) == 2 and all(c["reached_robot_time_s"] is not None for _, c, _ in runs):
            a = curve.get("warmup_robot_time_s", 0.0) + curve["reached_robot_time_s"]
            b = other[k].get("warmup_robot_time_s", 0.0) + other[k]["reached_robot_time_s"]
            if b > a:
                ax.axvspan(a, b, color="tab:green", alpha=0.15, label=f"saved {b - a:.0f} s")
        rule = stop_rule(curve, wf)
        ax.axhline(rule["successes"] / rule["window"], color="k", lw=0.8, ls="-.")
        ax.set_title(f"stage {k}: {curve['task_ids'][-1]}", fontsize=9)
        ax.set_xlabel("robot interaction time for RL (s)")
        ax.set_ylim(-0.02, 1.02)
        ax.legend(fontsize=6, loc="lower right")
    axes[0].set_ylabel(
        f"running success (last {next(iter(curves.values()))['stop_window']} episodes)" if curves else "running success"
    )
    return _save(fig, path)


def table3_markdown(table: dict[int, dict[str, list[bool]]], wf: Workflow) -> str:
    stages = sorted(table)
    if not stages or len(wf.tasks) < 2:  # retention is of tasks 1..k-1 after stage k: none before stage 2
        why = (
            f"the workflow has one task ({wf.tasks[0]})"
            if len(wf.tasks) < 2
            else "no stage after the first has committed evaluate-all yet"
        )
        return f"# Retention trials (Table III)\n\nNo retention trials: {why}; they are run on tasks 1..k-1 after stage k.\n"
    lines = ["| task | " + " | ".join(f"after stage {k}" for k in stages) + " |", "|---|" + "---|" * len(stages)]
    for i, task in enumerate(wf.tasks[:-1], 1):
        cells = [f"{sum(table[k][task])}/{len(table[k][task])}" if task in table[k] else "–" for k in stages]
        lines.append(f"| stage {i} ({task}) | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def write_hardware_report(
    store: Store, wf: Workflow, out_dir: Path | None = None, single_task: Workflow | None = None
) -> dict:
    curves = stage_curves(store, wf)
    if not curves:
        raise StageError(
            f"workflow {wf.name}: no hardware train step has committed yet (run `accrue stage run ... --stage 1`)"
        )
    other = stage_curves(store, single_task) if single_task is not None else None
    if single_task is not None and single_task.tasks != wf.tasks:
        raise StageError(f"--single-task {single_task.name}: its tasks differ from {wf.name}'s")
    out = Path(out_dir) if out_dir is not None else Path("runs") / wf.name / "report"
    out.mkdir(parents=True, exist_ok=True)
    table = retention_table(store, wf)
    summary = {
        "workflow": wf.name,
        "method": wf.method,
        "hardware": True,
        "stages": {k: stage_summary(c, wf) for k, c in curves.items()},
        "retention": {
            k: {t: {"successes": sum(v), "trials": len(v)} for t, v in row.items()} for k, row in table.items()
        },
    }
    if other:
        saved = {}
        for k, c in curves.items():
            if (
                k in other
                and k > 1
                and c["reached_robot_time_s"] is not None
                and other[k]["reached_robot_time_s"] is not None
            ):
                a, b = c["reached_robot_time_s"], other[k]["reached_robot_time_s"]
                saved[k] = {
                    "accrue_s": a,
                    "single_task_s": b,
                    "saved_s": round(b - a, 3),
                    "saved_percent": round(100 * (b - a) / b, 1) if b > 0 else None,
                }
        summary["single_task"] = {
            "workflow": single_task.name,
            "stages": {k: stage_summary(c, single_task) for k, c in other.items()},
            "time_saved": saved,
        }
    files = {"fig4": str(plot_fig4(curves, wf, out / REPORT_FILES["fig4"], other))}
    (out / REPORT_FILES["table3"]).write_text(table3_markdown(table, wf))
    files["table3"] = str(out / REPORT_FILES["table3"])
    taken = stage_interventions(store, wf)
    if taken:  # only a workflow run with robot.intervention has any
        summary["interventions"] = taken
        (out / INTERVENTIONS_FILE).write_text(interventions_markdown(taken))
        files["interventions"] = str(out / INTERVENTIONS_FILE)
    judged = stage_classifiers(store, wf)
    if judged:  # only a workflow run with robot.success_classifier has any
        summary["success_classifier"] = judged
        (out / CLASSIFIER_FILE).write_text(classifier_markdown(judged))
        files["success_classifier"] = str(out / CLASSIFIER_FILE)
    summary["files"] = files
    summary["out_dir"] = str(out)
    (out / REPORT_FILES["summary"]).write_text(json.dumps(summary, indent=2, default=str) + "\n")
    return summary
