"""benchmarks/cost_model.py: the episodes it counts are the train loop's, exactly, under both evaluation
protocols; its schedules are the Evaluator's and warmup's; the script measures at tiny sizes and writes its
JSON with the command that made it (figures are not asserted: speed belongs to the script, not to tests)."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "OMP_NUM_THREADS": "1", "HF_HUB_OFFLINE": "1", "MUJOCO_GL": "egl", "RERUN": "off"}


@pytest.fixture(scope="module")
def cm():
    spec = importlib.util.spec_from_file_location("cost_model", ROOT / "benchmarks" / "cost_model.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_headline_cell_evaluates_9900_episodes_before_and_5250_after(cm):
    # 3 stages, 11 grid points, 50 selection + 100 report episodes per task and point
    cell = cm.spec_cells("contact-headline")[0]
    counts = cm.episode_counts(cell.workflow)
    assert counts["train_eval_old"] == 11 * 150 * (1 + 2 + 3) == 9_900
    # the current task at every point on both sets; earlier tasks once, on the report set
    assert counts["train_eval_new"] == 3 * 11 * 150 + (0 + 1 + 2) * 100 == 5_250
    assert counts["evaluate_all"] == 2 * 100 * (1 + 2 + 3)  # actor and base policy alone, report set
    assert counts["warmup_at_least"] == 3 * 16


def test_without_a_report_set_earlier_tasks_are_scored_once_on_the_selection_set(cm):
    config = {"task_ids": ["a", "b"], "eval_episodes": 30, "env_steps": 12_000, "eval_every": 6_000}
    assert cm.train_eval_calls(config, "old") == [("a", 3, 30), ("b", 3, 30)]
    assert cm.train_eval_calls(config, "new") == [("a", 1, 30), ("b", 3, 30)]
    assert cm.evaluate_all_calls({"task_ids": ["a"], "episodes": 30}) == [("a", 30, True), ("a", 30, False)]


def test_the_evaluation_schedule_is_the_evaluators(cm):
    """eval_chunks counts the chunk steps rl_loop.Evaluator takes on an env whose episodes last a given number
    of chunks (the same scheduling: an ended env restarts while fewer than M episodes have started)."""
    from accrue import rl_loop

    lengths = (3, 5, 2, 7, 4)

    class Env:
        """Episodes of lengths[j] chunks, the j-th episode started; stepped only where one runs."""

        def __init__(self, n):
            self.num_envs, self.episode, self.calls = n, np.full(n, -1), 0
            self.left, self.started = np.zeros(n, int), 0

        def reset(self, mask=None):
            for i in np.arange(self.num_envs) if mask is None else np.flatnonzero(mask):
                self.episode[i] += 1
                self.left[i], self.started = lengths[self.started % len(lengths)], self.started + 1
            return {"state": np.zeros((self.num_envs, 1))}

        def step_chunk(self, a, gamma):
            self.calls += 1
            self.left -= 1
            done, no = self.left == 0, np.zeros(self.num_envs, bool)
            return SimpleNamespace(terminated=done, truncated=no, success=no, obs={"state": a[:, 0, :1]})

    for n, episodes in ((4, 10), (8, 5), (3, 9)):
        env = Env(min(n, episodes))
        reference = {"t": lambda o: np.zeros((len(o["state"]), 1, 6))}
        ev = rl_loop.Evaluator(lambda t, k, env=env: env, reference, lambda o: o["state"], episodes, n, 1, 0.99)
        ev.success_rate("t")
        assert cm.eval_chunks(episodes, n, lengths) == env.calls


def test_warmup_runs_until_its_episodes_have_ended(cm):
    # 2 envs, episodes of 3 chunks: 4 episodes end after 6 chunk steps
    assert cm.warmup_chunks(4, 2, (3,)) == 6
    assert cm.warmup_chunks(5, 2, (3,)) == 9
    assert cm.warmup_chunks(0, 2, (3,)) == 1  # at least one chunk


def test_steps_shared_through_the_cache_have_one_key(cm):
    headline = {c.name: c for c in cm.spec_cells("contact-headline")}
    accrue = next(c for c in headline.values() if (c.method, c.ordering, c.seed) == ("accrue", "RKG", 0))
    seq = next(c for c in headline.values() if (c.method, c.ordering, c.seed) == ("sequential", "RKG", 0))
    other = next(c for c in headline.values() if (c.method, c.ordering, c.seed) == ("accrue", "RGK", 0))
    a, s, o = (cm.step_keys(cm.cell_plans(c.workflow)) for c in (accrue, seq, other))
    for stage in (1, 2, 3):  # methods share the demos, the fine-tunes and the warmups
        for step in ("record-demos", "finetune-base", "warmup"):
            assert a[(stage, step)] == s[(stage, step)]
        assert a[(stage, "train")] != s[(stage, "train")]
    assert a[(1, "finetune-base")] == o[(1, "finetune-base")]  # the same first task
    assert a[(2, "finetune-base")] != o[(2, "finetune-base")]  # another prefix
    # the ablations' accrue row is the headline's cells, step for step
    ablation = next(
        c for c in cm.spec_cells("contact-ablations") if (c.method, c.ordering, c.seed) == ("accrue", "RKG", 0)
    )
    assert cm.step_keys(cm.cell_plans(ablation.workflow)) == a


def test_the_script_measures_at_tiny_sizes_and_writes_its_json(tmp_path):
    out = tmp_path / "cost.json"
    args = ["--measure", "--specs", "contact-learner", "--episodes", "2", "--updates", "4", "--no-validation"]
    subprocess.run(
        [sys.executable, "benchmarks/cost_model.py", *args, "--out", str(out)],
        cwd=ROOT,
        env=ENV,
        check=True,
        capture_output=True,
        text=True,
    )
    result = json.loads(out.read_text())
    assert result["command"] == "python benchmarks/cost_model.py " + " ".join(args)  # --out changes no figure
    coef = result["coefficients"]
    assert set(coef) == {"physics", "learner", "base_policy", "finetune", "overhead", "demo_success"}
    for row in [*coef["physics"].values(), *coef["learner"].values()]:
        assert "load_avg_1min" in row
    assert all(p["control_steps_per_s"] > 0 and p["episode_chunks"] for p in coef["physics"].values())
    assert all(r["first_update_s"] > 0 and r["later_update_s"] > 0 for r in coef["learner"].values())
    proj = result["projections"]["contact-learner"]
    assert proj["cells"] == cm_cells("contact-learner")
    assert set(proj["grid_h"]) == {"2", "16"} and set(proj["cell_min"]) == {"old", "new"}
    assert "full grid" not in result["projections"]  # one spec of the grid or none: no full grid
    # without --measure it projects again from the coefficients it wrote, and --markdown prints the table
    md = subprocess.run(
        [
            sys.executable,
            "benchmarks/cost_model.py",
            "--specs",
            "contact-learner",
            "--no-validation",
            "--coefficients",
            str(out),
            "--out",
            str(tmp_path / "again.json"),
            "--markdown",
        ],
        cwd=ROOT,
        env=ENV,
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    assert md.startswith("| spec | cells |") and "`contact-learner`" in md
    again = json.loads((tmp_path / "again.json").read_text())
    assert again["coefficients"] == coef and again["projections"] == result["projections"]


def cm_cells(name: str) -> int:
    from stages.bench.spec import load_spec

    return len(load_spec(ROOT / "workflows" / "bench" / f"{name}.yaml").cells)


def test_perf_report_model_row_projects_the_grid_from_the_committed_coefficients(tmp_path):
    out = tmp_path / "perf.json"
    out.write_text(json.dumps({"grid": {"kept": True}}))
    subprocess.run(
        [sys.executable, "benchmarks/perf_report.py", "--row", "model", "--out", str(out)],
        cwd=ROOT, env=ENV, check=True, capture_output=True, text=True,
    )  # fmt: skip
    rows = json.loads(out.read_text())
    assert rows["grid"] == {"kept": True}  # the store-based row stays as it was
    row = rows["model"]
    assert row["command"] == "python benchmarks/perf_report.py --row model"
    assert set(row["full_grid_h"]) == {"2", "16"} and set(row["full_grid_h"]["2"]) == {"old", "new"}
    assert {"contact-headline", "contact-ablations", "bias-control", "full grid"} <= set(row["cell_min"])
    assert row["coefficients_date"] and len(row["coefficients_load_avg_1min"]) == 2
