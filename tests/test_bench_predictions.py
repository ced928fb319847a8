"""Predictions a spec declares before its runs: parsed strictly, and each judged holds / contradicted / not
resolved on the paired differences from its own reference."""

from __future__ import annotations

import pytest
import yaml
from test_bench_report import BASE  # tests/ is on sys.path (rootdir conftest, no package)

from stages.bench.claims import Claim, claims_markdown, judge_against
from stages.bench.spec import load_spec
from stages.errors import StageError


def record(method: str, seed: int, fwt: float, f_final: float) -> dict:
    return {
        "method": method,
        "ordering": "S1",
        "seed": seed,
        "tasks": ["a", "b"],
        "metrics": {"FWT": fwt, "F_final": f_final, "FWT_no0": None},
    }


# FWT by seed: accrue 0.5 0.6 0.7; single-task 0.3 0.4 0.45 (accrue higher by 0.2 0.2 0.25);
# beta0 0.5 0.7 0.6 (differences 0 +0.1 −0.1: unresolved); F_final: beta1 below accrue by 0.1 each seed
RECORDS = [
    *(record("accrue", s, f, 0.3) for s, f in enumerate((0.5, 0.6, 0.7))),
    *(record("single-task", s, f, 0.3) for s, f in enumerate((0.3, 0.4, 0.45))),
    *(record("beta0", s, f, 0.3) for s, f in enumerate((0.5, 0.7, 0.6))),
    *(record("beta1", s, 0.5, 0.2) for s in range(3)),
]
METHODS = ["accrue", "single-task", "beta0", "beta1"]


def test_each_verdict_is_reached():
    predictions = [
        Claim("ACCRUE transfers more than Single-task", "FWT", "higher", ("single-task",)),
        Claim("on the bias family ACCRUE does not transfer more", "FWT", "not-higher", ("single-task",)),
        Claim("β = 0 loses FWT", "FWT", "higher", ("beta0",)),
        Claim("β = 1 forgets less than β = 0.1 (accrue)", "F_final", "lower", ("accrue",), reference="beta1"),
        Claim("a figure the runs lack", "FWT_no0", "higher", ("single-task",)),
    ]
    judged = judge_against(predictions, RECORDS, "accrue", METHODS)
    assert [j["verdict"] for j in judged] == ["holds", "contradicted", "not resolved", "holds", "not resolved"]
    assert [j["reference"] for j in judged] == ["accrue", "accrue", "accrue", "beta1", "accrue"]
    d = judged[0]["against"][0]["difference"]  # single-task − accrue: −0.2, −0.2, −0.25
    assert d["mean"] == pytest.approx(-0.65 / 3) and d["n"] == 3
    assert judged[3]["against"][0]["difference"]["mean"] == pytest.approx(0.1)  # accrue − beta1
    assert judged[4]["against"][0]["verdict"] == "no runs"  # undefined for every pair: not judged
    text = claims_markdown(judged, "accrue", what="prediction")
    assert "| prediction | test | vs | Δ (vs − reference) [CI] | verdict | prediction verdict |" in text
    assert "| β = 1 forgets less than β = 0.1 (accrue) | beta1 lower on F_final | accrue |" in text
    assert "**contradicted**" in text and "**not resolved**" in text


PREDICTION = {"prediction": "transfers more", "metric": "FWT_no0", "reference_is": "higher", "than": ["single-task"]}


def spec_file(tmp_path, **fields):
    (tmp_path / "base.yaml").write_text(yaml.safe_dump(BASE))
    data = {
        "base": "base.yaml",
        "methods": {"accrue": {}, "single-task": {}, "beta0": {"method": "accrue", "learner.ablation": "beta0"}},
        "orderings": {"S1": BASE["tasks"]},
        "seeds": [0],
        **fields,
    }
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_predictions_load_with_their_own_reference(tmp_path):
    other = {**PREDICTION, "reference": "beta0", "than": ["accrue"], "reference_is": "lower"}
    spec = load_spec(spec_file(tmp_path, predictions=[PREDICTION, other], success_threshold=0.8))
    assert [p.reference for p in spec.predictions] == ["accrue", "beta0"]
    assert spec.predictions[0].metric == "FWT_no0" and spec.success_threshold == 0.8


@pytest.mark.parametrize(
    "fields, message",
    [
        ({"predictions": [{**PREDICTION, "metric": "SPEED"}]}, r"predictions\[0\].metric: 'SPEED' is not one of"),
        ({"predictions": [{**PREDICTION, "reference": "nobody"}]}, r"predictions\[0\].reference: 'nobody' is not"),
        ({"predictions": [{**PREDICTION, "than": ["accrue"]}]}, r"predictions\[0\].than: .*other than accrue"),
        ({"predictions": [{**PREDICTION, "why": "x"}]}, r"predictions\[0\]: expected exactly the fields"),
        ({"predictions": [{"claim": "x"}]}, r"predictions\[0\]: expected exactly the fields prediction"),
        ({"success_threshold": 0}, r"success_threshold: must be a success rate in \(0, 1\]"),
    ],
)
def test_a_bad_prediction_names_its_field(tmp_path, fields, message):
    with pytest.raises(StageError, match=message):
        load_spec(spec_file(tmp_path, **fields))
