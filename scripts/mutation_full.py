"""The full mutation sweep (issue 23): mutmut over accrue/learner/, accrue/methods.py, accrue/stage_rl.py,
accrue/metrics.py and artifacts/ ([tool.mutmut] in pyproject.toml), in a copy of the tree outside the
working tree, so other work in the checkout is never touched.

    .venv/bin/python scripts/mutation_full.py                       # run (or resume) the sweep
    .venv/bin/python scripts/mutation_full.py --time-limit 1800     # stop after 30 min; resume later
    .venv/bin/python scripts/mutation_full.py --mutant-limit 120    # a worker waiting 120 s counts as timeout
    .venv/bin/python scripts/mutation_full.py --only 'accrue.learner.losses*'   # some mutants only
        # (mutmut re-runs every mutant --only or --names gives, checked or not: to check only the unchecked
        #  ones, pass their names with --names)
    .venv/bin/python scripts/mutation_full.py --report              # counts and survivors so far
    .venv/bin/python scripts/mutation_full.py --counts              # the kept verdicts, a table per file
    .venv/bin/python scripts/mutation_full.py --counts --untriaged LEFT.txt   # survivors no triage file names
    .venv/bin/python scripts/mutation_full.py --names /tmp/accrue-mutmut/survivors.txt   # re-run the survivors

mutmut keeps its results in WORKDIR/tree/mutants/, so a second call continues where the first stopped
(and re-tests functions whose code changed). After each call its verdicts (mutmut's `.meta` files) are
copied to benchmarks/results/mutation/mutmut/ (`--records`), which git keeps: on a new machine, with no
WORKDIR yet, the sweep starts from them instead of from nothing. Survivors are written to
WORKDIR/survivors.txt, one `mutmut show` name a line; each is triaged in docs/MUTATION.md (killed by a new test, or equivalent).
The critical, named mutations that CI checks are scripts/mutation_critical.py.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import tomllib
from collections import Counter
from pathlib import Path

import psutil

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mutation_critical import PYTEST_ENV, ROOT, copy_tree  # noqa: E402

MUTMUT = Path(sys.executable).with_name("mutmut")
RECORDS = ROOT / "benchmarks" / "results" / "mutation" / "mutmut"
TRIAGE = RECORDS.parent / "triage"  # NAME<TAB>killed|equivalent<TAB>the test, or why: one file per triage
CONFIG = "mutmut-config.json"  # the [tool.mutmut] table the kept verdicts were measured under


def mutmut_config(tree: Path) -> dict:
    path = tree / "pyproject.toml"
    return tomllib.loads(path.read_text()).get("tool", {}).get("mutmut", {}) if path.exists() else {}


def record_files(mutants: Path) -> list[Path]:
    """The `.meta` file mutmut keeps beside each mutated file (each mutant's exit code, each function's source
    hash), relative to mutants/. That is all a sweep needs to resume: mutmut writes the mutated sources again,
    resets the verdicts of any function whose hash changed, and rebuilds its function-to-test map (a few MB,
    not kept) with one run of the selection."""
    return sorted(p.relative_to(mutants) for p in mutants.rglob("*.meta"))


def save_records(tree: Path, records: Path) -> int:
    """Copy the sweep's verdicts to `records` (replacing what was there); the number of files copied."""
    mutants = tree / "mutants"
    files = record_files(mutants)
    if not files:
        return 0
    for old in record_files(records) if records.is_dir() else []:
        (records / old).unlink()
    for rel in files:
        (records / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(mutants / rel, records / rel)
    (records / CONFIG).write_text(json.dumps(mutmut_config(tree), indent=1, sort_keys=True) + "\n")
    return len(files)


def restore_records(records: Path, tree: Path, config: dict) -> str:
    """Start a sweep on a new machine from the verdicts in `records`, never over a sweep already in `tree`, and
    only if they were measured under `config`: a different test selection or pytest arguments make every verdict
    stale (mutmut itself resets them all on such a change, but only while it still has its own map)."""
    mutants = tree / "mutants"
    if mutants.exists() or not (records / CONFIG).is_file():
        return ""
    if json.loads((records / CONFIG).read_text()) != config:
        return f"not resuming from {records}: its verdicts were measured under another [tool.mutmut]"
    files = record_files(records)
    for rel in files:
        (mutants / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(records / rel, mutants / rel)
    return f"resuming from the verdicts of {len(files)} files in {records}"


def refresh(tree: Path, source: str) -> None:
    """Copy the current tree over WORKDIR/tree, keeping mutants/ (mutmut's results) in place."""
    tree.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        copy_tree(Path(tmp), source)
        subprocess.run(["cp", "-a", f"{tmp}/.", str(tree)], check=True)


def code_digest(tree: Path) -> str | None:
    """One hash over the .py files of `[tool.mutmut] source_paths` in tree (None before the first copy)."""
    roots = [tree / base for base in mutmut_config(tree).get("source_paths", [])]
    if not any(root.is_dir() for root in roots):
        return None
    digest = hashlib.blake2b()
    for path in sorted(p for root in roots if root.is_dir() for p in root.rglob("*.py")):
        digest.update(str(path.relative_to(tree)).encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def forget_test_map(tree: Path) -> bool:
    """Make mutmut collect its map of which tests reach which function again, over the whole selection. Its
    own update after a code change only runs the tests that are new: a function the change created (or a call
    it added) is then reached by those alone, and its mutants that only old tests would kill survive. The
    verdicts (the .meta files) are kept; mutmut still re-tests only the functions whose code changed."""
    stats = tree / "mutants" / "mutmut-stats.json"
    if not stats.exists():
        return False
    stats.unlink()
    return True


def deselect(tree: Path, nodes: list[str]) -> None:
    """Leave known-failing tests out of this sweep (in the copy's pyproject only): mutmut needs green tests."""
    if not nodes:
        return
    path = tree / "pyproject.toml"
    text = path.read_text()
    key = 'pytest_add_cli_args = ["'
    if text.count(key) != 1:
        raise SystemExit("error: [tool.mutmut] pytest_add_cli_args not found in pyproject.toml")
    extra = "".join(f'"--deselect", "{n}", ' for n in nodes)
    path.write_text(text.replace(key, f"pytest_add_cli_args = [{extra}" + '"', 1))


class MutantWatchdog(threading.Thread):
    """Ends a mutant worker that has run `limit` seconds of wall time. mutmut's own limit counts CPU time, so a
    mutant that sleeps or waits (a retry loop, a lock, moto's backoff) never reaches it: SIGXCPU first, which
    mutmut records as a timeout, then SIGKILL `grace` seconds later. Only mutmut's workers are watched: its
    children (`depth` 1), or under its fork server (`process_isolation = "forkserver"`) the server's children
    (`depth` 2), never the long-lived server; and only once `armed` is set (mutmut prints "Running mutation
    testing"), so the stats and clean runs before it are never cut short."""

    def __init__(self, pid: int, limit: float, grace: float = 30.0, poll: float = 2.0, depth: int = 1):
        super().__init__(daemon=True)
        self.pid, self.limit, self.grace, self.poll, self.depth = pid, limit, grace, poll, depth
        self.armed, self.done = threading.Event(), threading.Event()
        self.ended: list[tuple[int, str]] = []  # (pid, "XCPU" | "KILL"), for the log and the tests
        self.warned_at: dict[int, float] = {}  # pid -> when SIGXCPU was sent

    def run(self) -> None:
        while not self.done.wait(self.poll):
            if self.armed.is_set():
                self.check()

    def workers(self) -> list[psutil.Process]:
        try:
            level = [psutil.Process(self.pid)]
        except psutil.Error:
            return []  # mutmut has ended
        for _ in range(self.depth):
            below = []
            for proc in level:
                try:
                    below += proc.children()
                except psutil.Error:
                    continue  # ended meanwhile
            level = below
        return level

    def check(self) -> None:
        children = self.workers()
        now = time.time()
        for child in children:
            try:
                warned_at = self.warned_at.get(child.pid)
                if (child.pid, "KILL") in self.ended:
                    continue  # dying; not yet reaped
                # SIGKILL counts its grace from the SIGXCPU actually sent, so a watchdog that a busy machine
                # schedules late still sends SIGXCPU first (mutmut reads only that one as a timeout)
                if warned_at is not None and now - warned_at > self.grace:
                    child.kill()
                    self.ended.append((child.pid, "KILL"))
                elif warned_at is None and now - child.create_time() > self.limit:
                    child.send_signal(signal.SIGXCPU)
                    self.warned_at[child.pid] = now
                    self.ended.append((child.pid, "XCPU"))
            except psutil.Error:
                continue  # the mutant ended on its own meanwhile


def forward_output(stream, watchdog: MutantWatchdog) -> None:
    """Copy mutmut's output through, arming the watchdog when the mutants start running."""
    seen = b""
    for chunk in iter(lambda: stream.read1(4096), b""):
        sys.stdout.buffer.write(chunk)
        sys.stdout.flush()
        if not watchdog.armed.is_set():
            seen = (seen + chunk)[-200:]
            if b"Running mutation testing" in seen:
                watchdog.armed.set()


def stop(proc: subprocess.Popen) -> None:
    """mutmut 3.8 ignores SIGINT; it saves each mutant's verdict as it comes, so SIGTERM loses only the
    mutant in flight (SIGKILL if it is still there 30 s later). The next call resumes."""
    os.killpg(proc.pid, signal.SIGTERM)
    try:
        proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def isolation(tree: Path) -> str:
    """mutmut's process_isolation for this tree ("fork", its default, or "forkserver")."""
    path = tree / "pyproject.toml"
    config = tomllib.loads(path.read_text()) if path.exists() else {}
    return config.get("tool", {}).get("mutmut", {}).get("process_isolation", "fork")


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def run_sweep(tree: Path, children: int, time_limit: float | None, only: list[str], mutant_limit: float) -> int:
    env = {**os.environ, **PYTEST_ENV}
    cmd = ["nice", "-n", "10", str(MUTMUT), "run", "--max-children", str(children), *only]
    proc = subprocess.Popen(cmd, cwd=tree, env=env, start_new_session=True, stdout=subprocess.PIPE)
    watchdog = MutantWatchdog(proc.pid, mutant_limit, depth=2 if isolation(tree) == "forkserver" else 1)
    watchdog.start()
    reader = threading.Thread(target=forward_output, args=(proc.stdout, watchdog), daemon=True)
    reader.start()
    # mutmut runs in its own session (so a stop reaches its workers): a SIGTERM or Ctrl-C to this script
    # must be passed on, or mutmut would go on alone
    signal.signal(signal.SIGTERM, _interrupt)
    try:
        return proc.wait(timeout=time_limit)
    except (subprocess.TimeoutExpired, KeyboardInterrupt) as why:
        stop(proc)
        after = f" after {time_limit:.0f} s" if isinstance(why, subprocess.TimeoutExpired) else ""
        print(f"\nstopped{after} (resume with the same command)", flush=True)
        return 0
    finally:
        watchdog.done.set()
        reader.join(timeout=5)
        if watchdog.ended:
            print(f"watchdog: {len(watchdog.ended)} signals to mutants past {mutant_limit:.0f} s", flush=True)


def verdict_counts(records: Path) -> dict[str, Counter]:
    """mutmut's verdict per mutant, counted per mutated file, from kept `.meta` files (no mutmut run needed)."""
    from mutmut.stats import status_by_exit_code  # mutmut's own reading of its exit codes

    counts: dict[str, Counter] = {}
    for rel in record_files(records):
        codes = json.loads((records / rel).read_text()).get("exit_code_by_key", {})
        if codes:
            counts[str(rel.with_suffix(""))] = Counter(status_by_exit_code[code] for code in codes.values())
    return counts


def survivors(records: Path) -> list[str]:
    """The mutants the kept verdicts say survived (mutmut's exit code 0: every mapped test passed)."""
    names = []
    for rel in record_files(records):
        codes = json.loads((records / rel).read_text()).get("exit_code_by_key", {})
        names += [name for name, code in codes.items() if code == 0]
    return sorted(names)


def triaged(triage: Path) -> dict[str, str]:
    """Each triaged mutant's verdict ("killed" by a named test, or "equivalent"), from the triage files."""
    verdicts = {}
    for path in sorted(triage.glob("*.tsv")) if triage.is_dir() else []:
        for line in path.read_text().splitlines():
            name, _, rest = line.partition("\t")
            if rest:
                verdicts[name.strip()] = rest.split("\t")[0].strip()
    return verdicts


def stale_triage(records: Path, triage: Path) -> list[str]:
    """Triage lines the kept verdicts no longer bear out: a mutant called equivalent that the sweep now kills,
    or a name no kept verdict has. Both happen when a function's code changed after its triage: mutmut numbers
    a function's mutants afresh, so an old line then names another mutation (or none); look at it again."""
    codes = {}
    for rel in record_files(records):
        codes.update(json.loads((records / rel).read_text()).get("exit_code_by_key", {}))
    return sorted(
        name
        for name, verdict in triaged(triage).items()
        if name not in codes or (verdict == "equivalent" and codes[name] == 1)
    )


def print_counts(counts: dict[str, Counter]) -> None:
    """A Markdown table: one row per mutated file, a total row per top-level package."""
    columns = ["killed", "survived", "timeout", "no tests", "not checked"]
    others = sorted({s for c in counts.values() for s in c} - set(columns))
    print("| file | " + " | ".join(columns + others) + " | all |")
    print("| --- |" + " ---: |" * (len(columns) + len(others) + 1))
    totals: dict[str, Counter] = {}
    for name, c in sorted(counts.items()):
        totals.setdefault(name.split("/")[0], Counter()).update(c)
        print(f"| `{name}` | " + " | ".join(f"{c[s]:,}" for s in columns + others) + f" | {c.total():,} |")
    for top, c in sorted(totals.items()):
        print(f"| **{top}/ in all** | " + " | ".join(f"{c[s]:,}" for s in columns + others) + f" | {c.total():,} |")


def print_triage_counts(triage: Path) -> None:
    """A Markdown table: per triage file, how many mutants it names killed and equivalent."""
    print("| triage file | killed | equivalent |")
    print("| --- | ---: | ---: |")
    for path in sorted(triage.glob("*.tsv")) if triage.is_dir() else []:
        c = Counter(line.split("\t")[1].strip() for line in path.read_text().splitlines() if "\t" in line)
        print(f"| `{path.name}` | {c['killed']:,} | {c['equivalent']:,} |")


def report(tree: Path, out: Path) -> dict[str, list[str]]:
    """mutmut's verdict per mutant (`mutmut results --all true`), grouped; survivors written to `out`."""
    res = subprocess.run(
        [str(MUTMUT), "results", "--all", "true"], cwd=tree, capture_output=True, text=True, env=os.environ
    )
    groups: dict[str, list[str]] = {}
    for line in res.stdout.splitlines():
        name, sep, status = line.strip().rpartition(": ")
        if sep:
            groups.setdefault(status, []).append(name)
    survivors = sorted(groups.get("survived", []))
    out.write_text("".join(f"{n}\n" for n in survivors))
    for status, names in sorted(groups.items()):
        print(f"{status:14s} {len(names)}")
    print(f"survivors listed in {out}")
    return groups


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workdir", type=Path, default=Path(tempfile.gettempdir()) / "accrue-mutmut")
    ap.add_argument("--children", type=int, default=max(1, (os.cpu_count() or 2) // 2))
    ap.add_argument("--time-limit", type=float, default=None, help="seconds, then stop (resumable)")
    ap.add_argument(
        "--mutant-limit", type=float, default=180.0, help="wall seconds a mutant may run before it counts as a timeout"
    )
    ap.add_argument("--only", action="append", default=[], help="mutant name pattern (repeatable)")
    ap.add_argument("--names", type=Path, help="file of mutant names or patterns, one a line (e.g. survivors.txt)")
    ap.add_argument("--source", choices=("worktree", "head"), default="worktree", help="head: the last commit")
    ap.add_argument("--deselect", action="append", default=[], help="test node id to leave out (repeatable)")
    ap.add_argument("--report", action="store_true", help="only print what is known so far")
    ap.add_argument("--counts", action="store_true", help="print the kept verdicts' counts per file (Markdown)")
    ap.add_argument("--triage", type=Path, default=TRIAGE, help="the triage files (with --counts)")
    ap.add_argument(
        "--untriaged",
        type=Path,
        help="with --counts: write the survivors not yet triaged, and stale triage lines, here",
    )
    ap.add_argument("--records", type=Path, default=RECORDS, help="where the verdicts are kept between machines")
    args = ap.parse_args(argv)
    if args.counts:
        if not args.records.is_dir():
            print(f"error: no kept verdicts in {args.records}", file=sys.stderr)
            return 2
        print_counts(verdict_counts(args.records))
        alive, known = survivors(args.records), triaged(args.triage)
        left = [n for n in alive if n not in known]
        print(f"\nsurvivors: {len(alive):,}, not yet triaged in {args.triage}: {len(left):,}\n")
        print_triage_counts(args.triage)
        stale = stale_triage(args.records, args.triage)
        if stale:
            print(f"\ntriage lines to look at again (equivalent but now killed, or no such mutant): {len(stale):,}")
            print("".join(f"- {n}\n" for n in stale), end="")
        if args.untriaged:
            args.untriaged.write_text("".join(f"{n}\n" for n in left + stale))
        return 0
    if not MUTMUT.exists():
        print("error: mutmut is not installed: run `bash scripts/setup.sh` (it is a dev dependency)", file=sys.stderr)
        return 2
    if args.names is not None:
        try:
            args.only += [n.strip() for n in args.names.read_text().splitlines() if n.strip()]
        except OSError as exc:
            print(f"error: --names {args.names}: {exc.strerror}", file=sys.stderr)
            return 2
    tree = args.workdir / "tree"
    if args.report and not (tree / "mutants").is_dir():
        print(f"error: no sweep in {args.workdir} yet (run without --report first)", file=sys.stderr)
        return 2
    if not args.report:
        if args.workdir.resolve().is_relative_to(ROOT):
            print("error: --workdir must be outside the working tree", file=sys.stderr)
            return 2
        before = code_digest(tree)
        refresh(tree, args.source)  # mutants/ is left as it was: restoring below only fills a missing one
        if before is not None and code_digest(tree) != before and forget_test_map(tree):
            print("the mutated code changed since the last run: mutmut's test map is collected again", flush=True)
        said = restore_records(args.records, tree, mutmut_config(tree))
        if said:
            print(said, flush=True)
        deselect(tree, args.deselect)
        rc = run_sweep(tree, args.children, args.time_limit, args.only, args.mutant_limit)
        saved = save_records(tree, args.records)
        print(f"verdicts kept in {args.records} ({saved} files; commit them to resume elsewhere)", flush=True)
        if rc not in (0, 1):
            print(f"error: mutmut exited {rc}", file=sys.stderr)
            return rc
    report(tree, args.workdir / "survivors.txt")
    return 0


if __name__ == "__main__":
    sys.exit(main())
