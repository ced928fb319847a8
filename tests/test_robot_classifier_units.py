"""robot.success_classifier's parts: the model learns a separable labelling and not a shuffled one, the
classifier labels alone only above the workflow's threshold, a proposal's label says it was one, and a bad
setting is a one-line refusal at load (accrue.robot.success_classifier, stages.steps.robot_classifier)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from accrue.robot.operator import ScriptedOperator
from accrue.robot.success_classifier import ClassifierSettings, audited, confident, fit, held_out, scores

ROOT = Path(__file__).resolve().parents[1]


def toy(seed: int, n: int = 240, d: int = 8):
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, d))
    y = X[:, 0] + 0.5 * X[:, 1] - 0.3 * X[:, 2] > 0
    return X, y


def test_it_learns_a_separable_labelling_and_not_a_shuffled_one():
    X, y = toy(0)
    train, test = slice(0, 160), slice(160, None)
    model = fit(X[train], y[train])
    accuracy = np.mean((model.predict(X[test]) >= 0.5) == y[test])
    assert accuracy >= 0.9, accuracy
    shuffled = np.random.default_rng(1).permutation(y)
    chance = fit(X[train], shuffled[train])
    held = np.mean((chance.predict(X[test]) >= 0.5) == shuffled[test])
    assert held < 0.7, held  # no better than a guess on episodes it was not trained on
    again = fit(X[train], y[train])  # the same rows give the same model
    np.testing.assert_array_equal(again.w, model.w)


def test_held_out_share_is_spread_and_stable():
    marks = [held_out(j, 0.25) for j in range(40)]
    assert sum(marks) == 10 and marks[:4] == [False, False, False, True]
    assert not any(held_out(j, 0.0) for j in range(40))


def test_every_nth_sure_episode_is_audited():
    assert [n for n in range(10) if audited(n, 3)] == [2, 5, 8]
    assert not any(audited(n, None) for n in range(10))
    assert all(audited(n, 1) for n in range(10))  # 1: the operator labels every one blind


def test_scores_count_success_as_positive():
    s = scores([True, True, False, False, True], [True, False, True, False, True])
    assert (s["tp"], s["fp"], s["fn"], s["tn"]) == (2, 1, 1, 1)
    assert s["precision"] == pytest.approx(2 / 3, abs=1e-4) and s["recall"] == pytest.approx(2 / 3, abs=1e-4)
    assert scores([False], [False])["precision"] is None


class _Session:
    """The part of a HardwareSession the gate reads: no sealed episode yet."""

    def ordered(self, phase=None):
        return []


class _Fixed:
    def __init__(self, p: float):
        self.p = p

    def predict(self, X):
        return np.full(len(X), self.p)


def gate_with(p: float, **settings):
    from stages.steps.robot_classifier import ClassifierGate

    gate = ClassifierGate(ClassifierSettings(enabled=True, **settings), _Session(), "none", "warmup")
    gate.image_width, gate.model, gate.trained_on = 4, _Fixed(p), [0, 1, 2, 3]
    gate.refresh = lambda: None  # the model above stands in for one fitted on sealed labels
    return gate


@pytest.mark.parametrize(
    "p, above, mode, success",
    [
        (0.96, 0.95, "auto", True),
        (0.03, 0.95, "auto", False),  # confident of a failure: labelled a failure alone
        (0.95, 0.95, "proposed", True),  # at the threshold, not above it: the operator confirms
        (0.30, 0.95, "proposed", True),  # the operator (the simulator's truth) overrules
        (0.999, None, "proposed", True),  # no threshold: never alone
    ],
)
def test_the_classifier_labels_alone_only_above_the_threshold(p, above, mode, success):
    operator = ScriptedOperator(oracle=lambda: True, name="ann")
    label, entry = gate_with(p, auto_label_above=above).label(7, "done, 40 steps", np.zeros(10), operator)
    assert entry["mode"] == mode and entry["p"] == pytest.approx(p)
    assert label.success is success
    if mode == "auto":
        assert label.by == "classifier" and label.via == "classifier" and f"{p:.6f}" in label.note
        assert operator.told and "by the classifier" in operator.told[-1]
    else:
        assert label.by == "ann" and label.via == "scripted+classifier-proposal"
        assert label.note.endswith("confirmed" if (p >= 0.5) == success else "overruled")


def test_without_propose_the_operator_labels_as_today_and_held_out_is_blind():
    operator = ScriptedOperator(oracle=lambda: False, name="ann")
    label, entry = gate_with(0.6, propose=False, auto_label_above=0.9).label(1, "done", np.zeros(10), operator)
    assert entry["mode"] == "operator" and label.via == "scripted" and label.by == "ann" and not label.success
    gate = gate_with(0.99, auto_label_above=0.5)
    gate.judged = lambda: [{"classifier": {"mode": "untrained"}}] * 3  # the next operator label is the 4th
    label, entry = gate.label(5, "done", np.zeros(10), operator)
    assert entry == {"mode": "held-out", "p": None, "trained_on": 0} and label.by == "ann"
    assert confident(0.5, 0.0)  # max(p, 1 - p) = 0.5 > 0: a threshold of 0 labels everything


def test_every_audit_every_th_sure_episode_goes_to_the_operator_blind_and_is_held_out():
    """Two sure episodes labelled alone, the third the operator's (no proposal shown), then alone again:
    the count is of the stage's sure episodes so far (warmup's carried ones first)."""
    operator = ScriptedOperator(oracle=lambda: False, name="ann")
    gate = gate_with(0.99, auto_label_above=0.95, audit_every=3)
    sealed: list[dict] = []
    gate.judged = lambda: sealed
    modes = []
    for index in range(7):
        label, entry = gate.label(index, "done", np.zeros(10), operator)
        modes.append(entry["mode"])
        sealed.append({"index": index, "classifier": entry, "label": {"by": label.by, "success": label.success}})
        if entry["mode"] == "audit":
            assert label.by == "ann" and label.via == "scripted" and not label.success and entry["p"] == 0.99
    assert modes == ["auto", "auto", "audit", "auto", "auto", "audit", "auto"]
    gate = gate_with(0.99, auto_label_above=0.95, audit_every=3)
    gate.carried = [{"mode": "auto"}, {"mode": "untrained"}, {"mode": "auto"}]  # warmup's: two sure ones
    assert gate.label(9, "done", np.zeros(10), operator)[1]["mode"] == "audit"
    off = gate_with(0.99, auto_label_above=0.95, audit_every=None)
    off.judged = lambda: [{"classifier": {"mode": "auto"}}] * 2
    assert off.label(3, "done", np.zeros(10), operator)[1]["mode"] == "auto"


def test_metrics_count_audits_and_warmups_held_out_episodes():
    from stages.steps.robot_classifier import metrics

    def entry(phase, mode, label, p, by="ann"):
        return {"phase": phase, "index": 0, "mode": mode, "label": label, "label_by": by, "p": p, "sim_success": label}

    entries = [
        entry("warmup", "held-out", True, 0.9),
        entry("warmup", "untrained", False, 0.2),
        entry("train", "held-out", False, 0.6),
        entry("train", "audit", True, 0.3),
        entry("train", "auto", True, 0.99, by="classifier"),
    ]
    m = metrics(entries, "train")
    held = m["held_out_vs_operator"]
    assert (held["episodes"], held["tp"], held["fp"], held["fn"], held["tn"]) == (3, 1, 1, 1, 0)
    assert m["labels"] == {"audit": 1, "auto": 1, "held-out": 1}
    assert m["carried_labels"] == {"held-out": 1, "untrained": 1}
    assert m["auto_labels_vs_simulator"]["episodes"] == 1


def workflow(tmp_path: Path, encoder: str = "none", **classifier) -> dict:
    return {
        "name": "sc",
        "tasks": ["nist/rect_peg"],
        "method": "accrue",
        "horizon": 4,
        "encoder": encoder,
        "base_policy": {"init": "scripted-reference:1.0"},
        "budgets": {"env_steps": 1000, "eval_every": 1000},
        "robot": {
            "type": "accrue_sim",
            "config": {"calibration_dir": str(tmp_path / "calib"), "render_cameras": ["front"]},
            "operator": "scripted",
            "success_classifier": classifier,
        },
    }


def accrue(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1", "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-m", "cli.main", *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=300
    )


def test_bad_classifier_settings_are_one_line_refusals(tmp_path):
    enc = "vit_tiny_patch16_224:" + str(tmp_path / "w.safetensors")
    no_camera = workflow(tmp_path, enc, enabled=True)
    no_camera["robot"]["config"].pop("render_cameras")
    cases = {
        "high.yaml": (workflow(tmp_path, enc, auto_label_above=1.5), "auto_label_above: must be <= 1"),
        "low.yaml": (workflow(tmp_path, enc, auto_label_above=-0.1), "auto_label_above: must be >= 0"),
        "labels.yaml": (workflow(tmp_path, enc, min_labels=1), "min_labels: must be >= 2 (got 1)"),
        "encoder.yaml": (workflow(tmp_path, enabled=True), "needs camera features, and encoder is none"),
        "camera.yaml": (no_camera, "needs a robot with cameras"),
        "unknown.yaml": (workflow(tmp_path, enc, threshold=0.9), "threshold: unknown field"),
        "audit.yaml": (workflow(tmp_path, enc, audit_every=0), "audit_every: must be >= 1 (got 0)"),
    }
    for name, (spec, line) in cases.items():
        path = tmp_path / name
        path.write_text(yaml.safe_dump(spec))
        result = accrue("stage", "status", str(path), cwd=tmp_path)
        assert result.returncode == 2, (name, result.stderr[-2000:])
        assert "Traceback" not in result.stderr
        [said] = result.stderr.strip().splitlines()
        assert said.startswith(f"error: {path}: robot.success_classifier") and line in said, said


def test_off_keeps_the_keys_and_on_adds_the_output(tmp_path):
    from stages.plan import plan_stage
    from stages.runner_types import FromStep
    from stages.workflow import parse_workflow

    weights = tmp_path / "w.safetensors"
    weights.write_bytes(b"not read for planning beyond its digest")
    enc = f"vit_tiny_patch16_224:{weights}"
    steps = lambda spec: {i.step.name: i for i in plan_stage(parse_workflow(spec, "x"), 1, None).steps}  # noqa: E731
    off, on = steps(workflow(tmp_path, enc)), steps(workflow(tmp_path, enc, enabled=True, auto_label_above=0.9))
    for name in ("warmup", "train", "evaluate-all"):
        assert "success_classifier" not in off[name].config and "success_classifier" not in off[name].step.outputs
    for name in ("warmup", "train"):
        assert on[name].config["success_classifier"]["auto_label_above"] == 0.9
        assert on[name].config["success_classifier"]["audit_every"] == 10  # the default spot check
        assert on[name].step.outputs["success_classifier"] == "success-classifier"
    # train starts from warmup's classifier: a declared input, so in its cache key and lineage; not when off
    assert on["train"].inputs["warmup-classifier"] == FromStep("warmup", "success_classifier")
    assert "warmup-classifier" in on["train"].step.optional_inputs
    assert "warmup-classifier" not in off["train"].inputs and "warmup-classifier" not in on["warmup"].inputs
    for name in ("warmup", "train", "evaluate-all", "handoff"):
        assert {k: v for k, v in on[name].inputs.items() if k != "warmup-classifier"} == off[name].inputs
    assert "success_classifier" not in on["evaluate-all"].step.outputs  # retention trials stay the operator's
