"""workflows/hardware-sim-classifier.yaml end to end on the simulated robot (a seeded tiny ViT in place of the
DINOv2 file, offline): robot.success_classifier proposes and gives labels in warmup and train, each one is
on record in the sealed episode.json, train starts from warmup's labels (its `warmup-classifier` input) and
keeps warmup's held-out episodes held out, spot checks (audit_every) join the held-out set, and the report's
precision and recall are what the sealed episodes and the classifier artifact give when recomputed here.
The train step is interrupted (the operator aborts) and resumed with --continue: every decision after the
resume and the final artifact are those an uninterrupted run makes from the same sealed episodes.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
MODEL = "vit_tiny_patch16_224"
ABORT_AFTER = 3  # train episodes sealed before the interruption


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    import timm
    import torch
    from robot_workflow import cli_report_json, robot_events, run_stage
    from safetensors.torch import save_file

    from artifacts.store import Store
    from stages.errors import StageError

    root = tmp_path_factory.mktemp("classifier")
    torch.manual_seed(0)
    weights = root / "vit_tiny.safetensors"
    save_file(timm.create_model(MODEL, pretrained=False, num_classes=0).state_dict(), str(weights))
    spec = yaml.safe_load((ROOT / "workflows" / "hardware-sim-classifier.yaml").read_text())
    assert spec["robot"]["success_classifier"]["enabled"]
    spec["encoder"] = f"{MODEL}:{weights}"
    spec["robot"]["config"]["calibration_dir"] = str(root / "calib")
    path = root / "hardware-sim-classifier.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    Store.init(root / "store")
    warmup = run_stage(root / "store", path, 1, step="warmup")["warmup"]
    # the train step stops after ABORT_AFTER of its episodes (the operator aborts: a session setting, outside
    # the cache key), and --continue resumes it
    first = 1 + max(int(p.parent.name) for p in materialized(root, warmup.outputs["episodes"], "w0").glob("*/*.json"))
    spec["robot"]["scripted"] = {"abort_before": first + ABORT_AFTER}
    stopped = root / "stopped.yaml"
    stopped.write_text(yaml.safe_dump(spec, sort_keys=False))
    with pytest.raises(StageError, match="aborted by the operator"):
        run_stage(root / "store", stopped, 1, step="train")
    sealed = [e for e in robot_events(root / "store", "robot-episode-sealed") if e["phase"] == "train"]
    assert len(sealed) == ABORT_AFTER
    run_stage(root / "store", path, 1, step="train", mode="continue")
    results = run_stage(root / "store", path, 1)
    assert results["warmup"].cached and results["train"].cached
    return root, results, cli_report_json(root / "store", path, root / "report"), spec["robot"]["success_classifier"]


def materialized(root: Path, artifact: str, name: str) -> Path:
    from artifacts.manifests import materialize
    from artifacts.store import Store

    dest = root / "out" / f"{name}-{artifact[:12]}"
    return dest if dest.is_dir() else materialize(Store.open(root / "store"), artifact, dest)


HELD_OUT = ("held-out", "audit")


def sealed(root: Path, results, step: str) -> list[dict]:
    out = results[step].outputs["episodes"]
    eps = [json.loads(p.read_text()) for p in materialized(root, out, f"ep-{step}").glob("*/episode.json")]
    return sorted((e for e in eps if e["phase"] == step), key=lambda e: e["index"])


def classifier_of(root: Path, results, step: str) -> tuple[dict, np.ndarray]:
    artifact = materialized(root, results[step].outputs["success_classifier"], f"cls-{step}")
    return json.loads((artifact / "classifier.json").read_text()), np.load(artifact / "inputs.npy")


def recompute(episodes: dict[str, list[dict]], data: dict, inputs: np.ndarray, step: str) -> dict:
    """The report's figures from the sealed episode records (warmup's, and train's for train) and the
    classifier's own weights and inputs."""
    from accrue.robot.success_classifier import Model, scores

    p = Model.from_json(data["model"]).predict(inputs)
    by_key = {(phase, e["index"]): e for phase, eps in episodes.items() for e in eps}
    order = [(r["phase"], r["index"]) for r in data["episodes"]]
    phases = ("warmup",) if step == "warmup" else ("warmup", "train")
    assert order == [(ph, e["index"]) for ph in phases for e in episodes[ph] if "classifier" in e]
    for r in data["episodes"]:  # warmup's labels as sealed, carried into train unchanged
        assert r["label"] == by_key[r["phase"], r["index"]]["label"]["success"]
        assert r["mode"] == by_key[r["phase"], r["index"]]["classifier"]["mode"]
    held = [(by_key[k], q) for k, q in zip(order, p) if by_key[k]["classifier"]["mode"] in HELD_OUT]
    pred = [q >= 0.5 for _, q in held]
    auto = [e for e in episodes[step] if e["label"]["by"] == "classifier"]
    return {
        "held_out_vs_operator": scores(pred, [e["label"]["success"] for e, _ in held]),
        "held_out_vs_simulator": scores(pred, [e["sim_success"] for e, _ in held]),
        "auto_labels_vs_simulator": scores([e["label"]["success"] for e in auto], [e["sim_success"] for e in auto]),
    }


@pytest.mark.parametrize("step", ["warmup", "train"])
def test_the_report_holds_precision_and_recall_recomputed_from_the_sealed_episodes(run, step):
    root, results, summary, _ = run
    episodes = {ph: sealed(root, results, ph) for ph in ("warmup", "train")}
    data, inputs = classifier_of(root, results, step)
    reported = summary["success_classifier"]["1"][step]
    want = recompute(episodes, data, inputs, step)
    for name, figures in want.items():
        if figures["episodes"]:
            assert {k: reported[name][k] for k in figures} == figures, name
    assert Path(summary["files"]["success_classifier"]).read_text().count("| 1 | " + step) >= 2
    if step == "train":  # warmup's held-out episodes and train's own and spot checks: figures defined
        held = reported["held_out_vs_operator"]
        assert held["precision"] is not None and held["recall"] is not None, held
        assert held["tp"] + held["fn"] >= 1 and held["fp"] + held["tn"] >= 1, held  # both outcomes
        assert reported["labels"].get("audit", 0) >= 1 and reported["carried_labels"]["held-out"] >= 1
    else:
        assert reported["held_out_vs_operator"]["episodes"] >= 1


def test_train_starts_from_warmups_labels_and_keeps_its_held_out_episodes_out(run):
    """Train's artifact carries warmup's (its declared `warmup-classifier` input: in its cache key and
    lineage) rows and labels unchanged; it trains on warmup's trainable labels from its first episode, never
    on a held-out or audited one; nothing of another stage is carried."""
    from artifacts.store import Store

    root, results, _, settings = run
    warm, warm_rows = classifier_of(root, results, "warmup")
    train, train_rows = classifier_of(root, results, "train")
    record = Store.open(root / "store").read_json(results["train"].record_id)
    assert record["inputs"]["warmup-classifier"] == results["warmup"].outputs["success_classifier"]
    assert train["carried"] == {"from": results["warmup"].outputs["success_classifier"], "episodes": len(warm_rows)}
    assert warm["carried"] is None and "carried_labels" not in warm["metrics"]
    n = len(warm_rows)
    np.testing.assert_array_equal(train_rows[:n], warm_rows)
    assert [(r["phase"], r["index"], r["mode"], r["label"]) for r in train["episodes"][:n]] == [
        ("warmup", r["index"], r["mode"], r["label"]) for r in warm["episodes"]
    ]
    trainable = [
        ["warmup", r["index"]] for r in warm["episodes"] if r["mode"] not in HELD_OUT and r["label_by"] == "dry-run"
    ]
    assert train["trained_on"][: len(trainable)] == trainable
    first = next(e for e in sealed(root, results, "train") if "classifier" in e)
    assert first["classifier"]["trained_on"] >= len(trainable) >= settings["min_labels"]  # taught in warmup
    modes = {(r["phase"], r["index"]): r["mode"] for r in train["episodes"]}
    assert all(modes[tuple(k)] not in (*HELD_OUT, "auto") for k in train["trained_on"])


def test_a_resumed_train_step_decides_as_an_uninterrupted_one(run):
    """After the interruption and --continue, each train episode's classifier entry (mode, p, trained_on) is
    what a gate that ran uninterrupted from warmup's artifact decides over the same sealed episodes, and the
    final model is the one fitted afresh on its training rows."""
    from accrue.robot.operator import Label
    from accrue.robot.success_classifier import ClassifierSettings, Model, fit
    from stages.steps.robot_classifier import ClassifierGate

    root, results, _, settings = run
    warm_dir = materialized(root, results["warmup"].outputs["success_classifier"], "replay-warm")
    train, rows = classifier_of(root, results, "train")
    episodes = sealed(root, results, "train")
    sessions = json.loads(
        next(materialized(root, results["train"].outputs["episodes"], "replay-eps").rglob("sessions.json")).read_text()
    )
    assert len(sessions) == 2 and sessions[0]["ended"] == "aborted by the operator"
    row_of = {r["index"]: x for r, x in zip(train["episodes"], rows) if r["phase"] == "train"}

    class Seen:  # the sealed episodes before the one being decided
        def __init__(self):
            self.before: list[dict] = []

        def ordered(self, phase=None):
            return [e for e in self.before if phase is None or e["phase"] == phase]

        def arrays(self, index):
            return {"s": row_of[index][None]}

    class Recorded:  # the operator's sealed answer
        def __init__(self, e):
            self.label_ = Label(**{k: e["label"][k] for k in ("success", "by", "at", "note", "via")})

        def label(self, index, summary):
            return self.label_

        def label_proposed(self, index, summary, success, p):
            return self.label_

        def tell(self, line):
            pass

    seen = Seen()
    gate = ClassifierGate(ClassifierSettings.from_dict(settings), seen, train["inputs"]["encoder"], "train")
    gate.carry(warm_dir, results["warmup"].outputs["success_classifier"])
    gate.image_width, gate.state_width = train["inputs"]["image_width"], train["inputs"]["state_width"]
    decided = 0
    for e in episodes:
        if "classifier" in e:
            _, entry = gate.label(e["index"], "replay", row_of[e["index"]], Recorded(e))
            assert entry["mode"] == e["classifier"]["mode"] and entry["trained_on"] == e["classifier"]["trained_on"]
            if entry["p"] is None:
                assert e["classifier"]["p"] is None
            else:
                assert entry["p"] == pytest.approx(e["classifier"]["p"], abs=2e-6)
            decided += 1
        seen.before.append(e)
    assert decided > ABORT_AFTER  # decisions on both sides of the interruption
    gate.refresh()
    assert gate.trained_on == train["trained_on"]
    where = {(r["phase"], r["index"]): x for r, x in zip(train["episodes"], rows)}
    labels = {(r["phase"], r["index"]): r["label"] for r in train["episodes"]}
    keys = [tuple(k) for k in train["trained_on"]]
    again = fit(np.stack([where[k] for k in keys]), np.array([labels[k] for k in keys]))
    model = Model.from_json(train["model"])
    np.testing.assert_allclose(again.predict(rows), model.predict(rows), atol=1e-6)


def test_every_label_says_who_gave_it_and_the_classifier_trains_on_operator_labels_only(run):
    root, results, _, settings = run
    seen = set()
    episodes = {ph: sealed(root, results, ph) for ph in ("warmup", "train")}
    by_key = {(ph, e["index"]): e for ph, eps in episodes.items() for e in eps}
    for step in ("warmup", "train"):
        data, _ = classifier_of(root, results, step)
        for e in episodes[step]:
            if "classifier" not in e:  # a fault ended it: labelled by "system", never judged
                assert e["label"]["by"] == "system"
                continue
            c, label = e["classifier"], e["label"]
            seen.add(c["mode"])
            assert isinstance(e["sim_success"], bool)  # the simulated robot's own outcome, for the audit
            if c["mode"] == "auto":
                assert label["by"] == "classifier" and label["via"] == "classifier"
                assert max(c["p"], 1 - c["p"]) > settings["auto_label_above"] and f"{c['p']:.6f}" in label["note"]
                assert label["success"] == (c["p"] >= 0.5)
            else:
                assert label["by"] == "dry-run"
                if c["mode"] == "proposed":
                    assert label["via"] == "scripted+classifier-proposal" and "classifier proposed" in label["note"]
                    assert max(c["p"], 1 - c["p"]) <= settings["auto_label_above"]
                elif c["mode"] == "audit":  # it was sure, the operator labelled it blind anyway
                    assert label["via"] == "scripted" and max(c["p"], 1 - c["p"]) > settings["auto_label_above"]
                else:
                    assert label["via"] == "scripted" and c["p"] is None
        trained = [by_key[tuple(k)] for k in data["trained_on"]]
        assert len(trained) >= settings["min_labels"]
        assert all(e["classifier"]["mode"] in ("untrained", "proposed", "operator") for e in trained)
        assert all(e["label"]["by"] == "dry-run" for e in trained)
    assert {"untrained", "held-out", "audit"} <= seen and seen & {"auto", "proposed"}
