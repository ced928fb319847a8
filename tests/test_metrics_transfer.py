"""Issue 18's protocol figures against hand-computed values: FWT without step 0, jumpstart, env steps to a
success threshold, IQM, and the best checkpoint chosen on one episode set but scored on another."""

import pytest

from accrue.errors import AccrueError
from accrue.metrics import (
    aggregate_runs,
    continual_metrics,
    iqm,
    paired_differences,
    run_record,
    summarize_iqm,
    summarize_values,
)

CURVES = [  # the selection set (the same table as test_metrics_continual)
    [[0.2, 0.8, 0.8, 0.5]],  # e* = 1
    [[0.9, 0.6, 0.3, 0.1], [0.1, 0.7, 0.4, 0.7]],  # e* = 1
    [[0.5, 0.4, 0.2, 0.0], [0.3, 0.2, 0.6, 0.1], [0.0, 0.3, 0.9, 0.9]],  # e* = 2
]
GRID = [0, 1000, 2000, 3000]
# the same checkpoints on disjoint episodes: half the selection values, except stage 1's own curve,
# whose maximum (0.9 at e = 2) is not at the checkpoint the selection set chose (e = 1)
REPORT = [[[round(v / 2, 3) for v in curve] for curve in stage] for stage in CURVES]
REPORT[0][0] = [0.1, 0.4, 0.9, 0.25]


def test_fwt_without_step_0_and_jumpstart_by_hand():
    m = continual_metrics(CURVES)
    # own curves without e = 0: (0.8+0.8+0.5)/3 = 0.7, (0.7+0.4+0.7)/3 = 0.6, (0.3+0.9+0.9)/3 = 0.7
    assert m["per_stage"]["FWT_no0"] == pytest.approx([0.7, 0.6, 0.7])
    assert m["FWT_no0"] == pytest.approx(2 / 3)
    assert m["per_stage"]["jumpstart"] == [0.2, 0.1, 0.0]
    assert m["jumpstart"] == pytest.approx(0.1)
    assert m["FWT"] == pytest.approx(0.525)  # unchanged: with step 0
    assert continual_metrics([[[0.4]]])["FWT_no0"] is None  # a one-point grid has nothing after step 0


def test_steps_to_threshold_by_hand():
    m = continual_metrics(CURVES, grids=[GRID] * 3, threshold=0.5)
    # first point >= 0.5: stage 1 at 1000 (0.8), stage 2 at 1000 (0.7), stage 3 at 2000 (0.9)
    assert m["per_stage"]["T_thr"] == [1000.0, 1000.0, 2000.0]
    assert m["T_thr"] == pytest.approx(4000 / 3)
    high = continual_metrics(CURVES, grids=[GRID] * 3, threshold=0.85)
    # stages 1 and 2 never reach 0.85: counted at their budget (3000), a lower bound
    assert high["per_stage"]["T_thr"] == [3000.0, 3000.0, 2000.0]
    assert high["per_stage"]["T_thr_reached"] == [False, False, True]
    assert high["T_thr"] == pytest.approx(8000 / 3)
    assert continual_metrics(CURVES)["T_thr"] is None  # no grids: undefined, never guessed


def test_iqm_by_hand():
    assert iqm([4, 1, 3, 2]) == 2.5  # drop 1 and 4
    assert iqm([100, 0, 1, 2, 3, 4, 7, 8]) == 4.0  # drop 0, 1 and 8, 100: mean(2, 3, 4, 7)
    assert iqm([1, 2, 50, 3, 4]) == 3.0  # floor(5/4) = 1 from each end
    assert iqm([0.2, 0.9]) == pytest.approx(0.55)  # fewer than 4 values: nothing dropped
    s = summarize_iqm([1, 2, 3, 4, 5, 6, 7, 1000])
    assert s["mean"] == 4.5 and s["n"] == 8  # the outlier moves the mean (128.5), not the IQM
    assert s["ci_low"] <= s["mean"] <= s["ci_high"] < 1000
    assert summarize_iqm([None, 0.3, 0.3]) == {"mean": 0.3, "ci_low": 0.3, "ci_high": 0.3, "n": 2, "undefined": 1}
    with pytest.raises(AccrueError):
        iqm([])


def test_best_checkpoint_is_chosen_on_selection_and_scored_on_report():
    m = continual_metrics(CURVES, REPORT)
    assert m["best_checkpoint"] == [1, 1, 2]  # chosen on the selection set
    assert m["disjoint_report"] is True
    # c_{1,1} = REPORT[0][0][1] = 0.4, not the report set's own maximum 0.9 nor the selection's 0.8
    assert m["c"][0][0] == 0.4
    assert m["c"][1] == [0.3, 0.35, None]  # REPORT[1][j][1]
    assert m["c"][2] == [0.1, 0.3, 0.45]  # REPORT[2][j][2]
    assert m["FWT"] == pytest.approx((0.4125 + 0.2375 + 0.2625) / 3)  # means of the report's own curves
    assert m["F_final"] == pytest.approx(((0.4 - 0.1) + (0.35 - 0.3)) / 2)
    same = continual_metrics(CURVES)
    assert same["disjoint_report"] is False and same["c"][0][0] == 0.8


def test_report_curves_must_score_the_same_checkpoints():
    with pytest.raises(AccrueError, match="same checkpoints"):
        continual_metrics(CURVES, [[[0.1, 0.2]], [[0.1, 0.2], [0.3, 0.4]], [[0.1, 0.2]] * 3])


def test_records_without_the_new_metrics_aggregate_as_undefined():
    """A run stored before the transfer figures (its record lacks them) is counted as undefined, so an
    old report still builds and prints '—' there."""
    new = run_record(CURVES, method="accrue", tasks=["a", "b", "c"], seed=0, grids=[GRID] * 3)
    old = {**new, "seed": 1, "metrics": {k: new["metrics"][k] for k in ("FWT", "NBT", "AUC", "ACC_final", "F_final")}}
    agg = aggregate_runs([new, old])["methods"][0]
    assert agg["metrics"]["FWT"]["n"] == 2
    assert agg["metrics"]["FWT_no0"] == summarize_values([2 / 3, None])
    assert agg["iqm"]["T_thr"]["n"] == 1 and agg["iqm"]["T_thr"]["undefined"] == 1
    ref = {**old, "method": "single-task", "seed": 1}
    d = paired_differences([old, ref], "accrue")[0]
    assert d["metrics"]["jumpstart"]["mean"] is None and d["metrics"]["FWT"]["mean"] == 0.0
