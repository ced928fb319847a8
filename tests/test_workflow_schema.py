"""Workflow YAML: valid files load; every mistake is one line naming the file, field and problem."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from stages.errors import StageError
from stages.workflow import load_workflow

GOOD = {
    "name": "quick",
    "tasks": ["nist/round_peg", "nist/rect_peg"],
    "method": "accrue",
    "seed": 3,
    "base_policy": {"init": "embedded-act", "finetune_steps": 50},
    "learner": {"algo": "fasttd3", "batch_size": 64, "lam": 1.0},
    "budgets": {"env_steps": 2000, "eval_every": 500},
}


def write(tmp_path: Path, data, name: str = "x.yaml") -> Path:
    path = tmp_path / name
    path.write_text(data if isinstance(data, str) else yaml.safe_dump(data))
    return path


def with_change(path: str, value) -> dict:
    data = yaml.safe_load(yaml.safe_dump(GOOD))
    *parents, last = path.split(".")
    node = data
    for p in parents:
        node = node.setdefault(p, {})
    if value is KeyError:
        del node[last]
    else:
        node[last] = value
    return data


def test_valid_workflow_loads(tmp_path):
    wf = load_workflow(write(tmp_path, GOOD))
    assert wf.name == "quick" and wf.num_stages == 2 and wf.task(2) == "nist/rect_peg"
    assert wf.base_policy.finetune_steps == 50 and wf.budgets.eval_episodes == 10
    assert wf.learner_settings()["method"] == "accrue" and wf.learner_settings()["seed"] == 3
    with pytest.raises(StageError, match=r"stages 1\.\.2 \(got --stage 3\)"):
        wf.check_stage(3)


def test_name_defaults_to_the_file_stem(tmp_path):
    data = dict(GOOD)
    del data["name"]
    assert load_workflow(write(tmp_path, data, "five-plug.yaml")).name == "five-plug"


@pytest.mark.parametrize(
    "change, expected",
    [
        (("learner.batch_size", -3), "x.yaml: learner.batch_size: must be a positive integer (got -3)"),
        (("learner.batchsize", 3), "x.yaml: learner.batchsize: unknown setting"),
        (("budgets.env_steps", 0), "x.yaml: budgets.env_steps: must be > 0 (got 0)"),
        (("budgets.eval_every", 5000), "x.yaml: budgets: eval_every must be <= env_steps (2000) (got 5000)"),
        (("budgets", KeyError), "x.yaml: budgets: required field is missing"),
        (("method", "accru"), "x.yaml: method: must be one of"),
        (("tasks", []), "x.yaml: tasks: must not be empty (got [])"),
        (("tasks", ["a", "a"]), "x.yaml: tasks: task a appears twice"),
        (("colour", "red"), "x.yaml: colour: unknown field"),
        (("base_policy.demo_retention", 0.0), "x.yaml: base_policy.demo_retention: must be > 0.0 (got 0.0)"),
        (("base_policy.demo_quality", 1.5), "x.yaml: base_policy.demo_quality: must be <= 1.0 (got 1.5)"),
        (("budgets.log_episodes", -1), "x.yaml: budgets.log_episodes: must be >= 0 (got -1)"),
        (("base_policy.lr", -1.0), "x.yaml: base_policy.lr: must be > 0.0 (got -1.0)"),
        (("name", "has space"), "x.yaml: name: must be letters"),
        (("seed", "seven"), "x.yaml: seed: input should be a valid integer"),
        (("learner.method", "ewc"), "x.yaml: learner.method: differs from the workflow's method"),
    ],
)
def test_mistakes_are_one_line_naming_the_field(tmp_path, change, expected):
    with pytest.raises(StageError) as err:
        load_workflow(write(tmp_path, with_change(*change)))
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith(str(tmp_path / "x.yaml") + ": ") and expected in message, message


def test_yaml_syntax_error_missing_file_and_wrong_shape(tmp_path):
    with pytest.raises(StageError, match=r"x\.yaml: YAML syntax error at line 2, column \d+"):
        load_workflow(write(tmp_path, "tasks: [a, b\nmethod: accrue\n"))
    with pytest.raises(StageError, match="no such workflow file"):
        load_workflow(tmp_path / "missing.yaml")
    with pytest.raises(StageError, match="expected a mapping of workflow fields, got list"):
        load_workflow(write(tmp_path, "- a\n- b\n"))
    with pytest.raises(StageError, match="is a directory"):
        load_workflow(tmp_path)


def test_validation_does_not_import_torch(tmp_path):
    import subprocess
    import sys

    path = write(tmp_path, GOOD)
    code = (
        "import sys; from stages.workflow import load_workflow; load_workflow(sys.argv[1]); "
        "print('torch' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
