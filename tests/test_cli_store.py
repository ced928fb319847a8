"""The store and stage CLI, run as the user runs it: human output, --json, exit codes, and
one-line errors (never a traceback) for user mistakes."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from rich.console import Console

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_runner_support import count_invocation  # noqa: E402

from artifacts.store import Store
from stages.runner import Runner
from stages.runner_types import StagePlan

ROOT = Path(__file__).resolve().parents[1]
# Run the real entry point; a meta-path hook can hide stages.plan to test the "not installed" path.
_ENTRY = """
import sys
if sys.argv[1] == "--hide-plan":
    sys.argv.pop(1)
    class _Hide:
        def find_spec(self, name, path=None, target=None):
            if name == "stages.plan":
                raise ModuleNotFoundError("No module named 'stages.plan'", name="stages.plan")
    sys.meta_path.insert(0, _Hide())
sys.argv[0] = "accrue"
from cli.main import main
main()
"""


class Result:
    def __init__(self, returncode: int, stdout: str, stderr: str) -> None:
        self.returncode, self.stdout, self.stderr = returncode, stdout, stderr


def accrue(*args: str, store: Path | None = None, cwd: Path | None = None, hide_plan: bool = False):
    """Run the real entry point. In-process (fast) by default; in a subprocess when the import
    system must be altered (hide_plan)."""
    env = {k: v for k, v in os.environ.items() if k != "ACCRUE_STORE"}
    if store is not None:
        env["ACCRUE_STORE"] = str(store)
    env["COLUMNS"] = "200"
    if hide_plan:
        env["PYTHONPATH"] = str(ROOT)
        argv = [sys.executable, "-c", _ENTRY, "--hide-plan", *args]
        proc = subprocess.run(argv, capture_output=True, text=True, cwd=cwd or ROOT, env=env, timeout=120)
        result = Result(proc.returncode, proc.stdout, proc.stderr)
    else:
        result = _in_process(list(args), env, cwd or ROOT)
    assert "Traceback" not in result.stderr, result.stderr
    return result


def _in_process(args: list[str], env: dict, cwd: Path) -> Result:
    import contextlib
    import io

    from cli.main import main

    out, err = io.StringIO(), io.StringIO()
    saved_env, saved_argv, saved_cwd = dict(os.environ), sys.argv, os.getcwd()
    os.environ.clear()
    os.environ.update(env)
    sys.argv = ["accrue", *args]
    os.chdir(cwd)
    code = 0
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                main()
            except SystemExit as exc:
                code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    finally:
        os.environ.clear()
        os.environ.update(saved_env)
        sys.argv = saved_argv
        os.chdir(saved_cwd)
    return Result(code, out.getvalue(), err.getvalue())


def one_line_error(proc) -> str:
    assert proc.returncode == 2, (proc.returncode, proc.stdout, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), proc.stderr
    return lines[0]


@pytest.fixture
def store(tmp_path: Path) -> Path:
    path = tmp_path / "store"
    assert accrue("init", "--store", str(path)).returncode == 0
    return path


def test_init_defaults_to_dot_accrue_or_env(tmp_path):
    out = accrue("init", cwd=tmp_path)
    assert out.returncode == 0 and (tmp_path / ".accrue" / "config").is_file()
    assert "already" in accrue("init", cwd=tmp_path).stdout
    env_store = tmp_path / "elsewhere"
    assert accrue("init", store=env_store, cwd=tmp_path).returncode == 0
    assert (env_store / "config").is_file()


def test_add_show_log_refs_round_trip(store, tmp_path):
    ds = tmp_path / "dataset"
    (ds / "meta").mkdir(parents=True)
    (ds / "meta" / "info.json").write_text('{"fps": 10}')
    (ds / "data.bin").write_bytes(os.urandom(5000))
    added = accrue("add", str(ds), "--kind", "demos", "--ref", "demos/t1", "--store", str(store))
    assert added.returncode == 0
    aid = added.stdout.strip()
    assert re.fullmatch(r"[0-9a-f]{64}", aid)
    shown = json.loads(accrue("show", aid[:8], "--json", "--store", str(store)).stdout)
    assert shown["id"] == aid and shown["kind"] == "demos" and shown["files"] == 2 and shown["size"] == 5011
    table = accrue("show", "demos/t1", "--store", str(store)).stdout
    assert f"artifact {aid}" in table and "demos" in table
    tree = accrue("show", shown["content"][:10], "--store", str(store)).stdout
    assert "meta/info.json" in tree
    events = [json.loads(line) for line in accrue("log", "--json", "--all", "--store", str(store)).stdout.splitlines()]
    assert [e["event"] for e in events] == ["artifact-written", "ref-moved", "ref-moved"]
    assert "artifact-written" in accrue("log", "--store", str(store)).stdout
    refs = json.loads(accrue("refs", "demos/", "--json", "--store", str(store)).stdout)
    assert refs == {"demos/t1": aid}


def test_verify_exits_non_zero_on_a_flipped_byte(store, tmp_path):
    f = tmp_path / "weights.bin"
    f.write_bytes(os.urandom(20000))
    aid = accrue("add", str(f), "--kind", "base-policy", "--store", str(store)).stdout.strip()
    assert accrue("verify", "--store", str(store)).returncode == 0
    assert accrue("verify", "--full", "--store", str(store)).returncode == 0
    content = json.loads(accrue("show", aid, "--json", "--store", str(store)).stdout)["content"]
    obj = store / "objects" / "blake3" / content[:2] / content[2:]
    os.chmod(obj, 0o644)
    data = bytearray(obj.read_bytes())
    data[1234] ^= 0xFF
    obj.write_bytes(bytes(data))
    assert accrue("verify", "--store", str(store)).returncode == 0  # quick: sizes still match
    full = accrue("verify", "--full", "--json", "--store", str(store))
    report = json.loads(full.stdout)
    assert full.returncode == 1 and report["quarantined"] == [content]
    quick = accrue("verify", "--store", str(store))
    assert quick.returncode == 1 and f"missing object {content[:12]}" in quick.stdout


def test_gc_is_a_dry_run_unless_told(store, tmp_path):
    st = Store.open(store)
    loose = st.put_bytes(b"unreferenced")
    dry = json.loads(accrue("gc", "--grace", "0", "--json", "--store", str(store)).stdout)
    assert dry["dry_run"] and dry["removed"] == [loose] and st.has_object(loose)
    young = accrue("gc", "--yes", "--store", str(store))
    assert young.returncode == 0 and st.has_object(loose) and "younger than 24h" in young.stdout
    assert accrue("gc", "--yes", "--grace", "0", "--store", str(store)).returncode == 0
    assert not st.has_object(loose)


def test_lineage_goes_down_to_demos_and_shows_seeds(store, tmp_path):
    seed_dir = tmp_path / "seed"
    seed_dir.mkdir()
    (seed_dir / "seed.txt").write_text("1")
    demos = accrue("add", str(seed_dir), "--kind", "demos", "--store", str(store)).stdout.strip()
    st = Store.open(store)
    runner = Runner(st, console=Console(file=open(os.devnull, "w")))
    [result] = runner.run_plan(StagePlan("wf", 1, (count_invocation(4, seed=11, inputs={"seed": demos}),)))
    tree = accrue("lineage", "workflow/wf/stage/1/train:result", "--store", str(store)).stdout
    assert "eval" in tree and "from train" in tree and "seed=11" in tree
    assert "demos" in tree and demos[:12] in tree
    nested = json.loads(accrue("lineage", result.record_id[:10], "--json", "--store", str(store)).stdout)
    assert nested["type"] == "step-record" and nested["seeds"] == {"seed": 11}
    assert nested["inputs"]["seed"]["id"] == demos and nested["inputs"]["seed"]["kind"] == "demos"


@pytest.mark.parametrize(
    "args, pattern",
    [
        (("show", "abcd"), r"no accrue store|no object or ref"),
        (("show", "zz"), r"neither a ref nor an id"),
        (("show", "workflow/none/stage/1/train:out"), r"no object or ref|neither a ref"),
        (("gc", "--grace", "soon"), r"--grace: not a duration"),
        (("add", "/does/not/exist", "--kind", "demos"), r"no such file or directory"),
        (("add", ".", "--kind", "Not A Kind"), r"bad artifact kind"),
        (("log", "-n", "0"), r"-n|--lines"),
        (("verify", "--bogus"), r"No such option"),
    ],
)
def test_user_mistakes_are_one_line_errors(store, args, pattern):
    line = one_line_error(accrue(*args, store=store))
    assert re.search(pattern, line), line


def test_commands_without_a_store_say_how_to_make_one(tmp_path):
    line = one_line_error(accrue("log", cwd=tmp_path))
    assert "no accrue store" in line and "accrue init" in line


def workflow_file(tmp_path: Path, **changes) -> Path:
    data = {
        "name": "wf",
        "tasks": ["a/x", "a/y"],
        "method": "accrue",
        "budgets": {"env_steps": 100, "eval_every": 50},
        **changes,
    }
    path = tmp_path / "wf.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_stage_run_without_step_bodies_says_so(store, tmp_path):
    line = one_line_error(
        accrue("stage", "run", str(workflow_file(tmp_path)), "--stage", "1", store=store, hide_plan=True)
    )
    assert "step bodies are not installed" in line


@pytest.mark.parametrize(
    "extra, pattern",
    [
        (("--stage", "3"), r"has stages 1\.\.2 \(got --stage 3\)"),
        (("--stage", "1", "--continue", "--rerun"), r"--continue and --rerun exclude each other"),
        ((), r"Missing option '--stage'"),
    ],
)
def test_stage_run_argument_mistakes(store, tmp_path, extra, pattern):
    line = one_line_error(accrue("stage", "run", str(workflow_file(tmp_path)), *extra, store=store))
    assert re.search(pattern, line), line


def test_stage_run_rejects_a_malformed_workflow_in_one_line(store, tmp_path):
    bad = workflow_file(tmp_path, learner={"batch_size": -3})
    line = one_line_error(accrue("stage", "run", str(bad), "--stage", "1", store=store))
    assert line == f"error: {bad}: learner.batch_size: must be a positive integer (got -3)"
    broken = tmp_path / "broken.yaml"
    broken.write_text("tasks: [a\n")
    assert "YAML syntax error" in one_line_error(accrue("stage", "status", str(broken), store=store))


def test_stage_status_shows_committed_and_interrupted_steps(store, tmp_path):
    st = Store.open(store)
    runner = Runner(st, console=Console(file=open(os.devnull, "w")))
    runner.run_plan(StagePlan("wf", 1, (count_invocation(4, seed=1),)))

    def crash(ctx):
        d = ctx.scratch_dir("c")
        (d / "x").write_text("1")
        ctx.save_checkpoint(d, {"env_steps": 500})
        raise KeyboardInterrupt

    from stages.runner_types import StepDef, StepInvocation

    with pytest.raises(KeyboardInterrupt):
        runner.run_plan(StagePlan("wf", 2, (StepInvocation(StepDef("warmup", "1", crash), {}),)))
    rows = json.loads(accrue("stage", "status", str(workflow_file(tmp_path)), "--json", store=store).stdout)
    by = {(r["stage"], r["step"]): r for r in rows}
    assert len(rows) == 14 and by[(1, "train")]["state"] == "committed"  # 7 steps a stage, record-demos first
    assert by[(2, "warmup")]["state"] == "abandoned" and "env_steps=500" in by[(2, "warmup")]["detail"]
    assert by[(1, "handoff")]["state"] == "not run" and by[(2, "warmup")]["task"] == "a/y"
    table = accrue("stage", "status", str(workflow_file(tmp_path)), store=store).stdout
    assert "committed" in table and "abandoned" in table
