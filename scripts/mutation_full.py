"""The full mutation sweep (issue 23): mutmut over accrue/learner/, accrue/methods.py, accrue/stage_rl.py,
accrue/metrics.py and artifacts/ ([tool.mutmut] in pyproject.toml), in a copy of the tree outside the
working tree, so other work in the checkout is never touched.

    .venv/bin/python scripts/mutation_full.py                       # run (or resume) the sweep
    .venv/bin/python scripts/mutation_full.py --time-limit 1800     # stop after 30 min; resume later
    .venv/bin/python scripts/mutation_full.py --only 'accrue.learner.losses*'   # some mutants only
    .venv/bin/python scripts/mutation_full.py --report              # counts and survivors so far
    .venv/bin/python scripts/mutation_full.py --names /tmp/accrue-mutmut/survivors.txt   # re-run the survivors

mutmut keeps its results in WORKDIR/tree/mutants/, so a second call continues where the first stopped
(and re-tests functions whose code changed). Survivors are written to WORKDIR/survivors.txt, one
`mutmut show` name a line; each is triaged in docs/MUTATION.md (killed by a new test, or equivalent).
The critical, named mutations that CI checks are scripts/mutation_critical.py.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mutation_critical import PYTEST_ENV, ROOT, copy_tree  # noqa: E402

MUTMUT = Path(sys.executable).with_name("mutmut")


def refresh(tree: Path, source: str) -> None:
    """Copy the current tree over WORKDIR/tree, keeping mutants/ (mutmut's results) in place."""
    tree.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        copy_tree(Path(tmp), source)
        subprocess.run(["cp", "-a", f"{tmp}/.", str(tree)], check=True)


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


def run_sweep(tree: Path, children: int, time_limit: float | None, only: list[str]) -> int:
    env = {**os.environ, **PYTEST_ENV}
    cmd = ["nice", "-n", "10", str(MUTMUT), "run", "--max-children", str(children), *only]
    proc = subprocess.Popen(cmd, cwd=tree, env=env, start_new_session=True)
    try:
        return proc.wait(timeout=time_limit)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGINT)  # mutmut saves what it has; the next call resumes
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        print(f"stopped after {time_limit:.0f} s (resume with the same command)", flush=True)
        return 0


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
    ap.add_argument("--only", action="append", default=[], help="mutant name pattern (repeatable)")
    ap.add_argument("--names", type=Path, help="file of mutant names or patterns, one a line (e.g. survivors.txt)")
    ap.add_argument("--source", choices=("worktree", "head"), default="worktree", help="head: the last commit")
    ap.add_argument("--deselect", action="append", default=[], help="test node id to leave out (repeatable)")
    ap.add_argument("--report", action="store_true", help="only print what is known so far")
    args = ap.parse_args(argv)
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
        refresh(tree, args.source)
        deselect(tree, args.deselect)
        rc = run_sweep(tree, args.children, args.time_limit, args.only)
        if rc not in (0, 1):
            print(f"error: mutmut exited {rc}", file=sys.stderr)
            return rc
    report(tree, args.workdir / "survivors.txt")
    return 0


if __name__ == "__main__":
    sys.exit(main())
