"""accrue.tracking (issue 21 item 7): TensorBoard event files read back with tensorboard's own reader,
W&B offline, a missing wandb in one line, write failures that never end the run, and the hooks in
the train step (tags written, artifact ids the same with tracking on and off)."""

from __future__ import annotations

import glob
import importlib.util
import sys
import time
from pathlib import Path

import pytest

from accrue.tracking import open_tracker, run_name, settings_of, tracking_dir


def read_scalars(log_dir: Path) -> dict[str, list[tuple[int, float]]]:
    """tag -> [(step, value)] from every event file under log_dir (tensorboard's EventAccumulator)."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(log_dir), size_guidance={"scalars": 0})
    acc.Reload()
    return {tag: [(e.step, e.value) for e in acc.Scalars(tag)] for tag in acc.Tags()["scalars"]}


def test_event_files_read_back_with_tags_and_values(tmp_path):
    lines: list[str] = []
    with open_tracker(None, tmp_path / "run", "wf/stage-1/train", warn=lines.append) as tracker:
        assert tracker.sinks == ["tensorboard"]
        tracker.scalar("train/critic_loss", 0.5, 10)
        tracker.scalar("train/critic_loss", 0.25, 20)
        tracker.scalars({"eval/success/a": 0.75, "eval/success/b": 1.0, "skipped": None}, 40)
        tracker.scalar("nan_dropped", float("nan"), 41)
    tracker.close()  # idempotent
    tracker.scalar("after_close", 1.0, 1)  # a closed tracker writes nothing and does not raise
    assert lines == []
    assert read_scalars(tmp_path / "run") == {
        "train/critic_loss": [(10, 0.5), (20, 0.25)],
        "eval/success/a": [(40, 0.75)],
        "eval/success/b": [(40, 1.0)],
    }


def test_settings_defaults_and_paths(tmp_path):
    assert settings_of(None) == {"tensorboard": True, "wandb": None, "every": 20}
    assert settings_of({"wandb": {"project": "p"}, "every": 5})["wandb"] == {
        "project": "p",
        "mode": "offline",
        "entity": None,
    }
    name = run_name("quick", 2, "train")
    assert name == "quick/stage-2/train"
    assert tracking_dir(tmp_path, name) == tmp_path / "log" / "tracking" / "quick" / "stage-2" / "train"


def test_tensorboard_off_writes_nothing(tmp_path):
    with open_tracker({"tensorboard": False}, tmp_path / "run", "x") as tracker:
        assert not tracker.enabled
        tracker.scalar("a", 1.0, 1)
    assert not (tmp_path / "run").exists()


def test_thinning_due_every_n_updates(tmp_path):
    with open_tracker({"every": 5}, tmp_path / "run", "x") as tracker:
        assert [u for u in range(1, 16) if tracker.due(u)] == [5, 10, 15]


def test_write_failure_is_one_warning_and_the_run_goes_on(tmp_path):
    lines: list[str] = []
    tracker = open_tracker(None, tmp_path / "run", "wf/stage-1/train", warn=lines.append)

    class Broken:
        name = "tensorboard"

        def write(self, values, step):
            raise OSError(28, "No space left on device")

        def flush(self):
            pass

        def close(self):
            pass

    tracker._sinks[0].close()
    tracker._sinks[0] = Broken()
    for step in range(5):
        tracker.scalar("train/critic_loss", 1.0, step)  # never raises
    tracker.close()
    assert len(lines) == 1, lines
    assert "tensorboard stopped after a failed write" in lines[0] and "No space left" in lines[0]


def test_unwritable_log_dir_is_one_warning(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    lines: list[str] = []
    with open_tracker(None, blocker / "run", "x", warn=lines.append) as tracker:
        assert not tracker.enabled
        tracker.scalar("a", 1.0, 1)
    assert len(lines) == 1 and "cannot write TensorBoard event files" in lines[0]


def test_wandb_asked_for_but_missing_is_one_line(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "wandb", None)  # `import wandb` raises ImportError
    lines: list[str] = []
    with open_tracker({"wandb": {"project": "p"}}, tmp_path / "run", "x", warn=lines.append) as tracker:
        assert tracker.sinks == ["tensorboard"]
        tracker.scalar("a", 1.0, 1)
    assert lines == ["tracking.wandb: wandb is not installed (pip install wandb); not logging to W&B"]
    assert read_scalars(tmp_path / "run") == {"a": [(1, 1.0)]}


def test_workflow_cli_error_for_a_bad_wandb_mode():
    from stages.errors import StageError
    from stages.workflow import parse_workflow

    data = {"tasks": ["a"], "method": "accrue", "budgets": {"env_steps": 10, "eval_every": 5}}
    assert parse_workflow(data, "wf.yaml").tracking.tensorboard is True
    with pytest.raises(StageError, match=r"^wf.yaml: tracking.wandb.mode: must be one of 'offline' or 'online'"):
        parse_workflow({**data, "tracking": {"wandb": {"mode": "cloud"}}}, "wf.yaml")
    with pytest.raises(StageError, match=r"^wf.yaml: tracking.tensorbord: unknown field"):
        parse_workflow({**data, "tracking": {"tensorbord": False}}, "wf.yaml")


@pytest.mark.skipif(
    importlib.util.find_spec("wandb") is None, reason="wandb is not installed (it comes with lerobot[training] 0.6.1)"
)
def test_wandb_offline_writes_its_run_without_a_network(tmp_path, monkeypatch):
    # no network: offline mode must not try one; a proxy to nowhere makes any attempt fail
    monkeypatch.setenv("HTTPS_PROXY", "http://127.0.0.1:9")
    monkeypatch.setenv("WANDB_API_KEY", "")
    lines: list[str] = []
    spec = {"tensorboard": False, "wandb": {"project": "accrue-test", "mode": "offline"}}
    with open_tracker(spec, tmp_path / "run", "wf/stage-1/train", warn=lines.append) as tracker:
        assert tracker.sinks == ["wandb"], lines
        tracker.scalar("train/critic_loss", 0.5, 10)
        tracker.scalars({"eval/success/a": 0.75}, 20)
    assert lines == []
    runs = glob.glob(str(tmp_path / "run" / "wandb" / "offline-run-*" / "run-*.wandb"))
    assert len(runs) == 1
    # wandb-core (its own process) may still be writing the records when run.finish() returns: seen here
    # as a 7-byte file (the header only) right after finish and ~1.3 kB a moment later. Wait for the
    # records to land, up to a deadline no machine misses, instead of reading once.
    deadline = time.monotonic() + 60
    while True:
        data = Path(runs[0]).read_bytes()
        if (b"train/critic_loss" in data and b"eval/success/a" in data) or time.monotonic() > deadline:
            break
        time.sleep(0.1)
    assert b"train/critic_loss" in data and b"eval/success/a" in data


# ------------------------------------------------------------------------------ the train step
TINY = """
name: tracked
tasks: [nist/rect_peg]
method: accrue
seed: 3
horizon: 4
base_policy: {init: "scripted-reference:0.5"}
learner: {actor_hidden: [16, 16], critic_hidden: [16, 16], projector_dim: 8, batch_size: 16, num_atoms: 11, utd: 1,
          learning_starts: 8}
budgets: {env_steps: 48, eval_every: 24, eval_episodes: 2, num_envs: 2, warmup_episodes: 2,
          retained_episodes: 2, checkpoint_every: 0, log_episodes: 0}
"""


def run_stage_one(tmp_path: Path, tracking: dict | None) -> tuple[dict, Path]:
    """Stage 1 in-process as `accrue run` plans it (plan_stage binds the workflow's tracking section to
    the train step); returns step -> output ids and the store root."""
    import yaml
    from rich.console import Console

    from artifacts.store import Store
    from stages.plan import plan_stage
    from stages.runner import Runner
    from stages.workflow import parse_workflow

    wf = parse_workflow({**yaml.safe_load(TINY), **({"tracking": tracking} if tracking else {})}, "tiny.yaml")
    store = Store.init(tmp_path / "store")[0]
    plan = plan_stage(wf, 1, store)
    results = Runner(store, console=Console(stderr=True, width=200)).run_plan(plan)
    return {r.step: r.outputs for r in results}, store.root


def test_train_step_writes_losses_q_and_eval_success_and_keeps_artifact_ids(tmp_path, monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    on, root = run_stage_one(tmp_path / "on", {"every": 4})
    off, root_off = run_stage_one(tmp_path / "off", {"tensorboard": False})
    assert on == off  # tracking changes no artifact, not even the train step's
    assert not (root_off / "log" / "tracking").exists()
    run_dir = root / "log" / "tracking" / "tracked" / "stage-1" / "train"
    scalars = read_scalars(run_dir)
    for tag in ("train/critic_loss", "train/q_mean", "train/updates", "train/episodes", "train/success_rate"):
        assert tag in scalars, sorted(scalars)
    updates = [v for _, v in scalars["train/updates"]]
    assert updates and all(u % 4 == 0 for u in updates)  # thinned to one point in `every` updates
    assert [s for s, _ in scalars["eval/success/nist/rect_peg"]] == [0, 24, 48]  # every grid point
    assert all(0.0 <= v <= 1.0 for _, v in scalars["eval/success/nist/rect_peg"])
    # nothing of it in the store's objects: the event files are only under log/tracking
    objects = {p.name for p in (root / "objects").rglob("*") if p.is_file()}
    assert not any("tfevents" in name for name in objects)


# ------------------------------------------------------------------------------ the robot learner
def documented_runs(workflow: str, stage: int) -> set[str]:
    """The store run directories docs/TRACKING.md's "Where the files go" table gives for robot steps,
    with <workflow> and <k> filled in and <step> each hardware step."""
    import re

    text = (Path(__file__).resolve().parents[1] / "docs" / "TRACKING.md").read_text()
    out = set()
    for row in re.findall(r"^\| robot .*?\| `<store>/log/tracking/([^`]+)/`", text, flags=re.M):
        row = row.replace("<workflow>", workflow).replace("<k>", str(stage))
        out |= {row.replace("<step>", step) for step in ("warmup", "train", "evaluate-all")}
    return out


@pytest.mark.slow
def test_robot_learner_writes_losses_q_updates_and_version(tmp_path, monkeypatch):
    """Stage 1 of the tiny hardware workflow on the simulated robot: the learner process the actor
    starts writes its run beside the actor's, under the store's log directory."""
    from robot_workflow import run_stage, write_hw_workflow

    from artifacts.store import Store

    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    Store.init(tmp_path / "store")
    wf = write_hw_workflow(tmp_path / "hw.yaml", tmp_path / "calib")
    run_stage(tmp_path / "store", wf, 1, step=None)
    root = tmp_path / "store" / "log" / "tracking"
    run_dir = root / "hw" / "stage-1" / "train" / "learner"
    # every run the stage wrote (warmup and train on the actor's side, the learner's inside train/) is
    # one docs/TRACKING.md lists; stage 1 has no earlier task, so no evaluate-all run
    runs = sorted({str(p.parent.relative_to(root)) for p in root.rglob("events.out.tfevents*")})
    assert runs == ["hw/stage-1/train", "hw/stage-1/train/learner", "hw/stage-1/warmup"]
    assert all(run in documented_runs("hw", 1) for run in runs), (runs, documented_runs("hw", 1))
    scalars = read_scalars(run_dir)
    for tag in ("learner/critic_loss", "learner/q_mean", "learner/updates", "learner/version", "learner/episodes"):
        assert tag in scalars, sorted(scalars)
    steps = [s for s, _ in scalars["learner/updates"]]
    assert steps == sorted(steps) and all(s % 20 == 0 for s in steps)  # one point per `every` (20) updates
    assert [v for _, v in scalars["learner/updates"]] == [float(s) for s in steps]


# ------------------------------------------------------------------------------ bench cells
@pytest.mark.slow
def test_bench_cells_write_side_by_side_runs(tmp_path, monkeypatch):
    """Two cells of a one-task bench, serially: each cell's train step and the cell itself write under
    runs/bench/<spec>/tracking/<cell>/, so one `tensorboard --logdir` compares them."""
    import yaml

    from artifacts.store import Store
    from stages.bench.execute import run_bench
    from stages.bench.spec import load_spec

    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    monkeypatch.chdir(tmp_path)
    base = {**yaml.safe_load(TINY), "name": "tiny", "tracking": {"every": 2}}  # the section reaches the cells
    (tmp_path / "tiny.yaml").write_text(yaml.safe_dump(base))
    (tmp_path / "grid.yaml").write_text(
        yaml.safe_dump(
            {
                "base": "tiny.yaml",
                "methods": {"accrue": {}, "sequential": {}},
                "orderings": {"A": base["tasks"]},
                "seeds": [3],
            }
        )
    )
    spec = load_spec(tmp_path / "grid.yaml")
    store = Store.init(tmp_path / "store")[0]
    results = run_bench(spec, store, executor="serial")
    assert [r.state for r in results] == ["done", "done"], [r.error for r in results]
    root = tmp_path / "runs" / "bench" / "grid" / "tracking"
    assert sorted(p.name for p in root.iterdir()) == sorted(c.name for c in spec.cells)
    for cell in spec.cells:
        train = read_scalars(root / cell.name / "stage-1" / "train")
        assert [s for s, _ in train["eval/success/nist/rect_peg"]] == [0, 24, 48]
        assert "train/critic_loss" in train
        whole = read_scalars(root / cell.name / "cell")
        assert set(whole) == {"cell/seconds", "cell/steps_run", "cell/steps_cached"}
    assert not (store.root / "log" / "tracking").exists()  # a cell's runs are in the bench's directory


@pytest.mark.skipif(
    importlib.util.find_spec("wandb") is None, reason="wandb is not installed (it comes with lerobot[training] 0.6.1)"
)
def test_wandb_online_without_a_login_is_one_line_not_a_prompt(tmp_path, monkeypatch):
    monkeypatch.delenv("WANDB_API_KEY", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))  # no ~/.netrc entry
    monkeypatch.setenv("NETRC", str(tmp_path / "no-netrc"))
    lines: list[str] = []
    with open_tracker({"wandb": {"mode": "online"}}, tmp_path / "run", "x", warn=lines.append) as tracker:
        assert tracker.sinks == ["tensorboard"]
    assert lines == [
        "tracking.wandb: mode online needs a W&B login (`wandb login` or WANDB_API_KEY); not logging to W&B"
    ]
