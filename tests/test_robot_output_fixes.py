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


def test_a_short_memory_is_said_in_words_too():
    """Before: `handoff: stage 1 ended fewer than N = 20 episodes ({'0': 16}); the memory keeps what there is`."""
    from stages.steps.handoff import episodes_text

    assert (
        episodes_text({"0": 16}) == "16 of task 1" and episodes_text({"1": 3, "0": 20}) == "20 of task 1, 3 of task 2"
    )


@pytest.fixture
def warmup_store(tmp_path):
    from artifacts.store import Store

    Store.init(tmp_path / "store")
    return tmp_path


def hw_workflow(tmp_path: Path, **robot) -> Path:
    import yaml
    from robot_workflow import write_hw_workflow

    wf = write_hw_workflow(tmp_path / "hw.yaml", tmp_path / "calib")
    spec = yaml.safe_load(wf.read_text())
    spec["robot"].update(robot)
    wf.write_text(yaml.safe_dump(spec, sort_keys=False))
    return wf


def test_the_page_shows_the_stop_window_the_steps_run_and_an_ended_episode_at_its_label(warmup_store, monkeypatch):
    """Before: `success (last 20)` with 20 marks when stop_window was 3, and at the label prompt the page
    still said `episode 0 running` and `step 32` of a 30-step episode (a step per chunk of 4 was added)."""
    from robot_workflow import run_stage

    from accrue.robot.operator import ScriptedOperator

    seen: list[tuple[str, dict]] = []
    monkeypatch.setattr(ScriptedOperator, "show", lambda self, state: seen.append(("show", dict(state))))
    plain_label = ScriptedOperator.label
    monkeypatch.setattr(
        ScriptedOperator,
        "label",
        lambda self, *a: (seen.append(("label", {"episode": a[0]})), plain_label(self, *a))[1],
    )
    wf = hw_workflow(warmup_store, stop_window=3, stop_successes=3, episode_steps=30)
    run_stage(warmup_store / "store", wf, 1, step="warmup")
    shown = [s for kind, s in seen if kind == "show"]
    assert shown and all(s["window_size"] == 3 and s["max_steps"] == 30 for s in shown), [
        (s.get("window_size"), s.get("max_steps")) for s in shown
    ]
    assert all(0 <= s["step"] <= 30 for s in shown)
    labels = [i for i, (kind, _) in enumerate(seen) if kind == "label"]
    assert len(labels) == 3
    for i in labels:  # what the page showed while the operator labelled
        before = seen[i - 1][1]
        assert (
            before["status"].startswith(f"episode {seen[i][1]['episode']} ended (") and "label it" in before["status"]
        )
        assert "running" not in before["status"]


def test_the_page_words_the_window_and_interventions_as_a_person_reads_them():
    """Before: `success (last 20)` fixed in the page, and `18 steps this episode window rate 0.0% of steps`."""
    from accrue.robot.operator_page import PAGE

    assert "success (last 20)" not in PAGE and "length: 20 }" not in PAGE and "window rate" not in PAGE
    assert '"success (last " + size + ")"' in PAGE and " steps driven in this episode" in PAGE
    assert '% of the steps of the last " + size + " sealed episodes)' in PAGE


def test_the_last_warmup_episode_can_be_relabelled(warmup_store, capsys):
    """Before: a re-label is offered at the next reset prompt only, and the last episode of a step has none.
    Warmup also says how far it is, with its rate and the time left (before: one line at its end)."""
    from robot_workflow import robot_events, run_stage

    wf = hw_workflow(warmup_store, scripted={"mistakes": [2], "corrects": [2]})
    run_stage(warmup_store / "store", wf, 1, step="warmup")
    [relabelled] = robot_events(warmup_store / "store", "robot-episode-relabelled")
    assert relabelled["index"] == 2  # warmup's third and last episode
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warmup: episode ")]
    assert [line.split(" (")[0] for line in lines] == [f"warmup: episode {n}/3" for n in (1, 2, 3)]
    assert " episodes/s, " in lines[0] and lines[0].endswith(" left)") and lines[-1].endswith(", done)")


def test_a_terminal_operator_relabels_the_last_episode_at_the_steps_end(warmup_store, monkeypatch):
    from rich.console import Console
    from robot_workflow import robot_events, run_stage

    from accrue.robot import operator as operator_module

    said: list[str] = []

    class Keyed(operator_module.TerminalOperator):
        def __init__(self, name, console=None, audit=None):
            self.name, self.console, self._saved, self._audit = name, Console(file=None, quiet=True), None, audit
            self.typed = list("rsrsrs" + "x" + "lf" + "r")  # 3 episodes, a wrong key, re-label 2 a failure, finish

        def _key(self, timeout):
            return None if timeout == 0 else self.typed.pop(0)

        def _say(self, line):
            said.append(line)

    monkeypatch.setattr(operator_module, "TerminalOperator", Keyed)
    wf = hw_workflow(warmup_store, operator="terminal")
    run_stage(warmup_store / "store", wf, 1, step="warmup")
    [relabelled] = robot_events(warmup_store / "store", "robot-episode-relabelled")
    assert relabelled["index"] == 2 and relabelled["success"] is False
    assert any(line.startswith("warmup (nist/rect_peg): 3 episodes sealed: press r to finish") for line in said)
    assert "key 'x' does nothing here; keys now: r=finish  l=re-label last  a=abort" in said


def test_stage_status_says_which_episodes_faulted_and_how(warmup_store):
    """Before: `robot — stage 1 warmup (committed): 3 episodes, ..., 1 with faults` and nothing on which or why."""
    import re

    from robot_workflow import run_stage, write_hw_workflow

    from artifacts.store import Store
    from cli.hw_status_view import fault_text
    from stages.steps.robot_status import robot_status
    from stages.workflow import load_workflow

    wf = write_hw_workflow(warmup_store / "hw.yaml", warmup_store / "calib", faults="{disconnect_after_steps: 30}")
    run_stage(warmup_store / "store", wf, 1, step="warmup")
    [row] = robot_status(Store.open(warmup_store / "store"), load_workflow(wf))
    text = fault_text(row)
    assert re.fullmatch(r"1 with faults \(episode \d, ended fault: .*disconnect.*\)", text), text
    assert fault_text({"faults": 0, "fault_episodes": []}) == "no faults"


def test_a_learner_started_by_hand_writes_nothing_into_the_working_directory(tmp_path, monkeypatch, capsys):
    """Before: `accrue robot learner` wrote ./accrue-tracking/<run> wherever it was started."""
    from accrue.robot.learner_service import LearnerService

    monkeypatch.chdir(tmp_path)
    tracking = {"spec": {"tensorboard": True}, "run_name": "hw/stage-1/train/learner", "log_dir": "/elsewhere"}
    by_hand = LearnerService()
    by_hand._open_tracking(tracking)
    assert by_hand.tracker is None and list(tmp_path.iterdir()) == []
    assert "tracking off for this run" in capsys.readouterr().out

    kept = LearnerService(tracking_root=tmp_path / "store" / "log" / "tracking")
    kept._open_tracking(tracking)
    kept.tracker.scalars({"learner/updates": 1.0}, 1)
    kept.close_tracking()
    assert (tmp_path / "store" / "log" / "tracking" / "hw" / "stage-1" / "train" / "learner").is_dir()
    assert [p.name for p in tmp_path.iterdir()] == ["store"]
