"""A console a person can read: no traceback from a dependency's warning in a normal run.

lerobot finds its default video decoder by importing torchcodec; where FFmpeg's libraries are absent it
logs the failed import's tracebacks as a warning, at every fine-tune. accrue decodes with pyav, so that
probe must never run (accrue.policy.video_backend)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_policy_helpers import write_synthetic_demos  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

# a fine-tune in a fresh process, with every import of torchcodec's own modules recorded (running its
# __init__ looks them up; a find_spec of the top name alone, as HF datasets' config does, imports nothing)
FINETUNE = """
import json, sys
asked = []

class Spy:
    def find_spec(self, name, path=None, target=None):
        if name.startswith("torchcodec."):
            asked.append(name)
        return None

sys.meta_path.insert(0, Spy())
from accrue.policy.finetune import FinetuneSettings, finetune

finetune("embedded-mlp", [sys.argv[1]], sys.argv[2], FinetuneSettings(steps=2, batch_size=4, num_workers=0))
print(json.dumps(asked))
"""


def test_a_fine_tune_never_probes_torchcodec_and_prints_no_traceback(tmp_path):
    demos = write_synthetic_demos(tmp_path / "demos", "insert the round peg", 1.0, episodes=2, length=6)
    proc = subprocess.run(
        [sys.executable, "-c", FINETUNE, str(demos), str(tmp_path / "out")],
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(ROOT), "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1"},
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert json.loads(proc.stdout.strip().splitlines()[-1]) == []  # torchcodec never looked up
    assert "Traceback" not in proc.stderr and "torchcodec" not in proc.stderr
    assert (tmp_path / "out" / "model.safetensors").is_file()


def test_use_pyav_makes_lerobots_default_pyav_in_modules_that_bound_the_probe():
    import dataclasses

    import lerobot.configs.default as default
    import lerobot.datasets.lerobot_dataset as lerobot_dataset

    from accrue.policy.video_backend import default_video_backend, use_pyav

    use_pyav()  # after lerobot bound its probe by name: each binding is replaced (the real probe says pyav too)
    assert lerobot_dataset.get_safe_default_video_backend is default_video_backend
    field = {f.name: f for f in dataclasses.fields(default.DatasetConfig)}["video_backend"]
    assert field.default_factory is default_video_backend and field.default_factory() == "pyav"


def test_finetune_base_prints_each_count_once_with_its_rate_and_time_left(tmp_path):
    """`finetune-base: step 10/10` was printed twice (at the last step, then again once saved), and no
    line said how fast it went or how long was left."""
    import dataclasses
    import io

    from rich.console import Console

    from artifacts.ingest import add_path
    from artifacts.store import Store
    from stages.runner import Runner
    from stages.runner_types import StepInvocation
    from stages.steps import finetune_base

    demos = write_synthetic_demos(tmp_path / "demos", "insert the round peg", 1.0, episodes=2, length=6)
    store = Store.init(tmp_path / "store")[0]
    console = Console(file=io.StringIO(), width=200, record=True)
    config = {
        "stage": 1,
        "tasks": ["insert the round peg"],
        "init": "embedded-mlp",
        "finetune": True,
        "steps": 10,
        "batch_size": 4,
        "lr": 1e-3,
        "seed": 0,
        "retention": 1.0,
        "chunk_size": 4,
    }
    step = dataclasses.replace(finetune_base.STEP, inputs=finetune_base.demo_roles(1))
    Runner(store, console=console).run(
        StepInvocation(step=step, config=config, inputs={"demos-1": add_path(store, demos, "demos")[0]})
    )
    lines = [line for line in console.export_text().splitlines() if line.startswith("finetune-base: step")]
    assert [line.split(" (")[0] for line in lines] == [f"finetune-base: step {n}/10" for n in (2, 4, 6, 8, 10)]
    assert all(" steps/s, " in line for line in lines)
    assert all(line.endswith(" left)") for line in lines[:-1]) and lines[-1].endswith(", done)")


def test_progress_says_the_rate_and_the_time_left():
    from stages.steps.common import Progress, took_text

    said: list[str] = []
    progress = Progress(said.append, "warmup", unit="episode", parts=2)
    progress.started -= 10.0  # 10 s ago
    progress(1, 4)  # a quarter: under half, nothing yet
    progress(2, 4)
    progress(2, 4)  # the same count again: nothing
    progress(4, 4)
    assert said[0].startswith("warmup: episode 2/4 (0.2") and said[0].endswith(" episodes/s, 10.0 s left)")
    assert said[1].startswith("warmup: episode 4/4 (") and said[1].endswith(", done)") and len(said) == 2
    assert [took_text(s) for s in (4.25, 185, 7620)] == ["4.2 s", "3 min 05 s", "2 h 07 min"]


def test_accrue_run_ends_naming_the_reports_files(tmp_path, monkeypatch):
    from artifacts.store import Store
    from cli.run_cmds import report_line
    from stages.workflow import load_workflow

    root = Path(__file__).resolve().parents[1] / "workflows"
    monkeypatch.chdir(tmp_path)
    store = Store.init(tmp_path / ".accrue")[0]  # the default store: runs/<name>/report
    sim = report_line(load_workflow(root / "quickstart.yaml"), Path("workflows/quickstart.yaml"), store)
    assert sim == (
        "report: `accrue report workflows/quickstart.yaml` writes runs/quickstart/report/: curves.png, "
        "success_matrix.png, base_vs_rl.png, report.rrd, report.json"
    )
    robot = report_line(load_workflow(root / "so101-sim-ci.yaml"), Path("so101.yaml"), store)
    assert robot.endswith("writes runs/so101-sim-ci/report/: fig4.png, table3.md, report.json")
