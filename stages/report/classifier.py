"""The success classifier's part of a hardware report (robot.success_classifier; beyond the paper).

    rows = stage_classifiers(store, wf)      # {stage: {step: classifier.json's metrics}}
    text = classifier_markdown(rows)         # classifier.md

Each warmup / train step run with the classifier on wrote a `success_classifier` artifact; its metrics are
the final model's precision and recall (success positive) on the operator-labelled episodes held out from it
(held-out and audit; train's set includes its stage's warmup's held-out episodes, as it trains on warmup's labels),
against the operator's labels and, on the simulated robot, against the simulator's own success, and those
of the labels it gave alone against the simulator (stages.steps.robot_classifier.metrics).
"""

from __future__ import annotations

import json

from artifacts.store import Store
from stages.runner import step_ref
from stages.workflow import Workflow

CLASSIFIER_FILE = "classifier.md"
STEPS = ("warmup", "train")
SETS = {
    "held_out_vs_operator": "held-out episodes vs the operator's labels",
    "held_out_vs_simulator": "held-out episodes vs the simulator's success",
    "auto_labels_vs_simulator": "its own labels vs the simulator's success",
}


def step_classifier(store: Store, wf: Workflow, k: int, step: str) -> dict | None:
    """classifier.json of stage k's committed `step`, None when it has none (not run, or the classifier off)."""
    from artifacts.manifests import read_artifact, read_tree
    from artifacts.refs import read_ref

    record_id = read_ref(store, step_ref(wf.name, k, step))
    if record_id is None:
        return None
    artifact = (store.read_json(record_id).get("outputs") or {}).get("success_classifier")
    if artifact is None:
        return None
    manifest = read_artifact(store, artifact)
    found = [e["id"] for e in read_tree(store, manifest["content"]) if e["path"] == "classifier.json"]
    return json.loads(store.read_bytes(found[0])) if found else None


def stage_classifiers(store: Store, wf: Workflow) -> dict[int, dict[str, dict]]:
    out: dict[int, dict[str, dict]] = {}
    for k in range(1, wf.num_stages + 1):
        for step in STEPS:
            data = step_classifier(store, wf, k, step)
            if data is not None:
                trained = data["trained_on"]
                out.setdefault(k, {})[step] = {
                    **data["metrics"],
                    "trained_on": len(trained),
                    "trained_on_carried": sum(phase != data["phase"] for phase, _ in trained),
                }
    return out


def _figure(value) -> str:
    return "–" if value is None else f"{value:.3f}"


def classifier_markdown(rows: dict[int, dict[str, dict]]) -> str:
    lines = [
        "# Success classifier (robot.success_classifier; beyond the paper)",
        "",
        "Precision and recall with success as the positive class; a prediction is p(success) >= 0.5 of the",
        "step's final classifier. Held-out episodes (held-out and audit) were labelled by the operator and",
        "never trained on; train's include its stage's warmup held-out episodes, measured again.",
        "",
        "| stage | step | set | episodes | precision | recall | tp | fp | fn | tn |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for k, steps in sorted(rows.items()):
        for step, m in steps.items():
            for key, what in SETS.items():
                if key in m:
                    s = m[key]
                    lines.append(
                        f"| {k} | {step} | {what} | {s['episodes']} | {_figure(s['precision'])} | "
                        f"{_figure(s['recall'])} | {s['tp']} | {s['fp']} | {s['fn']} | {s['tn']} |"
                    )
    lines.append("")
    for k, steps in sorted(rows.items()):
        for step, m in steps.items():
            counts = ", ".join(f"{mode} {n}" for mode, n in m["labels"].items())
            line = f"- stage {k} {step}: trained on {m['trained_on']} labels"
            if m.get("carried_labels"):
                carried = ", ".join(f"{mode} {n}" for mode, n in m["carried_labels"].items())
                line += f" ({m['trained_on_carried']} of them warmup's); warmup's episodes by mode: {carried}"
            lines.append(f"{line}; episodes by mode: {counts}")
    return "\n".join(lines) + "\n"
