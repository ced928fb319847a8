"""The runner with steps defined here: cache keys and hits, records, refusals, continue/rerun,
plans wired across steps, and two processes running the same step."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from rich.console import Console

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_runner_support import COUNT, HANG_AT, KILL_AT, PAUSE_AT, RELEASE_FILE, count_invocation  # noqa: E402

from artifacts.auditlog import iter_events
from artifacts.errors import StoreError
from artifacts.ingest import add_path
from artifacts.manifests import read_artifact, read_tree
from artifacts.records import list_attempts
from artifacts.refs import read_ref
from artifacts.store import Store
from artifacts.verify import verify_store
from stages.errors import StageError
from stages.runner import Runner, reap_abandoned, step_ref
from stages.runner_types import (
    STEP_NAMES,
    FromRef,
    FromStep,
    StagePlan,
    StepDef,
    StepInvocation,
    cache_key,
    code_version_of,
)

SUPPORT = Path(__file__).resolve().parent / "test_runner_support.py"


def runner(store: Store, **kw) -> tuple[Runner, Console]:
    console = Console(record=True, width=200, file=open(os.devnull, "w"))
    return Runner(store, console=console, **kw), console


@pytest.fixture
def store(tmp_path: Path) -> Store:
    return Store.init(tmp_path / "store")[0]


def seed_artifact(store: Store, tmp_path: Path, text: str = "5") -> str:
    d = tmp_path / f"seed-{text}"
    d.mkdir()
    (d / "seed.txt").write_text(text)
    return add_path(store, d, "demos")[0]


def result_content(store: Store, result) -> dict:
    tree = read_tree(store, read_artifact(store, result.outputs["result"])["content"])
    return {e["path"]: e["id"] for e in tree}


def test_vocabulary_is_the_six_steps():
    assert STEP_NAMES == ("finetune-base", "cache-teacher", "warmup", "train", "evaluate-all", "handoff")


def test_cache_key_depends_on_step_config_inputs_and_code_version():
    base = cache_key(COUNT, {"n": 1}, {"seed": "a" * 64})
    assert base == cache_key(COUNT, {"n": 1}, {"seed": "a" * 64})
    assert base != cache_key(COUNT, {"n": 2}, {"seed": "a" * 64})
    assert base != cache_key(COUNT, {"n": 1}, {"seed": "b" * 64})
    assert base != cache_key(StepDef("train", "count-2", COUNT.run), {"n": 1}, {"seed": "a" * 64})
    assert base != cache_key(StepDef("warmup", "count-1", COUNT.run), {"n": 1}, {"seed": "a" * 64})
    assert code_version_of(COUNT).startswith("count-1+accrue-")
    with pytest.raises(StageError, match="not plain JSON"):
        cache_key(COUNT, {"n": object()}, {})


def test_second_run_is_a_cached_no_op_that_says_so(store, tmp_path):
    seed = seed_artifact(store, tmp_path)
    r, console = runner(store)
    first = r.run(count_invocation(6, inputs={"seed": seed}))
    second = r.run(count_invocation(6, inputs={"seed": seed}))
    assert not first.cached and second.cached
    assert second.outputs == first.outputs and second.record_id == first.record_id
    assert "cached" in console.export_text()
    assert [a["state"] for a in list_attempts(store)] == ["committed"]
    record = store.read_json(first.record_id)
    assert record["type"] == "step-record" and record["inputs"] == {"seed": seed}
    assert record["config"]["n"] == 6 and record["outputs"] == first.outputs
    for oid in result_content(store, first).values():  # outputs were adopted, and stay read-only
        assert store.object_path(oid).stat().st_mode & 0o777 == 0o444
    out = read_artifact(store, first.outputs["result"])
    assert out["kind"] == "eval" and out["inputs"] == {"seed": seed} and out["producer"]["step"] == "train"
    events = [e["event"] for e in iter_events(store)][2:]  # after the seed's add
    assert events.index("step-started") < events.index("artifact-written") < events.index("step-committed")


def test_rerun_runs_again_and_keeps_both_results(store):
    r, _ = runner(store)
    first = r.run(count_invocation(4))
    again = r.run(count_invocation(4), mode="rerun")
    assert not again.cached and again.record_id != first.record_id and again.attempt == 2
    assert result_content(store, again) == result_content(store, first)  # deterministic body
    assert r.run(count_invocation(4)).record_id == again.record_id  # newest intact hit wins


def test_corrupt_or_missing_input_is_refused_naming_role_and_id(store, tmp_path):
    seed = seed_artifact(store, tmp_path)
    blob = read_tree(store, read_artifact(store, seed)["content"])[0]["id"]
    path = store.object_path(blob)
    os.chmod(path, 0o644)
    path.write_text("6")  # same size, different bytes
    r, _ = runner(store)
    with pytest.raises(StoreError, match=rf"refuses input 'seed' \({seed[:12]}\).*corrupt"):
        r.run(count_invocation(3, inputs={"seed": seed}))
    assert list_attempts(store)[-1]["state"] == "failed"
    assert not store.has_object(blob)  # quarantined when the step found it
    assert any(q.name.startswith(blob) for q in store.quarantine_dir.iterdir())
    with pytest.raises(StoreError, match=r"refuses input 'seed'.*missing"):
        r.run(count_invocation(3, inputs={"seed": seed}))
    with pytest.raises(StoreError, match="refuses input 'seed'"):
        r.run(count_invocation(3, inputs={"seed": "0000" + "1" * 60}))


def test_a_hit_whose_output_is_corrupt_or_missing_is_a_miss(store):
    r, console = runner(store)
    first = r.run(count_invocation(4))
    victim = next(iter(result_content(store, first).values()))
    path = store.object_path(victim)
    os.chmod(path, 0o644)
    data = bytearray(path.read_bytes())
    data[0] ^= 1
    path.write_bytes(bytes(data))
    second = r.run(count_invocation(4))
    assert not second.cached and second.attempt == 2
    assert "damaged" in console.export_text()
    assert result_content(store, second) == result_content(store, first)
    # the damaged copy was quarantined on sight, so the new attempt re-created an intact object
    assert any(q.name.startswith(victim) for q in store.quarantine_dir.iterdir())
    assert store.object_path(victim).read_bytes() != bytes(data)
    assert verify_store(store, full=True).ok
    path = store.object_path(victim)
    path.unlink()
    third = r.run(count_invocation(4))  # attempt 2's output shares the missing object: a miss again
    assert not third.cached and third.attempt == 3 and store.has_object(victim)


def test_failed_step_is_recorded_and_error_propagates(store):
    def body(ctx):
        raise ValueError("boom\nsecond line")

    with pytest.raises(ValueError):
        runner(store)[0].run(StepInvocation(step=StepDef("warmup", "1", body), config={}))
    attempt = list_attempts(store)[0]
    assert attempt["state"] == "failed" and attempt["error"] == "ValueError: boom"
    assert "step-failed" in [e["event"] for e in iter_events(store)]
    assert list(store.tmp_dir.iterdir()) == []


def test_missing_declared_output_or_input_fails_clearly(store):
    lazy = StepDef("handoff", "1", lambda ctx: None, outputs={"handoff": "handoff"})
    with pytest.raises(StageError, match="did not produce output 'handoff'"):
        runner(store)[0].run(StepInvocation(step=lazy, config={}))
    needy = StepDef("warmup", "1", lambda ctx: None, inputs=("base",))
    with pytest.raises(StageError, match="missing input 'base'"):
        runner(store)[0].run(StepInvocation(step=needy, config={}))


def test_interrupted_step_needs_continue_or_rerun(store):
    calls = []

    def body(ctx):
        resumed = ctx.last_checkpoint()
        calls.append(None if resumed is None else resumed[1])
        d = ctx.scratch_dir("c")
        (d / "x").write_text(str(len(calls)))
        ctx.save_checkpoint(d, {"i": len(calls)})
        if len(calls) == 1:
            raise KeyboardInterrupt
        (ctx.new_output("out", "eval") / "done").write_text("ok")

    inv = StepInvocation(step=StepDef("train", "1", body), config={})
    r, _ = runner(store)
    with pytest.raises(KeyboardInterrupt):
        r.run(inv)
    assert list_attempts(store)[0]["state"] == "abandoned"
    with pytest.raises(StageError, match=r"interrupted .*--continue.*--rerun"):
        r.run(inv)
    result = r.run(inv, mode="continue")
    assert calls == [None, {"i": 1}] and not result.cached
    assert store.read_json(result.record_id)["resumed_from"] == list_attempts(store)[0]["checkpoints"][0]["id"]


def test_dead_running_attempt_is_abandoned_on_next_look(store):
    r, _ = runner(store)
    proc = subprocess.Popen(  # hangs after its first checkpoint, holding the step's lock, until killed
        [sys.executable, str(SUPPORT), "count", str(store.root), "normal", "200", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env={**os.environ, HANG_AT: "1"},
    )
    _wait_for_checkpoints(store, 1)
    key = list_attempts(store)[0]["cache_key"]
    assert reap_abandoned(store, key) == 0  # alive: holds the lock
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert list_attempts(store)[0]["state"] == "running"
    assert reap_abandoned(store, key) == 1
    assert list_attempts(store)[0]["state"] == "abandoned"


def _wait_for_checkpoints(store: Store, n: int, timeout: float = 60) -> None:
    start = time.monotonic()
    while True:
        attempts = list_attempts(store) if store.records_dir.exists() else []
        if attempts and len(attempts[-1].get("checkpoints", [])) >= n:
            return
        assert time.monotonic() - start < timeout, "the step never checkpointed"
        time.sleep(0.02)


def test_continue_after_kill_matches_an_uninterrupted_run(tmp_path):
    clean_store = Store.init(tmp_path / "clean")[0]
    clean = runner(clean_store)[0].run(count_invocation(40, every=2, sleep=0.0))
    # the subprocess uses every=2 and sleep 0.02 s per iteration: the same config as below; it kills
    # itself (SIGKILL) right after its 3rd checkpoint, so the crash point is exact on a busy machine
    store = Store.init(tmp_path / "crash")[0]
    proc = subprocess.run(
        [sys.executable, str(SUPPORT), "count", str(store.root), "normal", "40", "0.02"],
        capture_output=True,
        env={**os.environ, KILL_AT: "3"},
        timeout=300,
    )
    assert proc.returncode == -signal.SIGKILL, proc.stderr.decode()[-2000:]
    saved = list_attempts(store)[0]["checkpoints"]
    assert [c["progress"] for c in saved] == [{"i": 2}, {"i": 4}, {"i": 6}]
    r, console = runner(store)
    with pytest.raises(StageError, match="interrupted"):
        r.run(count_invocation(40, every=2, sleep=0.02))
    resumed = r.run(count_invocation(40, every=2, sleep=0.02), mode="continue")
    text = console.export_text()
    assert f"continuing from checkpoint {saved[-1]['id'][:12]}" in text
    assert list_attempts(store)[0]["state"] == "abandoned"
    assert store.read_json(resumed.record_id)["resumed_from"] == saved[-1]["id"]
    final = json.loads(store.read_bytes(result_content(store, resumed)["final.json"]))
    clean_final = json.loads(clean_store.read_bytes(result_content(clean_store, clean)["final.json"]))
    assert final == clean_final
    assert verify_store(store, full=True).ok
    # the shard file was stored once, however many checkpoints included it
    shard_ids = {
        e["id"]
        for c in saved
        for e in read_tree(store, read_artifact(store, c["id"])["content"])
        if e["path"] == "shard-000.bin"
    }
    assert len(shard_ids) == 1


def test_rerun_ignores_checkpoints(store):
    seen = []

    def body(ctx):
        seen.append(ctx.last_checkpoint())
        d = ctx.scratch_dir("c")
        (d / "x").write_text("1")
        ctx.save_checkpoint(d, {"i": 1})
        if len(seen) == 1:
            raise RuntimeError("crash")
        ctx.new_output("out", "eval")

    inv = StepInvocation(step=StepDef("train", "1", body), config={})
    r, _ = runner(store)
    with pytest.raises(RuntimeError):
        r.run(inv)
    r.run(inv, mode="rerun")
    assert seen == [None, None]


def test_second_process_refuses_naming_the_holder_or_waits(store, tmp_path):
    # the holder pauses after its first checkpoint (holding the step's lock) until the test releases it,
    # so the second and third processes meet it running however slow the machine is
    release = tmp_path / "release"
    holder = subprocess.Popen(
        [sys.executable, str(SUPPORT), "count", str(store.root), "normal", "30", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, PAUSE_AT: "1", RELEASE_FILE: str(release)},
    )
    try:
        _wait_for_checkpoints(store, 1)
        refused = subprocess.run(
            [sys.executable, str(SUPPORT), "count", str(store.root), "normal", "30", "0"],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert refused.returncode == 2
        assert f"already running (pid {holder.pid}" in refused.stderr and "--wait" in refused.stderr
        waiter = subprocess.Popen(
            [sys.executable, str(SUPPORT), "count", str(store.root), "normal", "30", "0", "--wait"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        seen = []
        for line in waiter.stderr:  # it says it waits before the holder is let go
            seen.append(line)
            if "waiting for" in line:
                break
        assert any(f"waiting for pid {holder.pid}" in line for line in seen), seen
    finally:
        release.touch()
    waiter_out, waiter_err = waiter.communicate(timeout=120)
    out, _ = holder.communicate(timeout=60)
    assert holder.returncode == 0 and waiter.returncode == 0, waiter_err
    first, second = json.loads(out), json.loads(waiter_out)
    assert not first["cached"] and second["cached"] and second["record"] == first["record"]
    assert [a["state"] for a in list_attempts(store)] == ["committed"]


def _producer(name: str, role: str, kind: str, text: str) -> StepDef:
    def body(ctx):
        out = ctx.new_output(role, kind)
        upstream = "".join((ctx.input_path(r) / "v.txt").read_text() for r in sorted(ctx.inputs))
        (out / "v.txt").write_text(upstream + text + str(ctx.config.get("seed", "")))

    return StepDef(name, "1", body, outputs={role: kind})


def test_plan_wires_outputs_to_later_steps_and_moves_stage_refs(store, tmp_path):
    prior = _producer("handoff", "handoff", "handoff", "H")
    r, _ = runner(store)
    stage1 = StagePlan("demo", 1, (StepInvocation(prior, {"seed": 1}),))
    [h1] = r.run_plan(stage1)
    assert read_ref(store, step_ref("demo", 1, "handoff")) == h1.record_id
    warm = _producer("warmup", "episodes", "episodes", "W")
    train = _producer("train", "actor", "checkpoint", "T")
    plan = StagePlan(
        "demo",
        2,
        (
            StepInvocation(warm, {"seed": 2}, inputs={"prev": FromRef("workflow/demo/stage/1/handoff:handoff")}),
            StepInvocation(train, {"seed": 3}, inputs={"episodes": FromStep("warmup", "episodes")}),
        ),
    )
    results = r.run_plan(plan)
    assert [x.step for x in results] == ["warmup", "train"]
    final = read_tree(store, read_artifact(store, results[1].outputs["actor"])["content"])[0]["id"]
    assert store.read_bytes(final) == b"H1W2T3"
    assert store.read_json(results[1].record_id)["inputs"] == {"episodes": results[0].outputs["episodes"]}
    assert all(x.cached for x in r.run_plan(plan))
    only = r.run_plan(plan, only_step="warmup", mode="rerun")
    assert [x.step for x in only] == ["warmup"] and not only[0].cached
    with pytest.raises(StageError, match="has no step 'evaluate-all'"):
        r.run_plan(plan, only_step="evaluate-all")
    broken = StagePlan(
        "demo", 3, (StepInvocation(warm, {}, inputs={"prev": FromRef("workflow/demo/stage/2/handoff")}),)
    )
    with pytest.raises(StageError, match="run the earlier stage first"):
        r.run_plan(broken)
    backwards = StagePlan("demo", 3, (StepInvocation(train, {}, inputs={"episodes": FromStep("warmup", "episodes")}),))
    with pytest.raises(StageError, match="does not run before it"):
        r.run_plan(backwards)


def test_continue_with_changed_config_explains_why_nothing_resumes(store):
    def body(ctx):
        with ctx.progress() as bar:
            task = bar.add_task("iterations", total=1)
            bar.advance(task)
        d = ctx.scratch_dir("c")
        (d / "x").write_text("1")
        ctx.save_checkpoint(d, {"i": 1})
        if ctx.config["lr"] == 1:
            raise RuntimeError("crash")
        ctx.log_event("custom-summary", value=3)
        ctx.new_output("out", "eval")

    step = StepDef("train", "1", body)
    r, console = runner(store)
    with pytest.raises(RuntimeError):
        r.run(StepInvocation(step, {"lr": 1}))
    r.run(StepInvocation(step, {"lr": 2}), mode="continue")
    text = console.export_text()
    assert "no checkpoint to continue from (attempt 1 of key" in text and "differ" in text
    assert [e["value"] for e in iter_events(store) if e["event"] == "custom-summary"] == [3]
