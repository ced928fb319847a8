"""Check survivor triage one mutant per pytest process (issue 23): for each mutmut mutant named, run the given
test files with that mutant switched on (`MUTANT_UNDER_TEST=NAME`) in a copy of the sweep's mutants/ tree,
and once with none, so "killed by test X" in docs/MUTATION.md is a measured fact, not a reading.

    .venv/bin/python scripts/mutation_verify.py NAMES.txt tests/test_mutation_survivors_artifacts_misc.py
    .venv/bin/python scripts/mutation_verify.py NAMES.txt TESTS... --out verdicts.tsv --mutants DIR

NAMES.txt: one mutant name a line (`mutmut results` spelling). The test files are copied from this checkout into
the copy (tests/ whole, with its helper modules), so new tests can be checked against mutants generated before
them. Prints, and writes to --out, one `NAME<TAB>killed<TAB>TEST|survived|error rc=N|timeout` line a mutant:
killed = pytest exit 1 (a test failed; TEST is the one that failed first, pytest runs with -x), survived =
exit 0; anything else (a collection error, a crash) is not a kill. Exit 1 if the clean run fails.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mutation_critical import PYTEST_ENV, ROOT  # noqa: E402

SWEEP_MUTANTS = Path(tempfile.gettempdir()) / "accrue-mutmut" / "tree" / "mutants"
IGNORED = shutil.ignore_patterns(".hypothesis", "__pycache__")


def run_tests(where: Path, tests: list[str], mutant: str | None, timeout: float) -> str:
    """'killed<TAB>the first failing test', 'survived', 'timeout' or 'error rc=N'."""
    env = {k: v for k, v in os.environ.items() if k != "MUTANT_UNDER_TEST"} | PYTEST_ENV
    if mutant is not None:
        env["MUTANT_UNDER_TEST"] = mutant
    cmd = [sys.executable, "-m", "pytest", "-x", "-q", "-rf", "-p", "no:cacheprovider", *tests]
    try:
        done = subprocess.run(cmd, cwd=where, env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return "timeout"
    if done.returncode == 1:  # -x: the one failure is the test that killed it (a triage line names one test)
        failed = [
            line.removeprefix("FAILED ").split(" - ")[0]
            for line in done.stdout.splitlines()
            if line.startswith("FAILED ")
        ]
        return "\t".join(["killed", *failed[:1]])
    return {0: "survived"}.get(done.returncode, f"error rc={done.returncode}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("names", type=Path)
    ap.add_argument("tests", nargs="+", help="test files (or node ids) relative to the repository root")
    ap.add_argument("--mutants", type=Path, default=SWEEP_MUTANTS, help="the sweep's mutants/ (copied, not used)")
    ap.add_argument("--out", type=Path)
    ap.add_argument("--source", type=Path, default=ROOT, help="where the test files are copied from")
    ap.add_argument("--timeout", type=float, default=120.0, help="seconds a mutant's run may take")
    args = ap.parse_args(argv)
    try:
        names = [n.strip() for n in args.names.read_text().splitlines() if n.strip()]
    except OSError as exc:
        print(f"error: {args.names}: {exc.strerror}", file=sys.stderr)
        return 2
    if not (args.mutants / "mutmut-stats.json").is_file():
        print(f"error: {args.mutants} is not a mutmut mutants/ directory (no mutmut-stats.json)", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        where = Path(tmp) / "mutants"
        shutil.copytree(args.mutants, where, ignore=IGNORED)
        # the tests as they are in this checkout, with the helper modules they import
        shutil.copytree(args.source / "tests", where / "tests", dirs_exist_ok=True, ignore=IGNORED)
        clean = run_tests(where, args.tests, None, args.timeout)
        if clean != "survived":
            print(f"error: the tests do not pass without a mutant ({clean})", file=sys.stderr)
            return 1
        lines = []
        for name in names:
            lines.append(f"{name}\t{run_tests(where, args.tests, name, args.timeout)}")
            print(lines[-1], flush=True)
    if args.out:
        args.out.write_text("".join(f"{line}\n" for line in lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
