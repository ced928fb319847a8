"""Author the built-in plug/socket/gripper parts as USD under accrue/sim/assets/<family>/<name>/.

Run after changing accrue/sim/part_shapes.py or PART_TABLE / CONTACT_PART_TABLE / CONTACT2_PART_TABLE in
accrue/sim/tasks.py:
    .venv/bin/python scripts/make_parts.py [--out DIR]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from accrue.sim.part_shapes import build_parts
from accrue.sim.tasks import ASSET_DIR, CONTACT2_PART_TABLE, CONTACT_PART_TABLE, PART_TABLE
from accrue.sim.usd_parts import write_part


def build_all(out: Path) -> list[Path]:
    written = []
    tables = [*PART_TABLE.items(), *CONTACT_PART_TABLE.items(), *CONTACT2_PART_TABLE.items()]
    for name, (family, shape, clearance, depth, chamfer, length) in tables:
        parts = build_parts(shape, clearance, depth, chamfer, length)
        folder = out / family / name
        for role, pieces in (("plug", parts.plug), ("socket", parts.socket), ("gripper", parts.gripper)):
            write_part(folder / f"{role}.usda", pieces, name=role.capitalize())
            written.append(folder / f"{role}.usda")
    return written


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ASSET_DIR)
    args = ap.parse_args()
    for p in build_all(args.out):
        print(p)


if __name__ == "__main__":
    main()
