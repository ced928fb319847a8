"""Steps defined for the runner tests (no product step bodies), and a script entry so the crash
and concurrency tests can run them in separate processes:

    python tests/test_runner_support.py count STORE MODE N SLEEP [--wait]
    python tests/test_runner_support.py writer STORE SEED
    python tests/test_runner_support.py accrue ARGS...   (the real CLI, with the checkpoint faults below)
"""

from __future__ import annotations

import json
import os
import random
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from artifacts.hashing import hash_bytes  # noqa: E402
from stages.runner_types import StepDef, StepInvocation  # noqa: E402


def _count_body(ctx) -> None:
    """A deterministic 'training loop': state_{i+1} = H(state_i, i, seed); a checkpoint every
    `every` iterations holds (i, state) plus an unchanged 'shard' file that must dedupe."""
    n, every, sleep = ctx.config["n"], ctx.config["every"], ctx.config.get("sleep", 0.0)
    seed_text = (ctx.input_path("seed") / "seed.txt").read_text() if ctx.has_input("seed") else ""
    i, state = 0, hash_bytes(f"start {ctx.config['seed']} {seed_text}".encode())
    resumed = ctx.last_checkpoint()
    if resumed is not None:
        path, progress = resumed
        saved = json.loads((path / "state.json").read_text())
        i, state = saved["i"], saved["state"]
        assert progress["i"] == i
    scratch, saved = ctx.scratch_dir("ckpt"), 0
    (scratch / "shard-000.bin").write_bytes(b"sealed shard" * 1000)
    while i < n:
        state = hash_bytes(f"{state} {i} {ctx.config['seed']}".encode())
        i += 1
        if sleep:
            time.sleep(sleep)
        if i % every == 0 and i < n:
            (scratch / "state.json").write_text(json.dumps({"i": i, "state": state}))
            ctx.save_checkpoint(scratch, {"i": i})
            saved += 1
            _fault_after_checkpoint(saved)
    out = ctx.new_output("result", "eval")
    (out / "final.json").write_text(json.dumps({"n": n, "state": state}))
    (out / "sub").mkdir()
    (out / "sub" / "copy-of-shard.bin").write_bytes(b"sealed shard" * 1000)


# Deterministic faults for the kill tests (environment, so the step's config and cache key are those
# of the uninterrupted run): after this process's N-th committed checkpoint, SIGKILL itself, or hang
# (holding the step's lock) until the test kills it.
# PAUSE_AT + RELEASE_FILE: wait there until the test creates that file.
KILL_AT, HANG_AT = "ACCRUE_TEST_KILL_AT_CHECKPOINT", "ACCRUE_TEST_HANG_AT_CHECKPOINT"
PAUSE_AT, RELEASE_FILE = "ACCRUE_TEST_PAUSE_AT_CHECKPOINT", "ACCRUE_TEST_RELEASE_FILE"


def _fault_after_checkpoint(saved: int) -> None:
    import signal

    if os.environ.get(KILL_AT) == str(saved):
        os.kill(os.getpid(), signal.SIGKILL)
    if os.environ.get(HANG_AT) == str(saved):
        time.sleep(3600)
    if os.environ.get(PAUSE_AT) == str(saved):
        release, deadline = Path(os.environ[RELEASE_FILE]), time.monotonic() + 300
        while not release.exists() and time.monotonic() < deadline:
            time.sleep(0.02)


COUNT = StepDef(
    name="train", code_version="count-1", run=_count_body, optional_inputs=("seed",), outputs={"result": "eval"}
)


def count_invocation(
    n: int,
    every: int = 5,
    sleep: float = 0.0,
    seed: int = 7,
    inputs=None,
    workflow: str | None = None,
    stage: int | None = None,
) -> StepInvocation:
    return StepInvocation(
        step=COUNT,
        config={"n": n, "every": every, "sleep": sleep, "seed": seed},
        inputs=inputs or {},
        workflow=workflow,
        stage=stage,
    )


def _writer(store_path: Path, seed: int) -> None:
    """Publish things in a loop, as fast as it can, until killed."""
    from artifacts.auditlog import append_event
    from artifacts.ingest import add_path
    from artifacts.refs import set_ref
    from artifacts.store import Store
    from stages.runner import Runner

    rng = random.Random(seed)
    store = Store.open(store_path)
    src = store_path.parent / f"src-{os.getpid()}"
    runner = Runner(store, console=_quiet_console())
    for round_ in range(10_000):
        d = src / f"r{round_}"
        d.mkdir(parents=True)
        (d / "seed.txt").write_text(str(rng.randint(0, 3)))
        for f in range(rng.randint(1, 4)):
            (d / f"f{f}.bin").write_bytes(rng.randbytes(rng.choice([10, 5000, 300_000, 2_000_000])))
        aid, _ = add_path(store, d, "demos", ref=f"user/r{round_ % 3}")
        set_ref(store, "user/latest", aid)
        append_event(store, "writer-round", round=round_)
        runner.run(count_invocation(n=rng.randint(2, 12), every=3, seed=round_, inputs={"seed": aid}))


def _quiet_console():
    from rich.console import Console

    return Console(file=open(os.devnull, "w"))


def _count_main(args: list[str]) -> None:
    from rich.console import Console

    from artifacts.store import Store
    from stages.runner import Runner

    store_path, mode, n, sleep = Path(args[0]), args[1], int(args[2]), float(args[3])
    # the runner's own lines (e.g. "waiting for pid …") go to stderr, where the tests read them
    runner = Runner(Store.open(store_path), console=Console(stderr=True, width=200), wait="--wait" in args)
    result = runner.run(count_invocation(n=n, every=2, sleep=sleep), mode=mode)
    print(json.dumps({"cached": result.cached, "record": result.record_id, "outputs": result.outputs}))


def _accrue_main(args: list[str]) -> None:
    """The real `accrue` CLI in this process, with the checkpoint faults above armed on every step's
    StepContext.save_checkpoint (the product has no test hooks; the environment picks the checkpoint)."""
    from cli.main import main
    from stages.runner_context import StepContext

    original, saved = StepContext.save_checkpoint, [0]

    def save_checkpoint(self, dir_path, progress):
        cid = original(self, dir_path, progress)  # committed: the attempt record and the event are written
        saved[0] += 1
        _fault_after_checkpoint(saved[0])
        return cid

    StepContext.save_checkpoint = save_checkpoint
    sys.argv = ["accrue", *args]
    main()


if __name__ == "__main__":
    cmd, rest = sys.argv[1], sys.argv[2:]
    if cmd == "count":
        try:
            _count_main(rest)
        except Exception as exc:  # the parent test reads this line
            print(f"error: {exc}", file=sys.stderr)
            sys.exit(2)
    elif cmd == "writer":
        _writer(Path(rest[0]), int(rest[1]))
    elif cmd == "accrue":
        _accrue_main(rest)
