"""Write the Markdown tables of bench specs (per method and per ordering, with bootstrap CIs, the
command, seeds and orderings that made them), so the documentation's tables are generated, never typed.

    python scripts/bench_tables.py workflows/bench/nist-small.yaml [more specs] [--store PATH]
    python scripts/bench_tables.py workflows/bench/nist-small.yaml --doc docs/benchmark/nist.md
    python scripts/bench_tables.py workflows/bench/contact-headline.yaml --records-root benchmarks/results/bench

With --records-root ROOT, cells the store has not done come from their records in ROOT/<spec name>/cells
(stages/bench/records.py), and a record is written there for every cell the store has done.

With --doc FILE, each spec's tables replace what lies between the markers
    <!-- bench:<spec name> -->  and  <!-- /bench:<spec name> -->
in that file (add the two marker lines where the table goes); without it they go to stdout. The benchmark
pages are docs/benchmark/contact.md (contact-*, bias-control) and docs/benchmark/nist.md (nist-*, retained-n).
--readme is the same option under its earlier name. --curves adds each method's whole learning curve per
stage (the tuning specs, where the question is the curve's shape).
Exit 2 with one line on a bad spec, a missing store, a bad record or missing markers.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def tables(
    spec_path: Path, store, command: str, records_root: Path | None = None, curves: bool = False
) -> tuple[str, str]:
    """A spec's Markdown tables; with records_root, from the store plus the cell records in
    <records_root>/<spec name>/cells (refreshed from the store's done cells, as `bench report --records`)."""
    from stages.bench.records import write_records
    from stages.bench.report import markdown, report_with_records
    from stages.bench.spec import load_spec

    spec = load_spec(spec_path)
    directory = None if records_root is None else records_root / spec.name / "cells"
    report, fresh = report_with_records(store, spec, directory)
    if directory is not None:
        write_records(directory, fresh)
    return spec.name, markdown(report, command=command, heading_level=3, curves=curves)


def replace_between_markers(text: str, name: str, block: str, where: str) -> str:
    from stages.errors import StageError

    start, end = f"<!-- bench:{name} -->", f"<!-- /bench:{name} -->"
    pattern = re.compile(re.escape(start) + r".*?" + re.escape(end), re.S)
    if not pattern.search(text):
        raise StageError(f"{where}: no {start} ... {end} markers; add them where the {name} tables go")
    return pattern.sub(lambda _: f"{start}\n{block.rstrip()}\n{end}", text, count=1)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("specs", nargs="+", type=Path, help="bench spec YAML files")
    ap.add_argument("--store", type=Path, default=None, help="store (default $ACCRUE_STORE or ./.accrue)")
    ap.add_argument(
        "--doc", "--readme", dest="readme", type=Path, default=None, help="replace the marked blocks in this file"
    )
    ap.add_argument(
        "--records-root",
        type=Path,
        default=None,
        help="cell records in ROOT/<spec name>/cells: used for cells the store has not done, refreshed from the rest",
    )
    ap.add_argument("--curves", action="store_true", help="add every method's whole learning curve per stage")
    args = ap.parse_args(argv)
    from accrue.errors import AccrueError
    from artifacts.errors import StoreError
    from artifacts.store import Store
    from stages.errors import StageError

    command = "python scripts/bench_tables.py " + " ".join(argv)
    try:
        store = Store.open(args.store)
        blocks = [tables(p, store, command, args.records_root, args.curves) for p in args.specs]
        if args.readme is None:
            print("\n".join(b for _, b in blocks))
            return 0
        try:
            text = args.readme.read_text(encoding="utf-8")
        except OSError as exc:
            raise StageError(f"{args.readme}: cannot read ({exc.__class__.__name__})") from None
        for name, block in blocks:
            text = replace_between_markers(text, name, block, str(args.readme))
        tmp = args.readme.with_name(args.readme.name + ".tmp")
        tmp.write_text(text, encoding="utf-8")
        tmp.replace(args.readme)
        print(f"{args.readme}: wrote the tables of {', '.join(n for n, _ in blocks)}")
        return 0
    except (StageError, StoreError, AccrueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
