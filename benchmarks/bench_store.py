"""Store benchmarks (a script, not a test): prints

1. ingest throughput of a large file (default 1 GiB) into the store vs raw BLAKE3 on the same file
   (goal: >= 0.8x), with the page cache warm for both;
2. `accrue log` wall time over a 10,000-event audit log (default view, and --all --json);
3. `accrue --help` cold-start time (goal: < 0.5 s).

  .venv/bin/python benchmarks/bench_store.py [--size-mb 1024] [--events 10000] [--dir DIR]
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import blake3
from rich.console import Console
from rich.table import Table

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from artifacts.auditlog import GENESIS  # noqa: E402
from artifacts.hashing import canonical_json, hash_bytes, hash_file  # noqa: E402
from artifacts.manifests import now_iso  # noqa: E402
from artifacts.store import Store  # noqa: E402

ACCRUE = (
    [str(ROOT / ".venv" / "bin" / "accrue")]
    if (ROOT / ".venv" / "bin" / "accrue").exists()
    else [sys.executable, "-m", "cli.main"]
)


def make_file(path: Path, size: int) -> None:
    block = os.urandom(16 * 1024 * 1024)
    with open(path, "wb") as f:
        written = 0
        while written < size:
            n = min(len(block), size - written)
            f.write(block[:n] if written % (3 * len(block)) else os.urandom(n))  # not all one block
            written += n


def best_of(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def bench_ingest(work: Path, size: int, repeat: int) -> list[tuple[str, str]]:
    src = work / "big.bin"
    make_file(src, size)
    hash_file(src)  # warm the page cache for every contender alike

    def raw_threaded():
        h = blake3.blake3(max_threads=blake3.blake3.AUTO)
        h.update_mmap(str(src))
        h.hexdigest()

    def raw_single():
        h = blake3.blake3()
        with open(src, "rb", buffering=0) as f:
            buf = bytearray(8 << 20)
            while n := f.readinto(buf):
                h.update(memoryview(buf)[:n])
        h.hexdigest()

    def ingest():
        store_dir = work / "store"
        if store_dir.exists():
            shutil.rmtree(store_dir)
        Store.init(store_dir)[0].ingest_file(src)

    def copy_hash_only():  # the one-pass copy+hash into the store's tmp area, no fsync/link
        from artifacts.hashing import copy_hashing

        tmp = work / "copy.tmp"
        tmp.unlink(missing_ok=True)
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT)
        try:
            with open(src, "rb", buffering=0) as f:
                copy_hashing(f, fd, size)
        finally:
            os.close(fd)

    def plain_copy():  # what any durable ingest must at least pay: the kernel copies, no hashing
        dst = work / "plain.tmp"
        dst.unlink(missing_ok=True)
        fi, fo = os.open(src, os.O_RDONLY), os.open(dst, os.O_WRONLY | os.O_CREAT)
        try:
            done = 0
            while done < size:
                done += os.copy_file_range(fi, fo, size - done)
            os.fsync(fo)
        finally:
            os.close(fi)
            os.close(fo)

    t_raw = best_of(raw_threaded, repeat)
    t_single = best_of(raw_single, repeat)
    t_ingest = best_of(ingest, repeat)
    t_copy = best_of(copy_hash_only, repeat)
    (work / "copy.tmp").unlink(missing_ok=True)
    t_plain = best_of(plain_copy, repeat)
    (work / "plain.tmp").unlink(missing_ok=True)
    gb = size / 1e9
    return [
        ("raw BLAKE3, all cores (update_mmap)", f"{gb / t_raw:.2f} GB/s  ({t_raw:.2f} s)"),
        ("raw BLAKE3, one core (8 MiB reads)", f"{gb / t_single:.2f} GB/s  ({t_single:.2f} s)"),
        ("store ingest (copy+hash one pass, fsync, link)", f"{gb / t_ingest:.2f} GB/s  ({t_ingest:.2f} s)"),
        ("  of which copy+hash (no fsync)", f"{gb / t_copy:.2f} GB/s  ({t_copy:.2f} s)"),
        ("plain durable copy, no hash (copy_file_range+fsync)", f"{gb / t_plain:.2f} GB/s  ({t_plain:.2f} s)"),
        ("ingest / plain durable copy", f"{t_plain / t_ingest:.2f}x   (the disk bound)"),
        ("ingest / raw all-cores", f"{t_raw / t_ingest:.2f}x   (goal >= 0.8x)"),
        ("ingest / raw one-core", f"{t_single / t_ingest:.2f}x"),
        ("copy+hash (no fsync) / raw one-core", f"{t_single / t_copy:.2f}x"),
    ]


def write_log(store: Store, events: int) -> None:
    """A genuine hash-chained log, written in one go (the benchmark is about reading it)."""
    prev, lines = GENESIS, []
    for seq in range(events):
        ev = ("step-started", "checkpoint-saved", "artifact-written", "step-committed", "ref-moved")[seq % 5]
        line = canonical_json(
            {
                "seq": seq,
                "ts": now_iso(),
                "event": ev,
                "pid": 1,
                "host": "bench",
                "step": "train",
                "attempt": 1 + seq // 5,
                "artifact": hash_bytes(str(seq).encode()),
                "prev": prev,
            }
        )
        lines.append(line)
        prev = hash_bytes(line)
    store.log_path.write_bytes(b"\n".join(lines) + b"\n")


def run_cli(args: list[str], repeat: int) -> float:
    env = {**os.environ, "COLUMNS": "120"}

    def once():
        subprocess.run(ACCRUE + args, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)

    once()
    return best_of(once, repeat)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size-mb", type=int, default=1024)
    parser.add_argument("--events", type=int, default=10_000)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--dir", type=Path, default=None, help="work dir (same disk as your stores)")
    args = parser.parse_args()
    console = Console()
    work = Path(tempfile.mkdtemp(prefix="accrue-bench-", dir=args.dir))
    try:
        rows = bench_ingest(work, args.size_mb * 1024 * 1024, args.repeat)
        shutil.rmtree(work / "store", ignore_errors=True)
        (work / "big.bin").unlink()
        store = Store.init(work / "logstore")[0]
        write_log(store, args.events)
        s = str(store.root)
        rows.append(
            (f"accrue log (last 20 of {args.events} events)", f"{run_cli(['log', '--store', s], args.repeat):.3f} s")
        )
        rows.append(
            (
                f"accrue log --all --json ({args.events} events)",
                f"{run_cli(['log', '--all', '--json', '--store', s], args.repeat):.3f} s",
            )
        )
        rows.append(
            (
                f"accrue verify (incl. {args.events}-line chain check)",
                f"{run_cli(['verify', '--store', s], args.repeat):.3f} s",
            )
        )
        helps = []
        for _ in range(max(5, args.repeat)):
            t = time.perf_counter()
            subprocess.run(ACCRUE + ["--help"], check=True, stdout=subprocess.DEVNULL)
            helps.append(time.perf_counter() - t)
        rows.append(
            (
                "accrue --help cold start (min / median)",
                f"{min(helps):.3f} s / {statistics.median(helps):.3f} s   (goal < 0.5 s)",
            )
        )
    finally:
        shutil.rmtree(work, ignore_errors=True)
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    table = Table(
        title=f"accrue store benchmark ({args.size_mb} MiB file, {os.cpu_count()} cores, load average {load})",
        title_justify="left",
    )
    table.add_column("measure")
    table.add_column("result")
    for name, value in rows:
        table.add_row(name, value)
    console.print(table)


if __name__ == "__main__":
    main()
