"""Metrics over task orderings (issue 10, fix 6): runs whose task lists are permutations are aggregated
per method with bootstrap CIs over runs, and each ordering keeps its own figures; `accrue metrics`
reads labelled runs of different orderings."""

import json

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from accrue.errors import AccrueError
from accrue.metrics import (
    BOOTSTRAP_RESAMPLES,
    aggregate_runs,
    bootstrap_ci,
    load_metrics_file,
    run_record,
    summarize_values,
)
from cli.metrics_cmds import register

A, B, C = "nist/rect_peg", "nist/round_peg", "nist/gear"


def two_stage(first: float, retained: float, second: float) -> list:
    """Two stages, two grid points each: stage 1 peaks at `first`, stage 2 keeps `retained` of task 1."""
    return [[[0.0, first]], [[retained, retained], [0.0, second]]]


def record(method, ordering, seed, metrics, tasks=(A, B)):
    return {"method": method, "ordering": ordering, "seed": seed, "tasks": list(tasks), "metrics": metrics}


def metrics(fwt, nbt, auc=0.5, acc=0.5, f=0.1):
    return {"FWT": fwt, "NBT": nbt, "AUC": auc, "ACC_final": acc, "F_final": f}


def test_permuted_runs_aggregate_by_sequence_level_metrics():
    r1 = run_record(two_stage(0.8, 0.6, 1.0), method="accrue", tasks=[A, B], ordering="S1", seed=0)
    r2 = run_record(two_stage(1.0, 0.5, 0.6), method="accrue", tasks=[B, A], ordering="S2", seed=0)
    # r1: FWT_1 = 0.4, FWT_2 = 0.5 -> 0.45; NBT = 0.8 - 0.6 = 0.2
    # r2: FWT_1 = 0.5, FWT_2 = 0.3 -> 0.40; NBT = 1.0 - 0.5 = 0.5
    assert r1["metrics"]["FWT"] == pytest.approx(0.45) and r2["metrics"]["NBT"] == pytest.approx(0.5)
    agg = aggregate_runs([r1, r2])
    [m] = agg["methods"]
    assert m["runs"] == 2
    assert m["metrics"]["FWT"]["mean"] == pytest.approx(0.425)
    assert m["metrics"]["NBT"]["mean"] == pytest.approx(0.35)
    assert [o["ordering"] for o in m["orderings"]] == ["S1", "S2"]
    assert m["orderings"][1]["tasks"] == [B, A]
    assert m["orderings"][0]["metrics"]["NBT"]["mean"] == pytest.approx(0.2)  # per-ordering figures kept


def test_method_means_and_cis_equal_a_hand_computation():
    recs = [
        record("accrue", "S1", 0, metrics(0.8, 0.1)),
        record("accrue", "S1", 1, metrics(0.6, 0.3)),
        record("accrue", "S2", 0, metrics(0.7, 0.2), tasks=(B, A)),
        record("er", "S1", 0, metrics(0.5, None)),
        record("er", "S2", 0, metrics(0.5, None), tasks=(B, A)),
    ]
    agg = aggregate_runs(recs)
    assert [m["method"] for m in agg["methods"]] == ["accrue", "er"]  # first-appearance order
    acc = agg["methods"][0]
    fwt = acc["metrics"]["FWT"]
    assert fwt["mean"] == pytest.approx((0.8 + 0.6 + 0.7) / 3) and fwt["n"] == 3
    # the CI is the percentile bootstrap of the mean, seeded: recompute it by hand
    rng = np.random.default_rng(0)
    v = np.array([0.8, 0.6, 0.7])
    means = v[rng.integers(0, 3, size=(BOOTSTRAP_RESAMPLES, 3))].mean(1)
    assert (fwt["ci_low"], fwt["ci_high"]) == pytest.approx((np.quantile(means, 0.025), np.quantile(means, 0.975)))
    assert fwt["ci_low"] < fwt["mean"] < fwt["ci_high"]
    s1 = acc["orderings"][0]
    assert s1["seeds"] == [0, 1] and s1["metrics"]["NBT"]["mean"] == pytest.approx(0.2)
    er = agg["methods"][1]
    assert er["metrics"]["NBT"] == {"mean": None, "ci_low": None, "ci_high": None, "n": 0, "undefined": 2}
    # identical values: a degenerate interval at the value itself
    assert er["metrics"]["FWT"]["mean"] == er["metrics"]["FWT"]["ci_low"] == er["metrics"]["FWT"]["ci_high"] == 0.5


def test_identical_values_give_a_degenerate_interval():
    assert bootstrap_ci([0.1, 0.1, 0.1]) == (0.1, 0.1)
    s = summarize_values([0.1, 0.1, 0.1, None])
    assert s["mean"] == s["ci_low"] == s["ci_high"] == 0.1 and s["n"] == 3 and s["undefined"] == 1
    with pytest.raises(AccrueError, match="no values"):
        bootstrap_ci([])


def test_an_ordering_name_cannot_mean_two_sequences():
    with pytest.raises(AccrueError, match="ordering 'S1' names two task sequences"):
        aggregate_runs(
            [record("accrue", "S1", 0, metrics(0.1, 0.1)), record("er", "S1", 0, metrics(0.1, 0.1), tasks=(B, A))]
        )


def app() -> typer.Typer:
    a = typer.Typer()

    @a.callback()
    def _root():
        pass

    register(a)
    return a


def run_json(method, ordering, tasks, curves, seed):
    return {"method": method, "ordering": ordering, "seed": seed, "tasks": tasks, "grid": [0, 100], "curves": curves}


def test_metrics_file_with_orderings_and_methods(tmp_path):
    runs = [
        run_json("accrue", "S1", [A, B], two_stage(0.8, 0.6, 1.0), 0),
        run_json("accrue", "S2", [B, A], two_stage(1.0, 0.5, 0.6), 0),
        run_json("sequential", "S1", [A, B], two_stage(0.8, 0.2, 1.0), 0),
    ]
    f = tmp_path / "runs.json"
    f.write_text(json.dumps(runs))
    loaded = load_metrics_file(f)
    assert [r["tasks"] for r in loaded] == [[A, B], [B, A], [A, B]]
    res = CliRunner().invoke(app(), ["metrics", str(f), "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    methods = {m["method"]: m for m in out["methods"]}
    assert methods["accrue"]["metrics"]["NBT"]["mean"] == pytest.approx(0.35)
    assert methods["sequential"]["metrics"]["NBT"]["mean"] == pytest.approx(0.6)
    assert len(out["runs"]) == 3
    res = CliRunner().invoke(app(), ["metrics", str(f)], env={"COLUMNS": "200"})
    assert res.exit_code == 0, res.output
    assert "per ordering" in res.output and "S2" in res.output and "sequential" in res.output
    assert "0.350 [" in res.output  # accrue's NBT mean with its interval


def test_unlabelled_runs_group_by_their_task_sequence(tmp_path):
    f = tmp_path / "runs.json"
    f.write_text(
        json.dumps(
            [
                {"tasks": [A, B], "grid": [0, 1], "curves": two_stage(0.8, 0.6, 1.0)},
                {"tasks": [B, A], "grid": [0, 1], "curves": two_stage(0.8, 0.6, 1.0)},
            ]
        )
    )
    loaded = load_metrics_file(f)
    assert [r["method"] for r in loaded] == ["all", "all"] and [r["seed"] for r in loaded] == [0, 1]
    assert loaded[1]["ordering"] == f"{B} → {A}"


def test_bad_labels_are_one_line_errors(tmp_path):
    f = tmp_path / "runs.json"
    f.write_text(json.dumps({"tasks": [A], "grid": [0], "curves": [[[0.5]]], "seed": "zero"}))
    with pytest.raises(AccrueError, match="'seed' must be an integer"):
        load_metrics_file(f)
    f.write_text(json.dumps({"tasks": [A], "grid": [0], "curves": [[[0.5]]], "method": ""}))
    with pytest.raises(AccrueError, match="'method' must be a non-empty name"):
        load_metrics_file(f)
