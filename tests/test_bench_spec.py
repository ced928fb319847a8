"""Bench specs: the grid of cells, merged overrides, derived workflow names, shared cache keys across
methods, the shipped specs, and bad specs as one-line errors with exit code 2."""

from __future__ import annotations

import itertools
import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from artifacts.store import Store
from stages.bench.spec import expand_dotted, load_spec, merge
from stages.errors import StageError
from stages.plan import plan_stage

ROOT = Path(__file__).resolve().parents[1]
BASE = {
    "name": "base",
    "tasks": ["nist/rect_peg", "nist/gear"],
    "method": "accrue",
    "seed": 0,
    "horizon": 4,
    "base_policy": {"init": "embedded-mlp", "finetune_steps": 5, "demos_per_task": 2},
    "learner": {"beta": 1.0, "lam": 10.0},
    "budgets": {"env_steps": 400, "eval_every": 200, "eval_episodes": 4, "num_envs": 2},
}
SPEC = {
    "base": "base.yaml",
    "overrides": {"budgets.env_steps": 200, "budgets": {"eval_every": 100}},
    "methods": {
        "accrue": {},
        "sequential": {},
        "no-ref": {"method": "accrue", "learner.ablation": "no-reference"},
        "lam0": {"method": "accrue", "learner": {"lam": None}},
    },
    "orderings": {"S1": ["nist/rect_peg", "nist/gear"], "S2": ["nist/gear", "nist/rect_peg"]},
    "seeds": [0, 1],
}


def write(tmp_path: Path, spec=SPEC, base=BASE, name="grid.yaml") -> Path:
    (tmp_path / "base.yaml").write_text(yaml.safe_dump(base))
    path = tmp_path / name
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path


def test_cells_are_methods_by_orderings_by_seeds_in_method_major_order(tmp_path):
    spec = load_spec(write(tmp_path))
    assert len(spec.cells) == 4 * 2 * 2
    assert [(c.method, c.ordering, c.seed) for c in spec.cells[:4]] == [
        ("accrue", "S1", 0),
        ("accrue", "S1", 1),
        ("accrue", "S2", 0),
        ("accrue", "S2", 1),
    ]
    cell = spec.cell("no-ref", "S2", 1)
    wf = cell.workflow
    assert wf.tasks == ["nist/gear", "nist/rect_peg"] and wf.seed == 1 and wf.method == "accrue"
    assert wf.budgets.env_steps == 200 and wf.budgets.eval_every == 100 and wf.budgets.eval_episodes == 4
    assert wf.learner == {"beta": 1.0, "lam": 10.0, "ablation": "no-reference"}
    assert spec.cell("lam0", "S1", 0).workflow.learner == {"beta": 1.0}  # null removes the key
    assert spec.cell("sequential", "S1", 0).workflow.method == "sequential"  # method from the name
    assert wf.name == cell.name and wf.name.startswith("grid.no-ref.S2.s1.")


def test_cell_names_are_deterministic_distinct_and_change_with_the_cell(tmp_path):
    a = load_spec(write(tmp_path))
    b = load_spec(write(tmp_path))
    assert [c.name for c in a.cells] == [c.name for c in b.cells]
    assert len({c.name for c in a.cells}) == len(a.cells)
    changed = {**SPEC, "overrides": {"budgets.env_steps": 300, "budgets": {"eval_every": 100}}}
    c = load_spec(write(tmp_path, changed))
    assert not {x.name for x in a.cells} & {x.name for x in c.cells}
    long = {**SPEC, "name": "x" * 40, "methods": {"m" * 40: {"method": "accrue"}}}
    for cell in load_spec(write(tmp_path, long)).cells:
        assert len(cell.name) <= 64


def test_overrides_merge_nested_and_dotted():
    assert expand_dotted({"a.b": 1, "a": {"c.d": 2}}, "x") == {"a": {"b": 1, "c": {"d": 2}}}
    assert merge({"a": {"b": 1, "c": 2}, "d": [1]}, {"a": {"b": 3}, "d": [2], "e": None}, "x") == {
        "a": {"b": 3, "c": 2},
        "d": [2],
    }
    with pytest.raises(StageError, match="not a mapping"):
        merge({"a": 1}, {"a": {"b": 2}}, "x")


def test_methods_share_base_policy_and_demo_cache_keys(tmp_path):
    """finetune-base and record-demos configs hold neither the method nor the workflow name, so every
    method of one ordering and seed reuses the same fine-tune through the step cache."""
    spec = load_spec(write(tmp_path))
    store = Store.init(tmp_path / "store")[0]
    plans = [plan_stage(spec.cell(m, "S1", 0).workflow, 2, store) for m in ("accrue", "sequential", "no-ref")]
    for step in ("record-demos", "finetune-base", "warmup"):
        invs = [next(i for i in p.steps if i.step.name == step) for p in plans]
        assert all(i.config == invs[0].config for i in invs), step
    for inv in (i for p in plans for i in p.steps if i.step.name in ("record-demos", "finetune-base")):
        text = json.dumps(inv.config)
        assert inv.workflow not in text and "sequential" not in text and "no-reference" not in text
    assert plans[0].steps[-1].config != plans[1].steps[-1].config  # handoff knows the method


@pytest.mark.parametrize(
    "change,message",
    [
        ({"methods": {"acrue": {}}}, "unknown method 'acrue'"),
        ({"methods": {"x": {"method": "acrue"}}}, "method: must be one of"),
        ({"methods": {}}, "empty grid: methods has no entries"),
        ({"seeds": []}, "empty grid: seeds has no entries"),
        ({"orderings": {"S1": ["nist/rect_peg", "nist/nope"]}}, r"orderings.S1\[1\]: unknown task 'nist/nope'"),
        ({"orderings": {"S1": ["nist/rect_peg", "nist/rect_peg"]}}, "appears twice"),
        ({"overrides": {"tasks": ["nist/gear"]}}, "overrides.tasks: set by the grid"),
        ({"overrides": {"budgets.env_steps": -1}}, "budgets.env_steps: must be > 0"),
        ({"overrides": {"learner.no_such_knob": 1}}, "learner.no_such_knob: unknown setting"),
        ({"seeds": [0, 0]}, "a seed appears twice"),
        ({"resources": {"num_gpus": -1}}, "resources.num_gpus: must be a non-negative number"),
        ({"colour": "red"}, "colour: unknown field"),
        ({"base": "missing.yaml"}, "missing.yaml: no such base workflow file"),
        ({"reference": "ewc"}, "reference: 'ewc' is not one of the spec's methods"),
    ],
)
def test_bad_specs_name_the_field(tmp_path, change, message):
    with pytest.raises(StageError, match=message):
        load_spec(write(tmp_path, {**SPEC, **change}))


def test_bad_spec_is_one_line_and_exit_2(tmp_path):
    path = write(tmp_path, {**SPEC, "methods": {"acrue": {}}})
    for args in (["bench", str(path)], ["bench", "status", str(path)], ["bench", "report", str(path)]):
        res = subprocess.run(
            [sys.executable, "-m", "cli.main", *args],
            capture_output=True,
            text=True,
            timeout=120,
            cwd=ROOT,
            env={"ACCRUE_STORE": str(tmp_path / "nostore"), "PATH": "/usr/bin:/bin"},
        )
        assert res.returncode == 2, res.stderr
        assert res.stderr.startswith("error: ") and res.stderr.count("\n") == 1 and "unknown method" in res.stderr


def test_shipped_specs_load():
    """Every spec in workflows/bench validates, claims included."""
    specs = sorted((ROOT / "workflows" / "bench").glob("*.yaml"))
    assert {p.stem for p in specs} >= {"nist-small", "nist-ablations", "retained-n"}
    for path in specs:
        spec = load_spec(path)
        assert spec.cells
        if path.stem in ("nist-small", "nist-ablations"):
            assert spec.claims and spec.reference == "accrue"
        if path.stem == "nist-small":
            assert set(spec.methods) >= {"accrue", "sequential", "er", "ewc", "retain", "single-task", "isolated"}
            assert len(spec.orderings) >= 2 and len(spec.seeds) >= 3
        if path.stem == "retained-n":
            assert sorted(c.workflow.budgets.retained_episodes for c in spec.cells if c.seed == spec.seeds[0]) == [
                10,
                20,
                50,
                100,
            ]


def test_unreachable_cluster_address_is_one_line_and_exit_2(tmp_path):
    path = write(tmp_path)
    Store.init(tmp_path / "store")
    res = subprocess.run(
        [sys.executable, "-m", "cli.main", "bench", str(path), "--address", "127.0.0.1:1"],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
        env={"ACCRUE_STORE": str(tmp_path / "store"), "PATH": "/usr/bin:/bin"},
    )
    assert res.returncode == 2, res.stderr
    assert res.stderr.startswith("error: --address 127.0.0.1:1: nothing answers there") and res.stderr.count("\n") == 1


def test_a_part_of_the_grid_can_run_first(tmp_path):
    from stages.bench.spec import select_cells

    spec = load_spec(write(tmp_path))
    part = select_cells(spec, seeds=[1], methods=["no-ref", "accrue"])
    assert [(c.method, c.ordering, c.seed) for c in part] == [
        ("accrue", "S1", 1),
        ("accrue", "S2", 1),
        ("no-ref", "S1", 1),
        ("no-ref", "S2", 1),
    ]  # the spec's own cells, in its order
    assert all(c is spec.cell(c.method, c.ordering, c.seed) for c in part)
    assert select_cells(spec) == spec.cells
    with pytest.raises(StageError, match=r"--seeds: 7 not in grid.yaml \(it has 0, 1\)"):
        select_cells(spec, seeds=[7])
    with pytest.raises(StageError, match="--orderings: S9 not in"):
        select_cells(spec, orderings=["S9"])
    res = subprocess.run(
        [sys.executable, "-m", "cli.main", "bench", str(write(tmp_path)), "--seeds", "0,x"],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
        env={"ACCRUE_STORE": str(tmp_path / "nostore"), "PATH": "/usr/bin:/bin"},
    )
    assert res.returncode == 2 and res.stderr == "error: --seeds: expected comma-separated integers (got '0,x')\n"


def grid_points(cell) -> int:
    b = cell.workflow.budgets
    return len(set(range(0, b.env_steps, b.eval_every)) | {b.env_steps})


def test_issue_18_specs_declare_their_predictions_and_protocol():
    """contact-headline / contact-ablations / bias-control: the protocol of issue 18 (>= 10 evaluation
    points after step 0, >= 100 report episodes on a set disjoint from the selection set, one optimiser
    for every method) and the predicted signs, loaded strictly against the tasks that exist."""
    bench = ROOT / "workflows" / "bench"
    specs = {n: load_spec(bench / f"{n}.yaml") for n in ("contact-headline", "contact-ablations", "bias-control")}
    for name, spec in specs.items():
        for c in spec.cells:
            assert grid_points(c) >= 11, (name, c.method)
            assert c.workflow.budgets.report_episodes >= 100
            lr = c.workflow.learner
            if c.method != "beta0-old-optimiser":
                assert (lr["actor_lr"], lr["critic_lr"], lr["learning_starts"], lr["max_grad_norm"]) == (
                    3e-4,
                    3e-4,
                    1280,
                    1.0,
                )
    head = specs["contact-headline"]
    assert set(head.methods) == {"accrue", "sequential", "er", "ewc", "retain", "single-task", "isolated"}
    assert len(head.seeds) >= 4 and len(head.orderings) == 6
    assert {tuple(o) for o in head.orderings.values()} == set(
        itertools.permutations(["contact/round_peg", "contact/keyed_peg", "contact/gear_mesh"])
    )
    signs = {(p.metric, p.reference_is, p.than) for p in head.predictions}
    assert ("FWT", "higher", ("single-task",)) in signs and ("FWT_no0", "higher", ("single-task",)) in signs
    bias = specs["bias-control"]
    assert all(t.startswith("nist/") for o in bias.orderings.values() for t in o) and len(bias.orderings) == 6
    assert ("FWT", "not-higher", ("single-task",)) in {(p.metric, p.reference_is, p.than) for p in bias.predictions}
    abl = specs["contact-ablations"]
    assert len(abl.orderings) >= 2
    betas = {
        c.workflow.learner.get("beta") if c.workflow.learner.get("ablation") != "beta0" else 0.0 for c in abl.cells
    }
    assert betas >= {0.0, 0.1, 1.0}
    ablations = {c.workflow.learner.get("ablation") for c in abl.cells}
    assert ablations >= {"no-reference", "beta0", "reset-critic", "critic-all-replay"}
    predicted = {m for p in abl.predictions for m in p.than}
    assert predicted >= {"no-reference", "beta0", "reset-critic", "critic-all-replay", "beta0-old-optimiser"}


def test_issue_18_specs_run_at_the_budget_the_single_task_rule_chose():
    """The budget of each issue-18 spec is the one `accrue bench budget workflows/bench/contact-budget.yaml`
    chose for its family (its output committed beside the budget report), with eval_every = B / 10:
    a spec edited to another budget after the freeze fails here."""
    bench = ROOT / "workflows" / "bench"
    chosen = {}
    rule_output = (ROOT / "benchmarks/results/bench/contact-budget/budget.txt").read_text().split("\n\n")[0]
    for line in rule_output.splitlines():  # the first block is the rule; a later one, the first declared rule
        if " -> chosen " in line:
            family, rest = line.split(":", 1)
            chosen[family] = int(rest.split(" -> chosen ")[1].split()[0])
    assert set(chosen) == {"contact", "nist"}
    for name, family in (("contact-headline", "contact"), ("contact-ablations", "contact"), ("bias-control", "nist")):
        for c in load_spec(bench / f"{name}.yaml").cells:
            b = c.workflow.budgets
            assert (b.env_steps, b.eval_every) == (chosen[family], chosen[family] // 10), (name, c.method)
