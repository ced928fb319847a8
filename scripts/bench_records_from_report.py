"""Write cell records (stages/bench/records.py) from the per-cell rows of a committed bench report.json,
for cells whose store is gone: `accrue bench report SPEC --records DIR` then folds them together with
cells measured on another machine.

    python scripts/bench_records_from_report.py benchmarks/results/bench/contact-headline/report.json \\
        --out benchmarks/results/bench/contact-headline/cells

Only the metrics survive in a report (it keeps mean stage curves, not each cell's), so these records have
no stage curves; their provenance names the report file, the git commit that last changed it and says
that the store was not available. Exit 2 with one line on an unreadable or malformed report.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def last_commit(path: Path) -> str | None:
    """The commit that last changed `path` (None outside git, or for a file git does not track)."""
    try:
        out = subprocess.run(
            ["git", "-C", str(ROOT), "log", "-1", "--format=%H", "--", str(path.resolve())],
            capture_output=True,
            text=True,
            timeout=30,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return (out.stdout.strip() or None) if out.returncode == 0 else None


def shown_path(path: Path) -> str:
    """The report's path relative to the repository where it lies inside it (records stay machine-neutral)."""
    try:
        return str(path.resolve().relative_to(ROOT))
    except ValueError:
        return str(path)


def records_from_report(report: dict, where: str, provenance: dict) -> list[dict]:
    from stages.bench.records import report_row_record
    from stages.errors import StageError

    try:
        spec, orderings, threshold = report["spec"], report["orderings"], report["success_threshold"]
        rows = [c for c in report["cells"] if c.get("metrics") is not None]
        return [report_row_record(spec, row, orderings[row["ordering"]], threshold, provenance) for row in rows]
    except (KeyError, TypeError, AttributeError) as exc:
        raise StageError(f"{where}: not a bench report.json (missing or malformed {exc})") from None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("report", type=Path, help="a bench report.json (benchmarks/results/bench/<spec>/report.json)")
    ap.add_argument("--out", type=Path, required=True, help="directory of the records (<cell>.json)")
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    from stages.bench.records import write_records
    from stages.errors import StageError

    try:
        try:
            report = json.loads(args.report.read_text(encoding="utf-8"))
        except OSError as exc:
            raise StageError(f"{args.report}: cannot read ({exc.__class__.__name__})") from None
        except ValueError as exc:
            raise StageError(f"{args.report}: not valid JSON ({exc})") from None
        provenance = {
            "report": shown_path(args.report),
            "report_commit": last_commit(args.report),
            "store": None,
            "note": "store not available",
            "host": None,
        }
        records = records_from_report(report, str(args.report), provenance)
        written = write_records(args.out, records)
    except StageError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{args.out}: {len(written)} records written ({len(records) - len(written)} unchanged) from {args.report}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
