"""`accrue bench report` says which episode set each run's numbers are on in words true of the spec: a spec
that asks for no report set is not described as holding runs "from before the split"."""

from __future__ import annotations

import yaml
from test_bench_protocol import SELECTION, commit_cell  # tests/ is on sys.path (rootdir conftest, no package)
from test_bench_report import BASE

from artifacts.store import Store
from stages.bench.report import build_report, markdown
from stages.bench.spec import load_spec


def spec_with(tmp_path, budgets: dict):
    (tmp_path / "base.yaml").write_text(yaml.safe_dump({**BASE, "budgets": {**BASE["budgets"], **budgets}}))
    spec_file = tmp_path / "p.yaml"
    spec_file.write_text(
        yaml.safe_dump(
            {"base": "base.yaml", "methods": {"accrue": {}}, "orderings": {"S1": BASE["tasks"]}, "seeds": [0, 1]}
        )
    )
    return load_spec(spec_file)


def test_a_spec_without_report_episodes_is_said_to_ask_for_none(tmp_path):
    """Before: `0 of 2 runs have a disjoint report set; the others' numbers are on the episodes their best
    checkpoint was chosen on (runs from before the split)`, of new runs whose spec never asked for one."""
    spec = spec_with(tmp_path, {})
    store = Store.init(tmp_path / "store")[0]
    for seed in (0, 1):
        commit_cell(store, spec.cell("accrue", "S1", seed), SELECTION, None)
    text = markdown(build_report(store, spec))
    assert "before the split" not in text and "before report sets existed" not in text
    assert "the spec sets no budgets.report_episodes, so every run's numbers are on the episodes their best" in text


def test_runs_older_than_a_spec_that_asks_for_a_report_set_are_said_to_be_older(tmp_path):
    spec = spec_with(tmp_path, {"report_episodes": 10})
    store = Store.init(tmp_path / "store")[0]
    commit_cell(store, spec.cell("accrue", "S1", 0), SELECTION, None)
    text = markdown(build_report(store, spec))
    assert "0 of 1 runs have a disjoint report set; 1 ran before report sets existed" in text
