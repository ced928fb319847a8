"""workflows/hardware-sim-classifier.yaml end to end on the simulated robot (a seeded tiny ViT in place of the
DINOv2 file, offline): robot.success_classifier proposes and gives labels in warmup and train, each one is
on record in the sealed episode.json, and the report's precision and recall are what the sealed episodes
and the classifier artifact give when recomputed here."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
MODEL = "vit_tiny_patch16_224"


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    import timm
    import torch
    from robot_workflow import run_stage
    from safetensors.torch import save_file

    from artifacts.store import Store

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
    results = run_stage(root / "store", path, 1)
    env = {**os.environ, "ACCRUE_STORE": str(root / "store"), "PYTHONPATH": str(ROOT), "HF_HUB_OFFLINE": "1"}
    report = subprocess.run(
        [sys.executable, "-m", "cli.main", "report", str(path), "--out", str(root / "report"), "--json"],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert report.returncode == 0, report.stderr[-2000:]
    return root, results, json.loads(report.stdout), spec["robot"]["success_classifier"]


def materialized(root: Path, artifact: str, name: str) -> Path:
    from artifacts.manifests import materialize
    from artifacts.store import Store

    return materialize(Store.open(root / "store"), artifact, root / "out" / name)


def recompute(episodes: list[dict], artifact: Path) -> dict:
    """The report's figures from the sealed episode records and the classifier's own weights and inputs."""
    from accrue.robot.success_classifier import Model, scores

    data = json.loads((artifact / "classifier.json").read_text())
    p = Model.from_json(data["model"]).predict(np.load(artifact / "inputs.npy"))
    by_index = {e["index"]: e for e in episodes}
    assert [r["index"] for r in data["episodes"]] == sorted(i for i, e in by_index.items() if "classifier" in e)
    held = [
        (by_index[r["index"]], q)
        for r, q in zip(data["episodes"], p)
        if by_index[r["index"]]["classifier"]["mode"] == "held-out"
    ]
    pred = [q >= 0.5 for _, q in held]
    auto = [e for e in episodes if e["label"]["by"] == "classifier"]
    return {
        "held_out_vs_operator": scores(pred, [e["label"]["success"] for e, _ in held]),
        "held_out_vs_simulator": scores(pred, [e["sim_success"] for e, _ in held]),
        "auto_labels_vs_simulator": scores([e["label"]["success"] for e in auto], [e["sim_success"] for e in auto]),
    }


@pytest.mark.parametrize("step", ["warmup", "train"])
def test_the_report_holds_precision_and_recall_recomputed_from_the_sealed_episodes(run, step):
    root, results, summary, _ = run
    out = results[step].outputs
    episodes = [
        json.loads(p.read_text())
        for p in sorted(materialized(root, out["episodes"], f"ep-{step}").glob("*/episode.json"))
    ]
    artifact = materialized(root, out["success_classifier"], f"cls-{step}")
    reported = summary["success_classifier"]["1"][step]
    want = recompute([e for e in episodes if e["phase"] == step], artifact)
    for name, figures in want.items():
        if figures["episodes"]:
            assert {k: reported[name][k] for k in figures} == figures, name
    assert reported["held_out_vs_operator"]["episodes"] >= 1
    assert Path(summary["files"]["success_classifier"]).read_text().count("| 1 | " + step) >= 2


def test_every_label_says_who_gave_it_and_the_classifier_trains_on_operator_labels_only(run):
    root, results, _, settings = run
    seen = set()
    for step in ("warmup", "train"):
        eps = [
            json.loads(p.read_text())
            for p in materialized(root, results[step].outputs["episodes"], f"ep2-{step}").glob("*/episode.json")
        ]
        data = json.loads(
            (
                materialized(root, results[step].outputs["success_classifier"], f"cls2-{step}") / "classifier.json"
            ).read_text()
        )
        by_index = {e["index"]: e for e in eps}
        for e in eps:
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
                else:
                    assert label["via"] == "scripted" and c["p"] is None
        trained = [by_index[i] for i in data["trained_on"]]
        assert len(trained) >= settings["min_labels"]
        assert all(
            e["classifier"]["mode"] not in ("held-out", "auto") and e["label"]["by"] == "dry-run" for e in trained
        )
    assert {"untrained", "held-out"} <= seen and seen & {"auto", "proposed"}
