"""accrue push and pull against a plain boto3 script moving the same files with the same concurrency
(issue 51), through a local S3 server (moto, in its own process). A script, not a test:

  nice -n 10 .venv/bin/python benchmarks/bench_transfer.py [--small 2000] [--big 5] [--big-mb 50]
      [--jobs 16] [--rounds 3] [--json benchmarks/results/transfer.json]

The files: --small objects of 1-16 KiB (episodes, step records) and --big files of --big-mb MiB
(checkpoints, replay shards), as one directory artifact. Each round runs, interleaved (the order flips
every round, so a machine that gets busier or quieter favours neither side):

  boto3 upload   a ThreadPoolExecutor(--jobs) of client.upload_file, boto3's default TransferConfig
                 (what a user scripts without accrue: big files in 8 MiB parts on its own threads)
  accrue push    `accrue push` to a fresh prefix, run as the user runs it (a new process)
  boto3 download the same pool of client.download_file into a fresh directory
  accrue pull    `accrue pull` into a fresh store (every object hashed as it streams, and fsynced)

The figures are the medians over rounds; the ratio is boto3's time over accrue's (>= 0.8 is the goal).
Also timed: the same push and pull inside this process (no interpreter start-up), and a no-op push
(with how many objects it uploaded: none). The JSON records the command, the commit and the machine's
load, before and after (others may be working on it).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from bench_remote import ACCRUE, MIB, free_port, start_moto, timed  # noqa: E402


def make_source(directory: Path, small: int, big: int, big_mb: int) -> None:
    rng = __import__("random").Random(51)
    (directory / "episodes").mkdir(parents=True)
    for i in range(small):
        (directory / "episodes" / f"ep-{i:05d}.bin").write_bytes(rng.randbytes(rng.randint(1024, 16 * 1024)))
    block = os.urandom(big_mb * MIB)
    for i in range(big):
        (directory / f"shard-{i:02d}.bin").write_bytes(block[i * 4096 :] + block[: i * 4096])  # distinct


def accrue(*args: str, store: Path, env: dict) -> subprocess.CompletedProcess:
    proc = subprocess.run([*ACCRUE, *args, "--store", str(store)], capture_output=True, text=True, env=env)
    if proc.returncode != 0:
        raise SystemExit(f"accrue {' '.join(args)} failed: {proc.stderr.strip()}")
    return proc


def boto3_upload(client, bucket: str, prefix: str, files: list[Path], base: Path, jobs: int) -> None:
    with ThreadPoolExecutor(jobs) as pool:
        list(
            pool.map(lambda p: client.upload_file(str(p), bucket, f"{prefix}/{p.relative_to(base).as_posix()}"), files)
        )


def boto3_download(client, bucket: str, prefix: str, keys: list[str], dest: Path, jobs: int) -> None:
    def one(key: str) -> None:
        target = dest / key
        target.parent.mkdir(parents=True, exist_ok=True)
        client.download_file(bucket, f"{prefix}/{key}", str(target))

    with ThreadPoolExecutor(jobs) as pool:
        list(pool.map(one, keys))


def load() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


def commit() -> str:
    """HEAD, with "+changes" when the code measured (artifacts/, cli/) differs from it."""
    done = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    dirty = subprocess.run(
        ["git", "status", "--porcelain", "--", "artifacts", "cli"], cwd=ROOT, capture_output=True, text=True
    )
    return (done.stdout.strip() or "unknown") + ("+changes" if dirty.stdout.strip() else "")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--small", type=int, default=2000, help="small objects (1-16 KiB)")
    ap.add_argument("--big", type=int, default=5, help="big files")
    ap.add_argument("--big-mb", type=int, default=50, help="MiB per big file")
    ap.add_argument("--jobs", type=int, default=16, help="parallel transfers, both sides")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--dir", type=Path, default=None, help="work directory (default: a temp dir)")
    ap.add_argument("--json", type=Path, default=None, help="also write the figures here")
    ap.add_argument("--note", default="", help="recorded with the figures (e.g. how busy the machine was)")
    args = ap.parse_args()

    import boto3
    from rich.console import Console
    from rich.table import Table

    work = Path(tempfile.mkdtemp(prefix="bench-transfer-", dir=args.dir))
    port = free_port()
    endpoint = f"http://127.0.0.1:{port}"
    creds = {"AWS_ACCESS_KEY_ID": "bench", "AWS_SECRET_ACCESS_KEY": "bench", "AWS_REGION": "us-east-1"}
    env = {**os.environ, **creds, "AWS_ENDPOINT_URL": endpoint, "ACCRUE_REMOTE_JOBS": str(args.jobs)}
    env.pop("AWS_PROFILE", None)
    os.environ.update({**creds, "AWS_ENDPOINT_URL": endpoint, "ACCRUE_REMOTE_JOBS": str(args.jobs)})
    console = Console()
    figures: dict = {
        "command": "python benchmarks/bench_transfer.py " + shlex.join(sys.argv[1:]),
        "commit": commit(),
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "load_before": load(),
            "note": args.note,
        },
        "small": args.small,
        "big": args.big,
        "big_mb": args.big_mb,
        "jobs": args.jobs,
        "rounds": args.rounds,
    }
    server = start_moto(port)
    rounds: dict[str, list[float]] = {}

    def keep(name: str, seconds: float) -> None:
        rounds.setdefault(name, []).append(round(seconds, 3))

    try:
        s3 = boto3.client("s3", endpoint_url=endpoint, region_name="us-east-1")
        for bucket in ("plain", "accrue"):
            s3.create_bucket(Bucket=bucket)
        src = work / "src"
        console.print(f"making {args.small} small and {args.big} x {args.big_mb} MiB files in {work} …")
        make_source(src, args.small, args.big, args.big_mb)
        files = sorted(p for p in src.rglob("*") if p.is_file())
        keys = [p.relative_to(src).as_posix() for p in files]
        figures["bytes"] = sum(p.stat().st_size for p in files)
        store = work / "store"
        accrue("init", store=store, env=env)
        accrue("add", str(src), "--kind", "replay", "--ref", "bench/data", store=store, env=env)
        for p in files:  # the page cache warm for both sides alike
            p.read_bytes()

        for r in range(args.rounds):
            accrue("remote", "add", f"r{r}", f"s3://accrue/r{r}", store=store, env=env)
            clone = work / f"clone{r}"
            accrue("init", store=clone, env=env)
            accrue("remote", "add", "origin", f"s3://accrue/r{r}", store=clone, env=env)
            down = work / f"down{r}"
            steps = [
                ("boto3_upload_s", lambda r=r: boto3_upload(s3, "plain", f"r{r}", files, src, args.jobs)),
                ("push_s", lambda r=r: accrue("push", f"r{r}", store=store, env=env)),
            ]
            later = [
                (
                    "boto3_download_s",
                    lambda r=r, down=down: boto3_download(s3, "plain", f"r{r}", keys, down, args.jobs),
                ),
                ("pull_s", lambda clone=clone: accrue("pull", store=clone, env=env)),
            ]
            if r % 2:  # flip the order every other round
                steps.reverse()
                later.reverse()
            for name, fn in steps + later:
                keep(name, timed(fn))
            if r == 0:
                accrue("verify", "--full", store=clone, env=env)  # what arrived is the store's, byte for byte
            shutil.rmtree(down)
            shutil.rmtree(clone)

        # the same transfers inside this process (no interpreter start-up): what the transfer costs
        from artifacts.remotes.config import add_remote
        from artifacts.remotes.pull import pull
        from artifacts.remotes.push import push
        from artifacts.store import Store

        for r in range(args.rounds):
            here = Store.open(store)
            add_remote(here, f"api{r}", f"s3://accrue/api{r}")
            keep("push_in_process_s", timed(lambda r=r, here=here: push(here, f"api{r}")))
            clone = Store.init(work / f"api-clone{r}")[0]
            add_remote(clone, "origin", f"s3://accrue/api{r}")
            keep("pull_in_process_s", timed(lambda clone=clone: pull(clone, "origin")))
            shutil.rmtree(work / f"api-clone{r}")
        noop = [json.loads(accrue("push", "r0", "--json", store=store, env=env).stdout) for _ in range(2)]
        keep("noop_push_s", timed(lambda: accrue("push", "r0", store=store, env=env)))
        figures["noop_push_objects_sent"] = noop[-1]["objects_sent"]
    finally:
        server.kill()
        shutil.rmtree(work, ignore_errors=True)

    med = {name: statistics.median(times) for name, times in rounds.items()}
    figures["machine"]["load_after"] = load()
    figures["rounds_s"] = rounds
    figures["median_s"] = {k: round(v, 3) for k, v in med.items()}
    mib = figures["bytes"] / MIB
    figures["median_mib_s"] = {k: round(mib / v, 1) for k, v in med.items() if k != "noop_push_s"}
    figures["push_vs_boto3"] = round(med["boto3_upload_s"] / med["push_s"], 3)
    figures["pull_vs_boto3"] = round(med["boto3_download_s"] / med["pull_s"], 3)
    figures["push_in_process_vs_boto3"] = round(med["boto3_upload_s"] / med["push_in_process_s"], 3)
    figures["pull_in_process_vs_boto3"] = round(med["boto3_download_s"] / med["pull_in_process_s"], 3)

    table = Table(
        title=f"{args.small} small + {args.big} x {args.big_mb} MiB ({mib:.0f} MiB), local moto S3, "
        f"{args.jobs} parallel transfers, median of {args.rounds} interleaved rounds; load {figures['machine']}",
        title_justify="left",
    )
    for col in ("transfer", "accrue", "boto3", "boto3 / accrue", "goal"):
        table.add_column(col)

    def cell(key: str) -> str:
        return f"{med[key]:.2f} s ({mib / med[key]:.0f} MiB/s)"

    table.add_row(
        "push / upload", cell("push_s"), cell("boto3_upload_s"), f"{figures['push_vs_boto3']:.2f}x", ">= 0.8x"
    )
    table.add_row("  in-process", cell("push_in_process_s"), "", f"{figures['push_in_process_vs_boto3']:.2f}x", "")
    table.add_row(
        "pull / download", cell("pull_s"), cell("boto3_download_s"), f"{figures['pull_vs_boto3']:.2f}x", ">= 0.8x"
    )
    table.add_row("  in-process", cell("pull_in_process_s"), "", f"{figures['pull_in_process_vs_boto3']:.2f}x", "")
    table.add_row(
        "no-op push", f"{med['noop_push_s']:.2f} s, {figures['noop_push_objects_sent']} objects sent", "", "", "0 sent"
    )
    console.print(table)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(figures, indent=2, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
