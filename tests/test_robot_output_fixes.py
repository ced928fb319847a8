"""Small output defects a newcomer met on a robot run, each fixed: what is printed, shown on the operator
page and written in the report says what is true, in words a person reads."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def so101_ci_workflow():
    from stages.workflow import load_workflow

    return load_workflow(ROOT / "workflows" / "so101-sim-ci.yaml")


def test_table3_of_a_one_task_workflow_is_a_sentence_not_a_malformed_table():
    """Before: `| task |  |` and `|---|`: a table with no column."""
    from stages.report.hardware import table3_markdown

    text = table3_markdown({}, so101_ci_workflow())
    assert "|" not in text and "No retention trials: the workflow has one task (so101/reach_close)" in text


def test_table3_with_retention_trials_is_still_the_table():
    from stages.report.hardware import table3_markdown
    from stages.workflow import load_workflow

    wf = load_workflow(ROOT / "workflows" / "hardware-sim.yaml")
    text = table3_markdown({2: {"nist/rect_peg": [True, False, True]}}, wf)
    assert text.splitlines()[:3] == ["| task | after stage 2 |", "|---|---|", "| stage 1 (nist/rect_peg) | 2/3 |"]


def test_warmup_interventions_are_in_the_report(monkeypatch):
    """Before: only train episodes were read, so what the operator drove in warmup was in no report."""
    from stages.report import hardware

    def episode(index, phase, driven, steps=30):
        return {"index": index, "phase": phase, "interventions": driven, "control_steps": steps}

    episodes = {
        "warmup": [episode(0, "warmup", 6), episode(1, "warmup", 0)],
        "train": [episode(2, "train", 3), episode(3, "train", 0), episode(4, "train", 0)],
    }
    monkeypatch.setattr(hardware, "step_episodes", lambda store, wf, k, step: episodes[step] if k == 1 else None)
    rows = hardware.stage_interventions(None, so101_ci_workflow())
    assert rows[1]["warmup"] == {
        "episodes": "0-1",
        "intervened_steps": 6,
        "control_steps": 60,
        "episodes_with_interventions": 1,
        "rate": 0.1,
    }
    text = hardware.interventions_markdown(rows)
    assert "| 1 | warmup 0-1 | 6 | 60 | 1 | 10.0% |" in text and "| 1 | 2-4 | 3 | 90 | 1 | 3.3% |" in text

    # a stage whose operator drove in warmup only is reported too
    episodes["train"] = [episode(2, "train", 0) | {"interventions": 0}]
    episodes["train"][0].pop("interventions")
    assert hardware.stage_interventions(None, so101_ci_workflow())[1]["warmup"]["intervened_steps"] == 6


@pytest.mark.parametrize(
    "kept, line",
    [({"0": 2}, "2 complete episodes of task 1 kept"), ({"0": 20, "1": 5}, "20 of task 1, 5 of task 2 kept")],
)
def test_handoff_says_the_kept_episodes_in_words_not_a_python_dict(kept, line):
    """Before: `handoff: θ^1, ψ^1 and 16 retained transitions ({'0': 2} complete episodes per task index)`."""
    from stages.steps.handoff import kept_text

    assert line in kept_text(kept) and "{" not in kept_text(kept)
