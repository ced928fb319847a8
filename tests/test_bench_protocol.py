"""Issue 18's protocol: the best checkpoint is chosen on one episode set (the "eval" seeds) and reported on a
disjoint one (the "report" seeds), in the train loop, in the plan's cache keys and in the bench report."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from test_bench_report import BASE  # tests/ is on sys.path (rootdir conftest, no package)

from accrue import rl_loop
from accrue.learner import LearnerConfig, ReplayBuffer, make_learner
from accrue.learner_inputs import state_features
from accrue.sim import STATE_DIM, make_vec_env
from artifacts.store import Store
from stages.bench.report import build_report, markdown, write_report
from stages.bench.spec import load_spec
from stages.plan import plan_stage
from stages.report.data import EVALUATE, SOURCES, TRAIN, load_run
from stages.report.summary import summarize
from stages.runner import Runner
from stages.runner_types import STEP_NAMES, StagePlan, StepDef, StepInvocation
from stages.workflow import parse_workflow

TASK, H, N = "nist/rect_peg", 4, 2


def test_report_seeds_are_disjoint_from_selection_seeds_and_ignore_the_stage():
    for seed in (0, 3):
        selection = {rl_loop.env_seed(seed, 1, "eval", i) for i in range(10)}
        report = {rl_loop.env_seed(seed, 1, "report", i) for i in range(10)}
        others = {rl_loop.env_seed(seed, k, p) for k in range(1, 6) for p in ("warmup", "train")}
        assert not selection & report and not (selection | report) & others
        assert rl_loop.env_seed(seed, 1, "report", 2) == rl_loop.env_seed(seed, 4, "report", 2)
    # different seeds, different episodes: the first observations of the two sets differ
    a = make_vec_env(TASK, N, seed=rl_loop.env_seed(0, 1, "eval", 0)).reset()["state"]
    b = make_vec_env(TASK, N, seed=rl_loop.env_seed(0, 1, "report", 0)).reset()["state"]
    assert not np.allclose(a, b)


class FixedRate:
    """An evaluator stand-in whose success rate names the set it was measured on."""

    def __init__(self, rate: float, report=None):
        self.rate, self.report, self.calls = rate, report, 0

    def success_rate(self, task_id, act=None):
        self.calls += 1
        return self.rate

    def close(self):
        pass


def reference(obs):
    s = np.asarray(obs["state"], dtype=np.float32)
    a = np.zeros((len(s), 6), dtype=np.float32)
    a[:, 2] = -0.6
    return np.repeat(a[:, None, :], H, axis=1)


def test_train_loop_scores_every_grid_point_on_both_sets(one_torch_thread):
    cfg = LearnerConfig(actor_hidden=[16], critic_hidden=[16], projector_dim=8, batch_size=16, num_atoms=11, utd=1)
    learner = make_learner(cfg, STATE_DIM, H)
    buf = ReplayBuffer(STATE_DIM, H)
    col = rl_loop.ChunkCollector(make_vec_env(TASK, N, seed=11), reference, state_features, buf, 0, 0.99)
    col.restart()
    rl_loop.warmup(col, 1)
    report = FixedRate(0.75)
    evaluator = FixedRate(0.25, report)
    settings = rl_loop.LoopSettings([TASK], env_steps=3 * N * H, eval_every=N * H, checkpoint_every=0)
    state = rl_loop.train_loop(learner, col, evaluator, settings)
    assert state.grid_done == settings.grid() == [0, 8, 16, 24]
    assert state.curve == {TASK: [0.25] * 4} and state.report_curve == {TASK: [0.75] * 4}
    assert report.calls == evaluator.calls == 4
    # no report set (every run before the split): the report curve stays empty, nothing else changes
    alone = rl_loop.train_loop(learner, col, FixedRate(0.25), settings)
    assert alone.report_curve == {} and alone.curve == {TASK: [0.25] * 4}


def test_report_episodes_enter_the_cache_keys_only_when_used(tmp_path):
    store = Store.init(tmp_path / "store")[0]
    old = parse_workflow(BASE, "base")
    new = parse_workflow({**BASE, "budgets": {**BASE["budgets"], "report_episodes": 100}}, "base")
    steps_old = {s.step.name: s.config for s in plan_stage(old, 1, store).steps}
    steps_new = {s.step.name: s.config for s in plan_stage(new, 1, store).steps}
    assert "report_episodes" not in steps_old["train"] and "report_episodes" not in steps_old["evaluate-all"]
    assert steps_new["train"]["report_episodes"] == steps_new["evaluate-all"]["report_episodes"] == 100
    assert steps_old["finetune-base"] == steps_new["finetune-base"]  # the fine-tunes stay shared


def stand_in(name: str, files) -> StepDef:
    role, filename = SOURCES.get(name, ("out", "out.json"))
    kind = "eval" if name in SOURCES else "checkpoint"

    def run(ctx):
        (ctx.new_output(role, kind) / filename).write_text(json.dumps(files(ctx.config)))

    return StepDef(name=name, code_version="stand-in-1", run=run, outputs={role: kind})


def commit_cell(store: Store, cell, selection: dict, report: dict | None) -> None:
    tasks = cell.tasks

    def files_for(step):
        def files(config):
            k = config["stage"]
            if step == TRAIN:
                data = {
                    "stage": k,
                    "task_ids": tasks[:k],
                    "grid": [0, 50, 100],
                    "success": {t: selection[k][i] for i, t in enumerate(tasks[:k])},
                    "episodes_per_point": 10,
                }
                if report is not None:
                    data.update(report_success={t: report[k][i] for i, t in enumerate(tasks[:k])}, report_episodes=100)
                return data
            if step == EVALUATE:
                last = {t: 0.5 for t in tasks[:k]}
                return {"stage": k, "task_ids": tasks[:k], "success": last, "base_success": last, "episodes": 10}
            return {"stage": k}

        return files

    runner = Runner(store)
    for k in (1, 2):
        steps = tuple(
            StepInvocation(step=stand_in(s, files_for(s)), config={"cell": cell.name, "stage": k}) for s in STEP_NAMES
        )
        runner.run_plan(StagePlan(workflow=cell.name, stage=k, steps=steps))


PREDICTION = {"prediction": "transfers more", "metric": "FWT_no0", "reference_is": "higher", "than": ["single-task"]}
# stage 1 picks e* = 1 on the selection set (0.9), where the report set says 0.4 (its own max, 0.8, is at e = 2)
SELECTION = {1: [[0.1, 0.9, 0.5]], 2: [[0.6, 0.2, 0.2], [0.0, 0.3, 0.7]]}  # stage 2: e* = 2
REPORT = {1: [[0.0, 0.4, 0.8]], 2: [[0.5, 0.5, 0.1], [0.2, 0.2, 0.6]]}


def test_bench_report_reads_the_report_set_and_says_which_runs_have_one(tmp_path):
    (tmp_path / "base.yaml").write_text(yaml.safe_dump(BASE))
    spec_file = tmp_path / "p.yaml"
    spec_file.write_text(
        yaml.safe_dump(
            {
                "base": "base.yaml",
                "methods": {"accrue": {}, "single-task": {}},
                "orderings": {"S1": BASE["tasks"]},
                "seeds": [0, 1],
                "predictions": [PREDICTION],
            }
        )
    )
    spec = load_spec(spec_file)
    store = Store.init(tmp_path / "store")[0]
    commit_cell(store, spec.cell("accrue", "S1", 0), SELECTION, REPORT)
    commit_cell(store, spec.cell("accrue", "S1", 1), SELECTION, None)  # a run from before the split
    report = build_report(store, spec)
    by_seed = {c["seed"]: c for c in report["cells"] if c["method"] == "accrue"}
    new, old = by_seed[0], by_seed[1]
    assert new["disjoint_report"] is True and old["disjoint_report"] is False
    # with the report set: c_{1,1} = 0.4, c_{2,1} = 0.1, c_{2,2} = 0.6 (report values at e* = 1, 2)
    assert new["metrics"]["ACC_final"] == pytest.approx((0.1 + 0.6) / 2)
    assert new["metrics"]["F_final"] == pytest.approx(0.4 - 0.1)
    assert new["metrics"]["FWT"] == pytest.approx((0.4 + 1.0 / 3) / 2)  # the report set's own curves
    assert new["metrics"]["FWT_no0"] == pytest.approx((0.6 + 0.4) / 2)
    assert new["metrics"]["jumpstart"] == pytest.approx(0.1)
    assert new["metrics"]["T_thr"] == pytest.approx((100 + 100) / 2)  # 0.8 at 100; 0.6 at 100
    # without it, the selection set scores its own max: c_{1,1} = 0.9, c_{2,1} = 0.2, c_{2,2} = 0.7
    assert old["metrics"]["ACC_final"] == pytest.approx((0.2 + 0.7) / 2)
    assert old["metrics"]["F_final"] == pytest.approx(0.9 - 0.2)
    assert report["runs_with_report_set"] == 1
    # the stage curves average the report set of the new run with the one set of the old: stage 1 at e = 2
    assert report["stage_curves"]["accrue"][0]["current"][2]["mean"] == pytest.approx((0.8 + 0.5) / 2)
    text = markdown(report)
    assert "1 of 2 runs have a disjoint report set" in text
    # the declared prediction is judged and shown: single-task has no run, so it is not resolved
    [judged] = report["predictions"]
    assert judged["verdict"] == "not resolved" and judged["against"][0]["verdict"] == "no runs"
    assert "Predictions the spec declared before its runs" in text
    assert "| method | pairs | ΔFWT_no0 | Δjumpstart | ΔT_thr |" in text and "| single-task | 0 | — | — | — |" in text
    assert "| transfers more | accrue higher on FWT_no0 | single-task | — | no runs | **not resolved** |" in text
    files = write_report(report, tmp_path / "out")
    rows = {
        r["seed"]: r
        for r in csv.DictReader(io.StringIO(Path(files["cells_csv"]).read_text()))
        if r["method"] == "accrue"
    }
    assert (rows["0"]["disjoint_report"], rows["1"]["disjoint_report"]) == ("true", "false")
    assert float(rows["0"]["FWT_no0"]) == pytest.approx(0.5)
    summary = list(csv.DictReader(io.StringIO(Path(files["summary_csv"]).read_text())))
    assert any(r["metric"] == "T_thr" and r["method"] == "accrue" and r["ordering"] == "all" for r in summary)
    # a single run's report (`accrue report`) reads the same set
    single = summarize(load_run(store, spec.cell("accrue", "S1", 0).workflow))
    assert single["disjoint_report"] is True and single["success_matrix"][0][0] == 0.4
    assert summarize(load_run(store, spec.cell("accrue", "S1", 1).workflow))["success_matrix"][0][0] == 0.9
