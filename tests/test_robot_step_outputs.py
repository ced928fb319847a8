"""warmup, train and evaluate-all on a robot (stages.steps.robot_env) and in the simulator (sim_env): the
step code versions the caches key on, a stop while a robot step writes its outputs, a crash in the
simulator's optional episode logs, and Isolated's per-task learners on a robot."""

from __future__ import annotations

from pathlib import Path

import pytest

pytestmark = pytest.mark.timeout(600)
ROOT = Path(__file__).resolve().parents[1]


def test_step_code_versions_are_those_the_caches_key_on(tmp_path):
    """The simulator's from each STEP, the robot's from robot_env.CODE_VERSIONS (one place each): a changed
    code version would re-run every cached step."""
    from artifacts.store import Store
    from stages.plan import plan_stage
    from stages.workflow import load_workflow

    store = Store.init(tmp_path / "store")[0]
    versions = {}
    for name in ("quickstart", "hardware-sim"):
        plan = plan_stage(load_workflow(ROOT / "workflows" / f"{name}.yaml"), 1, store)
        versions[name] = {inv.step.name: inv.step.code_version for inv in plan.steps}
    assert {s: versions["quickstart"][s] for s in ("warmup", "train", "evaluate-all")} == {
        "warmup": "warmup-2",
        "train": "train-3",
        "evaluate-all": "evaluate-all-1",
    }
    assert {s: versions["hardware-sim"][s] for s in ("warmup", "train", "evaluate-all")} == {
        "warmup": "hw-warmup-1",
        "train": "hw-train-2",
        "evaluate-all": "hw-evaluate-all-1",
    }


# ------------------------------------------------------------------ a stop while a robot step writes its outputs


@pytest.fixture(scope="module")
def base_store(tmp_path_factory):
    """A store with stage 1's finetune-base done on tests/test_robot_hold's workflow (train: 3 episodes)."""
    from test_robot_hold import hold_workflow, run_stage

    from artifacts.store import Store

    root = tmp_path_factory.mktemp("outputs-base")
    Store.init(root / "store")
    run_stage(root / "store", hold_workflow(root / "hw.yaml", root / "calib"), 1, step="finetune-base")
    return root


@pytest.fixture
def store(base_store, tmp_path):
    import shutil

    shutil.copytree(base_store / "store", tmp_path / "store")
    return tmp_path


def ctrl_c_at_write_json(monkeypatch, module) -> None:
    """Ctrl-C (SIGINT to this process, handled in the main thread as a person's) when `module` (a step)
    writes its JSON output: after its robot session, while it writes its outputs."""
    import signal

    from stages.steps import common

    def interrupted(path, data):
        signal.raise_signal(signal.SIGINT)
        common.write_json(path, data)

    monkeypatch.setattr(module, "write_json", interrupted)


def test_a_stop_while_a_robot_step_writes_its_outputs_says_how_to_resume(store, monkeypatch):
    """Each robot step, stopped after its session (writing replay / checkpoint / eval.json): the line
    names the sealed episodes and --continue, as a stop in the session does (it was a bare "stopped by
    operator (Ctrl-C)"); --continue then commits the step from what was sealed, running no episode again."""
    from test_robot_hold import fake_link, hold_workflow, robot_events, run_stage, use_link

    from stages.steps import evaluate_all, train, warmup
    from stages.steps.robot_session import SessionStop

    wf = hold_workflow(store / "hw.yaml", store / "calib")
    use_link(monkeypatch, store / "store", fake_link())
    sealed = {"warmup": 3, "train": 3, "evaluate-all": 0}  # stage 1 has no earlier task to retain
    for step, module in (("warmup", warmup), ("train", train), ("evaluate-all", evaluate_all)):
        with monkeypatch.context() as m:
            ctrl_c_at_write_json(m, module)
            with pytest.raises(SessionStop) as err:
                run_stage(store / "store", wf, 1, step=step)
        line = str(err.value)
        assert err.value.code == 130 and "\n" not in line
        assert line.startswith(f"{step}: stopped by operator (Ctrl-C); {sealed[step]} episodes sealed"), line
        assert f"(resume with `accrue stage run ... --step {step} --continue`)" in line
        before = len(robot_events(store / "store", "robot-episode-sealed"))
        assert run_stage(store / "store", wf, 1, step=step, mode="continue")[step].record_id
        assert len(robot_events(store / "store", "robot-episode-sealed")) == before
