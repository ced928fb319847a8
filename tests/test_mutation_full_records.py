"""scripts/mutation_full.py keeps mutmut's verdicts in the repository, so a sweep on a new machine starts from
them: checked with a real mutmut run on a two-function package (a few seconds), where a restored verdict is
kept without being measured again, and a function whose code changed is measured again."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections import Counter
from pathlib import Path

from test_mutation_full_watchdog import load_script

MUTMUT = Path(sys.executable).with_name("mutmut")
CALC = "def add(a, b):\n    return a + b\n\n\ndef half(x):\n    return x / 2\n"
TESTS = (
    "from pkg.calc import add, half\n\n\ndef test_add():\n    assert add(2, 3) == 5\n\n\n"
    "def test_half():\n    assert half(4) == 2\n"
)
CONFIG = (
    '[tool.mutmut]\nsource_paths = ["pkg/"]\npytest_add_cli_args = ["-p", "no:cacheprovider", "-q"]\n'
    'pytest_add_cli_args_test_selection = ["tests/test_calc.py"]\n'
)


def make_project(root: Path, calc: str = CALC, config: str = CONFIG) -> Path:
    (root / "pkg").mkdir(parents=True)
    (root / "tests").mkdir()
    (root / "pkg" / "__init__.py").write_text("")
    (root / "pkg" / "calc.py").write_text(calc)
    (root / "tests" / "test_calc.py").write_text(TESTS)
    (root / "pyproject.toml").write_text(config)
    return root


def mutmut(root: Path, *args: str) -> str:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("MUTANT_UNDER_TEST", "PYTEST_"))}
    res = subprocess.run([str(MUTMUT), *args], cwd=root, env=env, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    return res.stdout


def verdicts(root: Path) -> dict[str, str]:
    out = mutmut(root, "results", "--all", "true")
    return dict(line.strip().rsplit(": ", 1) for line in out.splitlines() if ": " in line)


def mark_survived(mutants: Path, name: str) -> None:
    meta = mutants / "pkg" / "calc.py.meta"
    data = json.loads(meta.read_text())
    data["exit_code_by_key"][name] = 0  # what mutmut records for a mutant no test killed
    meta.write_text(json.dumps(data))


def test_a_new_machine_resumes_from_the_kept_verdicts_and_remeasures_changed_functions(tmp_path, capsys):
    script = load_script()
    first = make_project(tmp_path / "first")
    mutmut(first, "run", "--max-children", "1")
    assert set(verdicts(first).values()) == {"killed"} and len(verdicts(first)) == 3
    records = tmp_path / "records"
    assert script.save_records(first, records) == 2  # pkg/__init__.py.meta, pkg/calc.py.meta
    assert sorted(p.name for p in records.rglob("*") if p.is_file()) == [
        "__init__.py.meta",
        "calc.py.meta",
        script.CONFIG,
    ]
    # the kept verdict of add's mutant is made "survived": if it is kept, no run measured it again
    mark_survived(records, "pkg.calc.x_add__mutmut_1")
    mark_survived(records, "pkg.calc.x_half__mutmut_1")
    assert script.verdict_counts(records) == {"pkg/calc.py": Counter(killed=1, survived=2)}
    assert script.survivors(records) == ["pkg.calc.x_add__mutmut_1", "pkg.calc.x_half__mutmut_1"]
    (tmp_path / "triage").mkdir()
    (tmp_path / "triage" / "r1.tsv").write_text("pkg.calc.x_add__mutmut_1\tequivalent\tsame sum\n")
    assert script.triaged(tmp_path / "triage") == {"pkg.calc.x_add__mutmut_1": "equivalent"}
    (tmp_path / "triage" / "r2.tsv").write_text("pkg.calc.x_half__mutmut_1\tkilled\ttests/t.py::test_half\n")
    script.print_triage_counts(tmp_path / "triage")
    assert capsys.readouterr().out.splitlines()[2:] == ["| `r1.tsv` | 0 | 1 |", "| `r2.tsv` | 1 | 0 |"]

    second = make_project(tmp_path / "second", calc=CALC.replace("x / 2", "x * 0.5"))
    said = script.restore_records(records, second, script.mutmut_config(second))
    assert said.startswith("resuming from the verdicts of 2 files")
    mutmut(second, "run", "--max-children", "1")
    after = verdicts(second)
    assert after["pkg.calc.x_add__mutmut_1"] == "survived"  # unchanged function: the kept verdict stands
    assert after["pkg.calc.x_half__mutmut_1"] == "killed"  # changed function: measured again


def test_kept_verdicts_are_not_restored_under_another_selection_or_over_a_sweep(tmp_path):
    script = load_script()
    records = tmp_path / "records"
    (records / "pkg").mkdir(parents=True)
    (records / "pkg" / "calc.py.meta").write_text('{"exit_code_by_key": {}}')
    project = make_project(tmp_path / "p")
    (records / script.CONFIG).write_text(json.dumps(script.mutmut_config(project)))

    other = script.mutmut_config(project) | {"pytest_add_cli_args_test_selection": ["tests/other.py"]}
    said = script.restore_records(records, project, other)
    assert said.startswith("not resuming") and not (project / "mutants").exists()

    (project / "mutants").mkdir()
    assert script.restore_records(records, project, script.mutmut_config(project)) == ""
    assert list((project / "mutants").iterdir()) == []  # a sweep already here is never overwritten

    assert script.restore_records(tmp_path / "none", tmp_path / "fresh", {}) == ""


def test_saving_replaces_the_kept_verdicts_of_files_no_longer_mutated(tmp_path):
    script = load_script()
    tree, records = tmp_path / "tree", tmp_path / "records"
    (tree / "mutants" / "pkg").mkdir(parents=True)
    (tree / "mutants" / "pkg" / "calc.py.meta").write_text("{}")
    (tree / "mutants" / "pkg" / "calc.py").write_text("mutated source, not kept")
    (records / "pkg").mkdir(parents=True)
    (records / "pkg" / "gone.py.meta").write_text("{}")
    assert script.save_records(tree, records) == 1
    assert sorted(str(p.relative_to(records)) for p in records.rglob("*") if p.is_file()) == [
        script.CONFIG,
        "pkg/calc.py.meta",
    ]
    assert script.save_records(tmp_path / "empty", records) == 0  # nothing measured: the records stay
    assert (records / "pkg" / "calc.py.meta").exists()


def test_verify_runs_each_mutant_in_its_own_pytest_and_copies_new_tests_in(tmp_path):
    project = make_project(tmp_path / "p")
    mutmut(project, "run", "--max-children", "1")
    # a test written after the sweep, too weak to see add's mutant (a + b -> a - b), with a helper module
    (project / "tests" / "calc_support.py").write_text("ZERO = 0\n")
    (project / "tests" / "test_weak.py").write_text(
        "from calc_support import ZERO\nfrom pkg.calc import add\n\n\ndef test_zero():\n    assert add(ZERO, ZERO) == 0\n"
    )
    names = tmp_path / "names.txt"
    names.write_text("pkg.calc.x_add__mutmut_1\n")
    out = tmp_path / "out.tsv"
    verify = [sys.executable, str(Path(__file__).resolve().parents[1] / "scripts" / "mutation_verify.py")]
    common = ["--mutants", str(project / "mutants"), "--source", str(project), "--out", str(out)]
    subprocess.run([*verify, str(names), "tests/test_calc.py", *common], check=True, capture_output=True, timeout=120)
    assert out.read_text() == "pkg.calc.x_add__mutmut_1\tkilled\ttests/test_calc.py::test_add\n"
    subprocess.run([*verify, str(names), "tests/test_weak.py", *common], check=True, capture_output=True, timeout=120)
    assert out.read_text() == "pkg.calc.x_add__mutmut_1\tsurvived\n"


def test_triage_lines_the_kept_verdicts_no_longer_bear_out_are_listed_to_look_at_again(tmp_path):
    """After a function's code changes, mutmut numbers its mutants afresh: a line calling a mutant equivalent
    that the sweep now kills, or naming a mutant that no longer exists, describes another mutation."""
    script = load_script()
    records, triage = tmp_path / "records", tmp_path / "triage"
    (records / "pkg").mkdir(parents=True)
    codes = {"pkg.calc.x_add__mutmut_1": 1, "pkg.calc.x_add__mutmut_2": 0, "pkg.calc.x_add__mutmut_3": 1}
    (records / "pkg" / "calc.py.meta").write_text(json.dumps({"exit_code_by_key": codes}))
    triage.mkdir()
    (triage / "a.tsv").write_text(
        "pkg.calc.x_add__mutmut_1\tequivalent\tsame sum\n"  # now killed: stale
        "pkg.calc.x_add__mutmut_2\tequivalent\tsame sum\n"  # still survives: stands
        "pkg.calc.x_add__mutmut_3\tkilled\ttests/t.py::test_add\n"  # killed and said so: stands
    )
    (triage / "b.tsv").write_text("pkg.calc.x_add__mutmut_9\tkilled\ttests/t.py::test_add\n")  # gone
    assert script.stale_triage(records, triage) == ["pkg.calc.x_add__mutmut_1", "pkg.calc.x_add__mutmut_9"]


def test_after_a_code_change_a_new_function_is_tested_by_the_old_tests_that_reach_it(tmp_path, capsys):
    """mutmut 3.8's own update of its test map after a code change runs only the tests that are new, so a
    function the change created is reached by none of the old tests and its mutants are "no tests" (or
    survive, when new tests exist). The sweep forgets the map when the mutated code changed, and mutmut
    collects it again from the whole selection, keeping every verdict."""
    script = load_script()
    project = make_project(tmp_path / "p")
    mutmut(project, "run", "--max-children", "1")
    assert script.code_digest(project) == script.code_digest(project)
    before = script.code_digest(project)
    split = CALC.replace(
        "def add(a, b):\n    return a + b\n",
        "def plus(a, b):\n    return a + b\n\n\ndef add(a, b):\n    return plus(a, b)\n",
    )
    (project / "pkg" / "calc.py").write_text(split)
    assert script.code_digest(project) != before
    control = tmp_path / "control"
    subprocess.run(["cp", "-a", f"{project}/.", str(control)], check=True)
    mutmut(control, "run", "--max-children", "1")
    assert verdicts(control)["pkg.calc.x_plus__mutmut_1"] == "no tests"  # mutmut's own update

    assert script.forget_test_map(project) and not script.forget_test_map(project)
    mutmut(project, "run", "--max-children", "1")
    assert verdicts(project)["pkg.calc.x_plus__mutmut_1"] == "killed"
    assert script.code_digest(tmp_path / "nothing") is None
