"""Tests written to kill mutants of accrue/metrics.py that survived mutmut's second sweep (docs/MUTATION.md).

Each test's docstring names the mutmut ids it kills; every expected value is computed by hand.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from accrue.errors import AccrueError
from accrue.metrics import (
    aggregate,
    aggregate_runs,
    bootstrap_ci,
    continual_metrics,
    load_metrics_file,
    paired_differences,
    run_record,
    steps_to_threshold,
    summarize_iqm,
    summarize_values,
)

ONE = [[[0.2, 0.6]]]  # one stage, two points: FWT 0.4, e* = 1
TWO = [[[0.2, 0.6]], [[0.4, 0.3], [0.1, 0.5]]]  # e* = (1, 1): c = [[0.6], [0.3, 0.5]]


def record(method, seed, fwt, ordering="o", nbt=None):
    """A labelled run with only the metrics paired_differences reads (others undefined)."""
    return {"method": method, "ordering": ordering, "seed": seed, "tasks": ["a"], "metrics": {"FWT": fwt, "NBT": nbt}}


def test_aggregate_names_its_fields():
    """Survivors aggregate 7-12: the result's keys are runs, confidence (0.95) and resamples (4000)."""
    got = aggregate([ONE, ONE])
    assert set(got) == {"metrics", "runs", "confidence", "resamples"}
    assert got["confidence"] == 0.95 and got["resamples"] == 4000
    assert got["runs"] == [continual_metrics(ONE)] * 2
    assert got["metrics"]["FWT"]["mean"] == pytest.approx(0.4)


def test_steps_to_threshold_counts_a_point_at_the_threshold_and_names_the_lengths():
    """Survivors steps_to_threshold 2 (the message), 7 (≥, not >)."""
    assert steps_to_threshold([0.2, 0.5, 0.9], [0, 10, 20], 0.5) == (10.0, True)
    assert steps_to_threshold([0.2, 0.4], [0, 10], 0.5) == (10.0, False)
    with pytest.raises(AccrueError, match=r"^grid has 3 points but the curve 2$"):
        steps_to_threshold([0.2, 0.4], [0, 10, 20], 0.5)


def test_run_record_passes_report_and_threshold_and_names_its_fields():
    """Survivors run_record 3 (report dropped), 9 (threshold dropped), 11 (message), 29-30 ("c"),
    37-38 ("disjoint_report")."""
    report = [[[0.1, 0.3]], [[0.2, 0.4], [0.3, 0.7]]]
    grids = [[0, 100], [0, 100]]
    r = run_record(TWO, method="m", tasks=["a", "b"], report=report, grids=grids, threshold=0.3)
    # e* chosen on TWO (1, 1), values read from report: c = [[0.3], [0.4, 0.7]]
    assert r["c"] == [[0.3, None], [0.4, 0.7]]
    assert r["disjoint_report"] is True
    assert r["metrics"]["FWT"] == pytest.approx((0.2 + 0.5) / 2)  # report's own curves: 0.2, 0.5
    # threshold 0.3 on the report's own curves [0.1, 0.3] and [0.3, 0.7]: reached at 100 and at 0
    assert r["per_stage"]["T_thr"] == [100.0, 0.0]
    assert r["metrics"]["T_thr"] == 50.0
    plain = run_record(TWO, method="m", tasks=["a", "b"])
    assert plain["disjoint_report"] is False and plain["c"] == [[0.6, None], [0.3, 0.5]]
    with pytest.raises(AccrueError, match=r"^run of m: 2 stages of curves but 1 tasks$"):
        run_record(TWO, method="m", tasks=["a"])


def test_aggregate_runs_counts_each_orderings_runs_and_names_the_bootstrap_seed():
    """Survivors aggregate_runs 70-71 (an ordering's "runs"), 86 (bootstrap_seed 0)."""
    a = run_record(ONE, method="m", tasks=["a"], ordering="x", seed=0)
    b = run_record(ONE, method="m", tasks=["a"], ordering="x", seed=1)
    c = run_record(ONE, method="m", tasks=["b"], ordering="y", seed=0)
    got = aggregate_runs([a, b, c])
    assert got["bootstrap_seed"] == 0
    (m,) = got["methods"]
    assert m["runs"] == 3
    assert [(o["ordering"], o["runs"], o["seeds"]) for o in m["orderings"]] == [("x", 2, [0, 1]), ("y", 1, [0])]


def test_paired_differences_pairs_each_method_with_the_reference_by_ordering_and_seed():
    """Survivors paired_differences 8, 17 (which side is the reference), 23, 26 (a pair is the same
    method at a shared (ordering, seed)), 36 (either side undefined -> undefined), 53-56 (field names)."""
    records = [
        record("ref", 0, 0.5, nbt=0.1),
        record("ref", 1, 0.2, nbt=None),
        record("m", 0, 0.75, nbt=0.4),  # pairs with ref seed 0: FWT +0.25, NBT +0.3
        record("m", 1, 0.4, nbt=0.2),  # pairs with ref seed 1: FWT +0.2, NBT undefined (the ref's is None)
        record("m", 2, 0.9),  # no ref at seed 2: no pair
        record("other", 0, 0.1, ordering="elsewhere"),  # no ref in that ordering
    ]
    got = paired_differences(records, "ref")
    assert [set(d) for d in got] == [{"method", "pairs", "metrics"}] * 2
    assert [(d["method"], d["pairs"]) for d in got] == [("m", 2), ("other", 0)]
    m = got[0]["metrics"]
    assert m["FWT"] == summarize_values([0.75 - 0.5, 0.4 - 0.2])
    assert m["NBT"] == summarize_values([0.4 - 0.1, None])
    assert m["NBT"]["undefined"] == 1 and m["NBT"]["mean"] == pytest.approx(0.3)
    assert got[1]["metrics"]["FWT"]["n"] == 0


def write(tmp_path, data, name="m.json"):
    path = tmp_path / name
    path.write_text(json.dumps(data))
    return path


RUN = {"tasks": ["a"], "grid": [0, 10], "curves": [[[0.1, 0.2]]]}


@pytest.mark.parametrize(
    "data, message",
    [
        ([], "{p}: empty list of runs"),
        ([RUN, 3], "{p}: run 1: expected an object with tasks, grid, curves"),
        ({**RUN, "tasks": "a"}, "{p}: 'tasks' must be a list of names"),
        ([RUN, {**RUN, "tasks": [1]}], "{p}: run 1: 'tasks' must be a list of names"),
        ({**RUN, "grid": 5}, "{p}: 'grid' must be a list of env-step counts"),
        ({**RUN, "grid": [0, True]}, "{p}: 'grid' must be a list of env-step counts"),
        ({**RUN, "grid": [0, "10"]}, "{p}: 'grid' must be a list of env-step counts"),
        ({**RUN, "curves": [[[0.1, 2.0]]]}, "{p}: curves[0][0][1]: success rate must be a number in [0, 1], got 2.0"),
        ({**RUN, "ordering": ""}, "{p}: 'ordering' must be a non-empty name"),
        ({**RUN, "method": 3}, "{p}: 'method' must be a non-empty name"),
    ],
)
def test_load_metrics_file_names_the_file_the_run_and_the_field(tmp_path, data, message):
    """Survivors load_metrics_file 12, 15-17 (`path: run r` only for a list), 19, 28, 34, 35, 39, 43, 47,
    54-55: each problem is one line naming the file, the run (in a list) and the field."""
    path = write(tmp_path, data)
    with pytest.raises(AccrueError) as exc:
        load_metrics_file(path)
    assert str(exc.value) == message.format(p=path)


def test_load_metrics_file_unreadable_files_are_one_line(tmp_path):
    """Survivors load_metrics_file 5 (no such file), 7 (cannot read)."""
    missing = tmp_path / "none.json"
    with pytest.raises(AccrueError, match=r"none\.json: no such file$"):
        load_metrics_file(missing)
    with pytest.raises(AccrueError, match=r"^" + str(tmp_path) + r": cannot read \("):
        load_metrics_file(tmp_path)  # a directory: IsADirectoryError, an OSError
    binary = tmp_path / "bin.json"
    binary.write_bytes(b"\xff\xfe\x00")
    with pytest.raises(AccrueError, match=r"bin\.json: cannot read \("):
        load_metrics_file(binary)


@pytest.mark.parametrize(
    "curves, message",
    [
        ([], "curves: expected a non-empty list (one entry per stage)"),
        ("x", "curves: expected a non-empty list (one entry per stage)"),
        ([[[0.1]], [[0.1]]], "curves[1]: stage 1 must list tasks 0..1 (2 curves), got 1"),
        ([[[0.1]], {"a": 1}], "curves[1]: stage 1 must list tasks 0..1 (2 curves), got dict"),
        ([[[]]], "curves[0][0]: expected a non-empty list of success rates"),
        ([[0.5]], "curves[0][0]: expected a non-empty list of success rates"),
        ([[[0.1, True]]], "curves[0][0][1]: success rate must be a number in [0, 1], got True"),
        ([[[0.1]], [[0.1, 0.2], [0.3]]], "curves[1][0]: has 2 evaluation points, expected 1"),
    ],
)
def test_check_curves_messages(curves, message):
    """Survivors _check_curves 1, 4-6, 15-19, 21, 24, 31: the exact one-line message of each malformed table
    (a bool is not a success rate)."""
    with pytest.raises(AccrueError) as exc:
        continual_metrics(curves)
    assert str(exc.value) == message


def test_two_point_curves_have_fwt_no0_and_two_stages_have_f_final():
    """Survivors continual_metrics 53 (FWT_no0 needs > 1 point, not > 2), 108 (F_final for K = 2),
    60 (the grids message), 157-158 ("threshold")."""
    m = continual_metrics(TWO, threshold=0.3)
    assert m["per_stage"]["FWT_no0"] == [0.6, 0.5] and m["FWT_no0"] == pytest.approx(0.55)
    assert m["F_final"] == pytest.approx(0.6 - 0.3)
    assert m["threshold"] == 0.3
    with pytest.raises(AccrueError) as exc:
        continual_metrics(TWO, grids=[[0, 1]])
    assert str(exc.value) == "grids: 1 stage grids for 2 stages"


def iqm_by_hand(row):
    """The interquartile mean of one resample, written out: sort, drop floor(n/4) from each end, average."""
    s = sorted(row)
    cut = len(s) // 4
    kept = s[cut : len(s) - cut]
    return sum(kept) / len(kept)


def percentile(xs, q):
    """numpy's default ('linear') percentile, written out."""
    s = sorted(xs)
    pos = q * (len(s) - 1)
    lo = int(pos)
    hi = min(lo + 1, len(s) - 1)
    return s[lo] + (s[hi] - s[lo]) * (pos - lo)


def test_summarize_iqm_ci_by_hand_with_the_default_seed_resamples_and_confidence():
    """Survivors summarize_iqm 1, 38 (seed 0), 50 (indices from 0), 54 (n // 4),
    57 (v.size - cut), 60, 62, 63 (tails (1 − 0.95)/2), 87-88 ("undefined"): the same resamples (numpy
    seed 0, 4000 of n rows) reduced by hand."""
    values = [0.79, 0.013, 0.52, 0.171, 0.97, 0.29, 0.611, 0.377]  # n = 8: cut 2 (n // 5 would be 1)
    got = summarize_iqm(values + [None])
    idx = np.random.default_rng(0).integers(0, 8, size=(4000, 8))
    stats = [iqm_by_hand([values[i] for i in row]) for row in idx.tolist()]
    assert got["mean"] == pytest.approx((0.29 + 0.377 + 0.52 + 0.611) / 4)
    assert got["ci_low"] == pytest.approx(percentile(stats, 0.025))
    assert got["ci_high"] == pytest.approx(percentile(stats, 0.975))
    assert (got["n"], got["undefined"]) == (8, 1)
    other = summarize_iqm(values, seed=1)
    assert (other["ci_low"], other["ci_high"]) != (got["ci_low"], got["ci_high"])  # these values: the seed shows


def test_summarize_iqm_of_nothing_and_of_identical_values():
    """Survivors summarize_iqm 8-18 (the all-undefined row), 21-22 (identical values: a degenerate interval)."""
    assert summarize_iqm([None, None]) == {"mean": None, "ci_low": None, "ci_high": None, "n": 0, "undefined": 2}
    # identical values are reported as themselves: the mean of three 0.1s is 0.10000000000000002 in floats
    assert summarize_iqm([0.1, 0.1, 0.1, None]) == {
        "mean": 0.1,
        "ci_low": 0.1,
        "ci_high": 0.1,
        "n": 3,
        "undefined": 1,
    }
    spread = summarize_iqm([0.0, 1.0])
    assert spread["ci_low"] < spread["ci_high"]


def test_bootstrap_ci_default_seed_by_hand():
    """Survivors bootstrap_ci 1 (seed 0 by default), 20 (the seed reaches the generator)."""
    values = [0.79, 0.013, 0.52, 0.171, 0.97, 0.29, 0.611, 0.377]
    idx = np.random.default_rng(0).integers(0, 8, size=(4000, 8))
    means = [sum(values[i] for i in row) / 8 for row in idx.tolist()]
    lo, hi = bootstrap_ci(values)
    assert bootstrap_ci(values, seed=1) != (lo, hi)  # these values: the seed shows
    assert lo == pytest.approx(percentile(means, 0.025)) and hi == pytest.approx(percentile(means, 0.975))
