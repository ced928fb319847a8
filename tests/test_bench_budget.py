"""Issue 18's budget rule (Single-task alone): the plateau by hand, on a store of known cells, and through
`accrue bench budget`."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from test_bench_protocol import REPORT, SELECTION, commit_cell  # tests/ is on sys.path (rootdir conftest)
from test_bench_report import BASE

from artifacts.store import Store
from stages.bench.budget import choose_budgets, plateau
from stages.bench.spec import load_spec
from stages.errors import StageError

ROOT = Path(__file__).resolve().parents[1]


def test_plateau_by_hand():
    assert plateau([(24000, 0.70), (12000, 0.50), (48000, 0.72)]) == (24000, True)  # 0.70 >= 0.72 - 0.03
    assert plateau([(12000, 0.5), (24000, 0.6), (48000, 0.7)]) == (48000, False)  # still rising: the largest
    assert plateau([(12000, 0.80), (24000, 0.79)]) == (12000, True)  # no gain from more steps
    assert plateau([(12000, 0.5), (24000, 0.6)], tolerance=0.1) == (12000, True)


def test_plateau_compares_with_every_larger_budget():
    """The contact family's measured points (contact-budget.yaml): 12k and 24k both precede learning, so
    12k is within 0.03 of 24k, but 48k gains 0.077 over it. The rule takes 48k; compared with the next
    budget only (the rule as first declared) it took 12k."""
    contact = [(12000, 0.320), (24000, 0.342), (48000, 0.397)]
    assert plateau(contact) == (48000, False)
    assert plateau(contact, against="next") == (12000, True)
    assert plateau([(12000, 0.5), (24000, 0.7), (48000, 0.71)]) == (24000, True)  # flat after 24k
    with pytest.raises(ValueError, match="against"):
        plateau(contact, against="all")


SPEC = {
    "base": "base.yaml",
    "methods": {
        "st-100": {"method": "single-task", "budgets.env_steps": 100, "budgets.eval_every": 50},
        "st-200": {"method": "single-task", "budgets.env_steps": 200, "budgets.eval_every": 100},
    },
    "orderings": {"S1": BASE["tasks"]},
    "seeds": [0, 1],
}
# stage ends on the report set: st-100 (0.8 + 0.6) / 2 = 0.7; st-200 (0.9 + 0.7) / 2 = 0.8
LONGER = {1: [[0.0, 0.4, 0.9]], 2: [[0.5, 0.5, 0.1], [0.2, 0.2, 0.7]]}


@pytest.fixture
def budget_bench(tmp_path):
    (tmp_path / "base.yaml").write_text(yaml.safe_dump(BASE))
    path = tmp_path / "budget.yaml"
    path.write_text(yaml.safe_dump(SPEC))
    spec = load_spec(path)
    store = Store.init(tmp_path / "store")[0]
    for seed in (0, 1):
        commit_cell(store, spec.cell("st-100", "S1", seed), SELECTION, REPORT)
    commit_cell(store, spec.cell("st-200", "S1", 0), SELECTION, LONGER)
    return spec, store, path


def test_the_rule_waits_for_every_cell_then_chooses(budget_bench):
    spec, store, _ = budget_bench
    [partial] = choose_budgets(store, spec)
    assert not partial["complete"] and partial["chosen"] is None  # st-200 seed 1 has not run
    commit_cell(store, spec.cell("st-200", "S1", 1), SELECTION, LONGER)
    [row] = choose_budgets(store, spec)
    assert [(p["env_steps"], p["runs"]) for p in row["points"]] == [(100, 2), (200, 2)]
    assert [p["end_success"] for p in row["points"]] == pytest.approx([0.7, 0.8])
    assert (row["chosen"], row["flattened"]) == (200, False)  # 0.7 < 0.8 - 0.03: still rising
    [loose] = choose_budgets(store, spec, tolerance=0.15)
    assert (loose["chosen"], loose["flattened"]) == (100, True)


def test_only_single_task_chooses_the_budget(tmp_path):
    (tmp_path / "base.yaml").write_text(yaml.safe_dump(BASE))
    path = tmp_path / "b.yaml"
    path.write_text(yaml.safe_dump({**SPEC, "methods": {**SPEC["methods"], "accrue": {}}}))
    with pytest.raises(StageError, match="Single-task alone"):
        choose_budgets(Store.init(tmp_path / "store")[0], load_spec(path))


def test_cli_prints_the_choice_and_a_bad_tolerance_is_one_line(budget_bench):
    spec, store, path = budget_bench
    env = {**os.environ, "ACCRUE_STORE": str(store.root)}

    def budget_cli(*args):
        cmd = [sys.executable, "-m", "cli.main", "bench", "budget", str(path), *args]
        return subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env=env)

    res = budget_cli()
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == (
        "S1: stage-end success by budget 100: 0.700 (2 of 2 runs), 200: 0.800 (1 of 2 runs) -> not chosen: cells missing"
    )
    for args, option in ((["--tolerance", "2"], "--tolerance"), (["--against", "all"], "--against")):
        bad = budget_cli(*args)
        assert bad.returncode == 2 and bad.stderr.startswith(f"error: {option}") and bad.stderr.count("\n") == 1
