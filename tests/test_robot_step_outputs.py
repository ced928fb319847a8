"""warmup, train and evaluate-all on a robot (stages.steps.robot_env) and in the simulator (sim_env): the
step code versions the caches key on, a stop while a robot step writes its outputs, a crash in the
simulator's optional episode logs, and Isolated's per-task learners on a robot."""

from __future__ import annotations

from pathlib import Path

import pytest
from test_robot_stops import base_store, store  # noqa: F401 - stage 1's finetune-base done, a copy per test

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


# ------------------------------------------------------------------ Isolated on a robot


def test_isolated_keeps_each_tasks_learner_on_a_robot(store, monkeypatch):
    """Isolated (accrue.methods: checkpoint_per_task) serves task i with the learner kept after stage i. On a
    robot stage 2's train dropped stage 1's kept learner (its checkpoint had no per_task/1) and evaluate-all
    ran every retention trial with the current learner; now task 1's trials act with the learner kept for it."""
    import json

    from test_robot_hold import fake_link, hold_workflow, run_stage, use_link

    from accrue import rl_loop
    from artifacts.manifests import materialize
    from artifacts.store import Store
    from stages.steps import evaluate_all

    wf = hold_workflow(store / "hw.yaml", store / "calib")
    wf.write_text(wf.read_text().replace("method: accrue\n", "method: isolated\n"))
    use_link(monkeypatch, store / "store", fake_link())
    run_stage(store / "store", wf, 1)
    seen: dict = {}
    acted: list = []
    real_deployed, real_act = evaluate_all.deployed, rl_loop.actor_act
    monkeypatch.setattr(evaluate_all, "deployed", lambda ctx, tasks: seen.setdefault("d", real_deployed(ctx, tasks)))
    monkeypatch.setattr(rl_loop, "actor_act", lambda learner: acted.append(learner) or real_act(learner))
    results = run_stage(store / "store", wf, 2)

    s = Store.open(store / "store")
    ck = json.loads(
        (materialize(s, results["train"].outputs["checkpoint"], store / "ck") / "checkpoint.json").read_text()
    )
    assert ck["method"] == "isolated" and ck["per_task"] == [1]
    ev = json.loads((materialize(s, results["evaluate-all"].outputs["eval"], store / "ev") / "eval.json").read_text())
    assert ev["per_task_checkpoint"] == ["nist/rect_peg"] and len(ev["trials"]["nist/rect_peg"]) == 3
    kept = seen["d"].learners["nist/rect_peg"]
    assert kept is not seen["d"].current
    assert any(learner is kept for learner in acted) and not any(learner is seen["d"].current for learner in acted)


def test_the_robot_learner_writes_its_scalars_where_the_plan_bound_trains_run(tmp_path):
    """One path for the run a train step's scalars go to (stage_io.tracking_run): the robot's learner took
    the session's tracking and the store's log dir and ignored the run the plan bound (its root)."""
    from types import SimpleNamespace

    from stages.steps.robot_env import learner_tracking
    from stages.steps.robot_session import SessionSettings

    ctx = SimpleNamespace(step="train", config={"workflow": "hw"}, store=SimpleNamespace(root=tmp_path / "store"))
    bound = {"spec": {"every": 7, "tensorboard": False}, "workflow": "hw", "root": str(tmp_path / "runs")}
    got = learner_tracking(ctx, bound, SessionSettings(), 2)
    assert got["run_name"] == "hw/stage-2/train/learner"
    assert got["log_dir"] == str(tmp_path / "runs" / "hw" / "stage-2" / "train" / "learner")
    assert got["spec"]["every"] == 7 and got["spec"]["tensorboard"] is False
    unbound = learner_tracking(ctx, None, SessionSettings(tracking={"every": 3}), 2)
    assert unbound["log_dir"] == str(tmp_path / "store" / "log" / "tracking" / "hw" / "stage-2" / "train" / "learner")
    assert unbound["spec"]["every"] == 3


# ------------------------------------------------------------------ the simulator's optional episode logs

TINY_SIM = """
name: logs
tasks: [nist/rect_peg]
method: accrue
seed: 1
horizon: 4
base_policy: {init: "scripted-reference:0.0"}
learner: {actor_hidden: [32, 32], critic_hidden: [32, 32], projector_dim: 16, batch_size: 32, num_atoms: 11, utd: 1}
budgets: {env_steps: 80, eval_every: 40, eval_episodes: 2, num_envs: 2, warmup_episodes: 2,
          retained_episodes: 2, checkpoint_every: 40, log_episodes: 1}
"""


def test_a_crash_in_the_simulators_episode_logs_keeps_the_evaluation(tmp_path, monkeypatch):
    """evaluate-all's success rates are sealed before its MCAP episode logs are written: after a crash in
    those, --continue writes the logs and the same eval.json without evaluating again (it evaluated every
    task again). A rerun from scratch gives the same eval artifact."""
    from test_robot_hold import run_stage

    from accrue import rl_loop
    from artifacts.manifests import materialize
    from artifacts.store import Store

    (tmp_path / "logs.yaml").write_text(TINY_SIM)
    Store.init(tmp_path / "store")
    wf = tmp_path / "logs.yaml"
    real_record = rl_loop.record_episodes
    with monkeypatch.context() as m:

        def broken(*a, **kw):
            raise OSError("disk full")

        m.setattr(rl_loop, "record_episodes", broken)
        with pytest.raises(OSError, match="disk full"):
            run_stage(tmp_path / "store", wf, 1, step="evaluate-all")
    with monkeypatch.context() as m:

        def evaluated_again(*a, **kw):
            raise AssertionError("evaluated again")

        m.setattr(rl_loop.Evaluator, "success_rate", evaluated_again)
        m.setattr(rl_loop, "record_episodes", real_record)
        resumed = run_stage(tmp_path / "store", wf, 1, step="evaluate-all", mode="continue")["evaluate-all"]
    s = Store.open(tmp_path / "store")
    logs = materialize(s, resumed.outputs["episodes"], tmp_path / "episodes")
    assert list(logs.rglob("*.mcap"))
    fresh = run_stage(tmp_path / "store", wf, 1, step="evaluate-all", mode="rerun")["evaluate-all"]
    assert fresh.outputs["eval"] == resumed.outputs["eval"]


def test_robot_status_finds_every_robot_steps_attempts():
    """`accrue stage status` tells the robot steps' attempts from the simulator's by their code version."""
    from stages.steps.robot_env import CODE_VERSIONS
    from stages.steps.robot_status import ROBOT_CODE_VERSION_PREFIX, ROBOT_STEPS

    assert set(ROBOT_STEPS) == set(CODE_VERSIONS)
    assert all(v.startswith(ROBOT_CODE_VERSION_PREFIX) for v in CODE_VERSIONS.values())
