"""Fault harness: kill -9 a tiny workflow at random moments, resume, and check nothing was lost.

    .venv/bin/python scripts/fault_harness.py --trials 100 --out benchmarks/results/fault_harness.json

First one uninterrupted reference run (its own store), whose log gives each step's time window
(from its step-started event to the next one). Then each trial, in a fresh store: draw a step
uniformly and a moment uniformly inside its reference window, start `accrue run WORKFLOW`, wait
until that step has started, sleep that long and kill the whole process group with SIGKILL (with
`--base embedded-mlp` the kill may land inside the in-process lerobot fine-tune), check the store, resume
with `accrue run WORKFLOW --continue`, and check again. A trial passes when

  * `verify --full` finds no problem, both right after the kill and after the resume;
  * no lock is held once the processes are gone (every locks/*.lock and the writer lock);
  * every step of every stage ends committed with outputs whose artifact ids equal the reference's
    (an artifact's id is a function of its kind, content, inputs, config and code version, so
    this compares every output byte, in another store at another path).

Prints one line per trial and a summary; --out writes them as JSON (with the command line, the code
version and the machine's load). --runs-file adds the run to a file of several runs (chunks with other
seeds, so a long measurement survives an interruption) and keeps its top-level summary over all of them:

    .venv/bin/python scripts/fault_harness.py --base embedded-mlp --trials 20 --seed 2 \
        --runs-file benchmarks/results/fault_harness_embedded_mlp.json --machine "shared 2-core machine"
"""

from __future__ import annotations

import argparse
import fcntl
import json
import os
import random
import shlex
import signal
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

# The tiny workflow of tests/test_e2e_tiny.py, smaller still: two stages so that every step runs
# with and without an earlier stage (cache-teacher, the handoff's memory), checkpoints inside train.
# BASE is --base.
TINY = """
name: harness
tasks: [nist/rect_peg, nist/gear]
method: accrue
seed: 3
horizon: 4
task_features: 8
base_policy: {init: BASE, finetune_steps: 2, batch_size: 8, demos_per_task: 2}
learner: {actor_hidden: [32, 32], critic_hidden: [32, 32], projector_dim: 16, batch_size: 32, num_atoms: 11, utd: 1}
budgets: {env_steps: 80, eval_every: 40, eval_episodes: 1, num_envs: 2, warmup_episodes: 1,
          retained_episodes: 1, checkpoint_every: 20, log_episodes: 1}
"""


def accrue_env(store: Path) -> dict:
    return {
        **os.environ,
        "ACCRUE_STORE": str(store),
        "OMP_NUM_THREADS": "1",
        "HF_HUB_OFFLINE": "1",
        "HF_DATASETS_OFFLINE": "1",
        "TRANSFORMERS_OFFLINE": "1",
        "RERUN": "off",
        "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"),
    }


def accrue(store: Path, *args: str, timeout: float = 1800) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "cli.main", *args],
        cwd=ROOT,
        env=accrue_env(store),
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def outputs_by_step(store: Path) -> dict[str, dict]:
    """'stage/step' -> {role: {artifact: id, content: content id, or {path: id} of a directory}} of
    the committed record each workflow ref names (the content shows which file differs)."""
    from artifacts.manifests import read_artifact, read_tree
    from artifacts.refs import list_refs
    from artifacts.store import Store

    st = Store.open(store)
    out = {}
    for name, rid in list_refs(st, "workflow/harness/").items():
        record = st.read_json(rid)
        _, _, _, stage, step = name.split("/")
        roles = {}
        for role, oid in sorted(record["outputs"].items()):
            manifest = read_artifact(st, oid)
            content = (
                manifest["content"]
                if manifest["layout"] == "file"
                else {e["path"]: e["id"] for e in read_tree(st, manifest["content"])}
            )
            roles[role] = {"artifact": oid, "content": content}
        out[f"{stage}/{step}"] = roles
    return out


def held_locks(store: Path) -> list[str]:
    """Lock files some process still holds (kernel flock, or the POSIX writer lock)."""
    held = []
    for path in sorted((store / "locks").glob("*.lock")):
        fd = os.open(path, os.O_RDWR)
        try:
            if path.name == "writers.lock":
                fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            else:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            held.append(path.name)
        finally:
            os.close(fd)
    return held


def verify_problems(store: Path) -> list[str]:
    """`verify --full`'s problems (in this process: it needs no torch, so it is cheap)."""
    from artifacts.store import Store
    from artifacts.verify import verify_store

    st = Store.open(store)
    try:
        return verify_store(st, full=True).problems
    finally:
        st.close()


def step_windows(store: Path) -> list[tuple[str, float]]:
    """(stage/step, seconds until the next step started) for every step-started event of a run."""
    events = [json.loads(line) for line in (store / "log" / "events.jsonl").read_bytes().splitlines()]
    starts = [
        (f"{e.get('stage')}/{e['step']}", datetime.fromisoformat(e["ts"]).timestamp())
        for e in events
        if e["event"] == "step-started"
    ]
    end = datetime.fromisoformat(events[-1]["ts"]).timestamp()
    return [(name, (starts[i + 1][1] if i + 1 < len(starts) else end) - t) for i, (name, t) in enumerate(starts)]


def started_steps(store: Path) -> int:
    log = store / "log" / "events.jsonl"
    return log.read_bytes().count(b'"event":"step-started"') if log.exists() else 0


def running_step(store: Path) -> str:
    """The step the log shows started and not finished (where the kill landed)."""
    log = store / "log" / "events.jsonl"
    open_steps: dict[tuple, str] = {}
    for line in log.read_bytes().splitlines() if log.exists() else []:
        try:
            e = json.loads(line)
        except ValueError:
            continue
        key = (e.get("cache_key"), e.get("attempt"))
        if e.get("event") == "step-started":
            open_steps[key] = f"{e.get('stage')}/{e.get('step')}"
        elif e.get("event") in ("step-committed", "step-failed", "step-abandoned"):
            open_steps.pop(key, None)
    return ", ".join(open_steps.values()) or "between steps"


def wait_for_step(store: Path, proc: subprocess.Popen, k: int, timeout: float = 900) -> bool:
    """Until the k-th step (0-based) of the run has started; False if the run ended first."""
    deadline = time.monotonic() + timeout
    while started_steps(store) <= k:
        if proc.poll() is not None or time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def reference_run(workdir: Path, wf: Path) -> tuple[dict, list[tuple[str, float]], float]:
    store = workdir / "reference"
    accrue(store, "init")
    start = time.monotonic()
    proc = accrue(store, "run", str(wf))
    if proc.returncode != 0:
        raise SystemExit(f"reference run failed:\n{proc.stderr[-3000:]}")
    return outputs_by_step(store), step_windows(store), time.monotonic() - start


def trial(n: int, workdir: Path, wf: Path, reference: dict, windows: list, rng: random.Random) -> dict:
    store = workdir / f"trial-{n:03d}"
    accrue(store, "init")
    k = rng.randrange(len(windows))  # a step, then a moment inside its reference window
    delay = rng.uniform(0, windows[k][1])
    started = time.monotonic()
    proc = subprocess.Popen(
        [sys.executable, "-m", "cli.main", "run", str(wf)],
        cwd=ROOT,
        env=accrue_env(store),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    killed_in = "after it finished"
    if wait_for_step(store, proc, k):
        deadline = time.monotonic() + delay
        while proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.005)
        if proc.poll() is None:
            killed_in = running_step(store)
    try:
        os.killpg(proc.pid, signal.SIGKILL)  # the run and its children (lerobot-train)
    except ProcessLookupError:
        pass
    proc.wait()
    time.sleep(0.2)  # let the kernel reap the children and drop their locks
    result = {
        "trial": n,
        "aimed_at": windows[k][0],
        "delay_s": round(delay, 3),
        "killed_in": killed_in,
        "killed_after_s": round(time.monotonic() - started, 2),
    }
    result["after_kill_problems"] = verify_problems(store)
    result["after_kill_locks"] = held_locks(store)
    resumed = accrue(store, "run", str(wf), "--continue")
    result["resume_exit"] = resumed.returncode
    if resumed.returncode != 0:
        result["resume_error"] = resumed.stderr.strip()[-500:]
    result["final_problems"] = verify_problems(store)
    result["final_locks"] = held_locks(store)
    got = outputs_by_step(store) if resumed.returncode == 0 else {}
    result["differing_steps"] = sorted(k for k in reference if got.get(k) != reference[k])
    result["ok"] = (
        not result["after_kill_problems"]
        and not result["after_kill_locks"]
        and resumed.returncode == 0
        and not result["final_problems"]
        and not result["final_locks"]
        and not result["differing_steps"]
    )
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0, help="seed of the kill moments")
    parser.add_argument(
        "--base",
        default="scripted-reference:0.5",
        help="base_policy.init: scripted-reference:0.5 (default: no lerobot, every output byte-reproducible) "
        "or embedded-mlp (recorded demos and the in-process lerobot fine-tune; slower)",
    )
    parser.add_argument("--out", type=Path, help="write the results as JSON here")
    parser.add_argument("--workdir", type=Path, help="keep the stores here (default: a temp dir, removed)")
    parser.add_argument(
        "--runs-file", type=Path, help="add this run to a JSON file of runs whose top-level summary covers them all"
    )
    parser.add_argument(
        "--add-run",
        type=Path,
        metavar="OUT_JSON",
        help="with --runs-file: add a run an earlier --out wrote, run no trials",
    )
    parser.add_argument("--machine", default="", help="the machine's state, recorded with the run (e.g. other jobs)")
    args = parser.parse_args()
    if args.add_run:
        if not args.runs_file:
            parser.error("--add-run needs --runs-file")
        add_run(args.runs_file, json.loads(args.add_run.read_text()))
        print(f"{args.add_run} added to {args.runs_file}: {json.dumps(read_runs(args.runs_file)['summary'])}")
        return 0
    run_info = {
        "run_id": datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ") + f"-seed{args.seed}",
        "compares": COMPARES,
        "code": {"head_at_start": git_head(), "modified_at_start": git_modified()},
        "machine": {"cpus": os.cpu_count(), "loadavg_at_start": rounded_load(), "note": args.machine},
    }
    rng = random.Random(args.seed)
    with tempfile.TemporaryDirectory(prefix="accrue-faults-") as tmp:
        workdir = args.workdir or Path(tmp)
        workdir.mkdir(parents=True, exist_ok=True)
        wf = workdir / "harness.yaml"
        workflow = TINY.replace("BASE", json.dumps(args.base))
        wf.write_text(workflow)
        t0 = time.monotonic()
        reference, windows, span = reference_run(workdir, wf)
        print(f"reference run: {len(reference)} steps committed in {span:.1f} s", flush=True)
        results = []
        for n in range(args.trials):
            r = trial(n, workdir, wf, reference, windows, rng)
            results.append(r)
            if args.out or args.runs_file:  # after every trial: an interrupted harness still reports what it saw
                write_results(args, run_info, workflow, results, span, t0)
            print(
                f"trial {n:3d}: {'ok  ' if r['ok'] else 'FAIL'} killed after {r['killed_after_s']:6.1f} s in "
                f"{r['killed_in']}" + ("" if r["ok"] else f" — {json.dumps(r)}"),
                flush=True,
            )
            if not args.workdir:
                import shutil

                shutil.rmtree(workdir / f"trial-{n:03d}", ignore_errors=True)
    summary = write_results(args, run_info, workflow, results, span, t0)
    print(f"fault harness: {summary['passed']}/{len(results)} trials passed; kills landed in {summary['killed_in']}")
    return 0 if summary["passed"] == len(results) else 1


def write_results(
    args: argparse.Namespace, run_info: dict, workflow: str, results: list[dict], span: float, t0: float
) -> dict:
    passed = sum(r["ok"] for r in results)
    summary = {
        "trials": len(results),
        "requested": args.trials,
        "passed": passed,
        "failed": len(results) - passed,
        "reference_run_s": round(span, 1),
        "wall_s": round(time.monotonic() - t0, 1),
        "killed_in": kill_points(results),
    }
    if args.out or args.runs_file:
        command = "python scripts/fault_harness.py " + " ".join(shlex.quote(a) for a in sys.argv[1:])
        run = {
            "command": command,
            **run_info,
            "code": {**run_info["code"], "head_at_end": git_head()},
            "machine": {**run_info["machine"], "loadavg_at_end": rounded_load()},
            "workflow": workflow.strip(),
            "summary": summary,
            "results": results,
        }
        if args.out:
            args.out.parent.mkdir(parents=True, exist_ok=True)
            args.out.write_text(json.dumps(run, indent=1) + "\n")
        if args.runs_file:
            add_run(args.runs_file, run)
    return summary


# What a trial's "same outputs" means; runs measured with another comparison are summed apart.
COMPARES = "artifact ids of every output, every file (manifest format 2)"


def kill_points(results: list[dict]) -> dict[str, int]:
    """How many trials' kills landed in each step ('between steps', 'after it finished')."""
    hit: dict[str, int] = {}
    for r in results:
        for step in r["killed_in"].split(", "):
            hit[step] = hit.get(step, 0) + 1
    return dict(sorted(hit.items()))


def read_runs(path: Path) -> dict:
    return json.loads(path.read_text()) if path.exists() else {"runs": []}


def add_run(path: Path, run: dict) -> None:
    """Put RUN into PATH's runs (replacing the one with its run_id: a run rewrites itself after every
    trial) and recompute the top-level summaries; written whole to a temp file, then renamed."""
    doc = read_runs(path)
    runs = [r for r in doc["runs"] if not run.get("run_id") or r.get("run_id") != run["run_id"]]
    runs.append(run)
    groups: dict[str, list[dict]] = {}
    for r in runs:
        groups.setdefault(r.get("compares", "not recorded"), []).append(r)
    doc = {
        **{k: v for k, v in doc.items() if k not in ("summary", "other_comparisons", "runs")},
        "summary": aggregate(groups.pop(COMPARES, [])),
        "other_comparisons": {c: aggregate(rs) for c, rs in groups.items()},
        "runs": runs,
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(doc, indent=1) + "\n")
    os.replace(tmp, path)


def aggregate(runs: list[dict]) -> dict:
    results = [t for r in runs for t in r["results"]]
    passed = sum(t["ok"] for t in results)
    return {
        "compares": COMPARES if not runs else runs[0].get("compares", "not recorded"),
        "runs": len(runs),
        "trials": len(results),
        "passed": passed,
        "failed": len(results) - passed,
        "killed_in": kill_points(results),
        "failed_trials": [
            {"command": r["command"], "trial": t["trial"]} for r in runs for t in r["results"] if not t["ok"]
        ],
        "commands": [r["command"] for r in runs],
        "code": sorted(
            {h for r in runs for h in (r.get("code", {}).get(k) for k in ("head_at_start", "head_at_end")) if h}
        ),
        "machine": sorted({r["machine"]["note"] for r in runs if r.get("machine", {}).get("note")}),
    }


def git_head() -> str | None:
    proc = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    return proc.stdout.strip() if proc.returncode == 0 else None


def git_modified() -> list[str]:
    """Tracked files that differ from HEAD (the trials ran this working tree, not only HEAD)."""
    proc = subprocess.run(
        ["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT, capture_output=True, text=True
    )
    return [line[3:] for line in proc.stdout.splitlines()] if proc.returncode == 0 else []


def rounded_load() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


if __name__ == "__main__":
    sys.exit(main())
