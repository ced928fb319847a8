"""Sec. V-A metrics against a hand-computed table (with ties in the maximum), bootstrap CIs, and the CLI."""

import json
import subprocess
import sys

import pytest
import typer
from typer.testing import CliRunner

from accrue.errors import AccrueError
from accrue.metrics import aggregate, bootstrap_ci, continual_metrics, load_metrics_file, success_matrix
from cli.metrics_cmds import register

CURVES = [
    [[0.2, 0.8, 0.8, 0.5]],  # max 0.8 at e = 1 and 2 → e* = 1
    [[0.9, 0.6, 0.3, 0.1], [0.1, 0.7, 0.4, 0.7]],  # max 0.7 at e = 1 and 3 → e* = 1
    [[0.5, 0.4, 0.2, 0.0], [0.3, 0.2, 0.6, 0.1], [0.0, 0.3, 0.9, 0.9]],  # max 0.9 at e = 2 and 3 → e* = 2
]
RUN = {"tasks": ["peg", "gear", "nut"], "grid": [0, 1000, 2000, 3000], "curves": CURVES}


def test_success_matrix_uses_earliest_maximum():
    c, best = success_matrix(CURVES)
    assert best == [1, 1, 2]
    assert c[1, 0] == 0.6  # the latest maximiser (e = 3) would give 0.1
    assert c[2].tolist() == [0.2, 0.6, 0.9]


def test_metrics_match_hand_computed_table():
    m = continual_metrics(CURVES)
    # FWT_k = 0.575, 0.475, 0.525
    assert m["per_stage"]["FWT"] == pytest.approx([0.575, 0.475, 0.525])
    assert m["FWT"] == pytest.approx(0.525)
    # NBT_0 = ((0.8 − 0.6) + (0.8 − 0.2)) / 2 = 0.4;  NBT_1 = 0.7 − 0.6 = 0.1
    assert m["per_stage"]["NBT"] == pytest.approx([0.4, 0.1])
    assert m["NBT"] == pytest.approx(0.25)
    # AUC_0 = (0.575 + 0.6 + 0.2)/3, AUC_1 = (0.475 + 0.6)/2, AUC_2 = 0.525
    assert m["per_stage"]["AUC"] == pytest.approx([1.375 / 3, 0.5375, 0.525])
    assert m["AUC"] == pytest.approx((1.375 / 3 + 0.5375 + 0.525) / 3)
    assert m["ACC_final"] == pytest.approx((0.2 + 0.6 + 0.9) / 3)
    assert m["F_final"] == pytest.approx(((0.8 - 0.2) + (0.7 - 0.6)) / 2)


def test_single_stage_has_no_backward_metrics():
    m = continual_metrics([[[0.0, 1.0]]])
    assert m["FWT"] == 0.5 and m["AUC"] == 0.5 and m["ACC_final"] == 1.0
    assert m["NBT"] is None and m["F_final"] is None


def test_bad_curves_raise_one_line_errors():
    with pytest.raises(AccrueError, match=r"curves\[1\]"):
        continual_metrics([[[0.1]], [[0.1]]])  # stage 1 must list 2 tasks
    with pytest.raises(AccrueError, match=r"curves\[0\]\[0\]\[1\]"):
        continual_metrics([[[0.1, 1.5]]])
    with pytest.raises(AccrueError, match="evaluation points"):
        continual_metrics([[[0.1, 0.2]], [[0.1], [0.3]]])


def test_seed_aggregation_and_bootstrap():
    shifted = [[[min(1.0, v + 0.1) for v in curve] for curve in stage] for stage in CURVES]
    agg = aggregate([CURVES, shifted])
    single = [continual_metrics(CURVES)["FWT"], continual_metrics(shifted)["FWT"]]
    assert agg["metrics"]["FWT"]["mean"] == pytest.approx(sum(single) / 2)
    lo, hi = agg["metrics"]["FWT"]["ci_low"], agg["metrics"]["FWT"]["ci_high"]
    assert min(single) <= lo <= hi <= max(single) and lo < hi
    vals = [0.1, 0.5, 0.9, 0.4, 0.6]
    assert bootstrap_ci(vals) == bootstrap_ci(vals)  # seeded
    lo, hi = bootstrap_ci(vals)
    assert lo < sum(vals) / 5 < hi
    assert bootstrap_ci([0.3]) == (0.3, 0.3)


def test_bootstrap_ci_against_hand_computed_percentiles():
    """Mutation bootstrap-ci-wrong (the test above compares bootstrap_ci with itself). For runs
    [0, 0, 0, 1] a resampled mean is K/4 with K ~ Binomial(4, 1/4): P(K <= 0, 1, 2, 3) = 0.316, 0.738,
    0.949, 0.996. So the 95% interval's ends are the 2.5% and 97.5% quantiles, 0 and 3/4; the 80%
    interval's are 0 and 1/2 (each 4+ standard errors of 4000 resamples away from a mass boundary)."""
    assert bootstrap_ci([0.0, 0.0, 0.0, 1.0]) == (0.0, 0.75)
    assert bootstrap_ci([0.0, 0.0, 0.0, 1.0], confidence=0.8) == (0.0, 0.5)
    assert bootstrap_ci([0.0, 0.0, 0.0, 1.0], confidence=0.6) == (0.0, 0.5)  # 20% and 80%, not 40% and 60%
    # [0, 1]: the mean of two draws is 0, 1/2 or 1 with probability 1/4, 1/2, 1/4
    assert bootstrap_ci([0.0, 1.0]) == (0.0, 1.0)
    assert bootstrap_ci([0.0, 1.0], confidence=0.4) == (0.5, 0.5)


def app() -> typer.Typer:
    a = typer.Typer()

    @a.callback()
    def _root():
        pass

    register(a)
    return a


def test_cli_json_and_table(tmp_path):
    f = tmp_path / "run.json"
    f.write_text(json.dumps([RUN, RUN]))
    res = CliRunner().invoke(app(), ["metrics", str(f), "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    [group] = out["methods"]
    assert group["metrics"]["NBT"]["mean"] == pytest.approx(0.25) and group["metrics"]["NBT"]["n"] == 2
    assert group["metrics"]["NBT"]["ci_low"] == group["metrics"]["NBT"]["ci_high"] == 0.25  # identical runs
    f.write_text(json.dumps(RUN))
    res = CliRunner().invoke(app(), ["metrics", str(f)])
    assert res.exit_code == 0 and "NBT" in res.output and "0.250" in res.output and "gear" in res.output


@pytest.mark.parametrize(
    "content,message",
    [
        ("{not json", "not valid JSON"),
        (json.dumps({"tasks": ["a"], "grid": [0]}), "missing field 'curves'"),
        (json.dumps({"tasks": ["a", "b"], "grid": [0], "curves": [[[0.5]]]}), "1 stages in 'curves' but 2 tasks"),
        (json.dumps({"tasks": ["a"], "grid": [0, 1], "curves": [[[0.5]]]}), "'grid' has 2"),
    ],
)
def test_malformed_file_messages(tmp_path, content, message):
    f = tmp_path / "bad.json"
    f.write_text(content)
    with pytest.raises(AccrueError, match=message):
        load_metrics_file(f)


def test_cli_malformed_file_is_one_line_exit_2(tmp_path):
    f = tmp_path / "bad.json"
    f.write_text('{"tasks": ["a"], "grid": [0], "curves": [[[2.0]]]}')
    res = subprocess.run(
        [sys.executable, "-c", "from cli.main import main; main()", "metrics", str(f)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 2
    assert res.stderr.startswith("error: ") and res.stderr.count("\n") == 1 and "curves[0][0][0]" in res.stderr
