"""Shared by the remote tests: a moto S3 server the suite starts itself, remotes of both kinds,
and a small store with artifacts and a step record."""

from __future__ import annotations

import os
import sys
import uuid
from pathlib import Path

import pytest
from rich.console import Console

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_cli_store import accrue  # noqa: E402
from test_runner_support import count_invocation  # noqa: E402

from artifacts.store import Store  # noqa: E402

S3_ENV = {
    "AWS_ACCESS_KEY_ID": "testing",
    "AWS_SECRET_ACCESS_KEY": "testing",
    "AWS_REGION": "us-east-1",
    "ACCRUE_REMOTE_RETRIES": "1",
    "ACCRUE_REMOTE_CONNECT_TIMEOUT": "2",
}


@pytest.fixture(scope="session")
def moto_endpoint():
    from moto.server import ThreadedMotoServer

    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    host, port = server.get_host_and_port()
    yield f"http://{host}:{port}"
    server.stop()


@pytest.fixture
def s3_env(moto_endpoint, monkeypatch):
    for k, v in {**S3_ENV, "AWS_ENDPOINT_URL": moto_endpoint}.items():
        monkeypatch.setenv(k, v)
    monkeypatch.delenv("AWS_PROFILE", raising=False)
    return moto_endpoint


def s3_client(endpoint: str):
    import boto3

    return boto3.client(
        "s3",
        endpoint_url=endpoint,
        region_name="us-east-1",
        aws_access_key_id="testing",
        aws_secret_access_key="testing",
    )


@pytest.fixture(params=["dir", "s3"])
def remote_url(request, tmp_path):
    """A fresh remote of each kind: a directory, or a new bucket on the moto server."""
    if request.param == "dir":
        (tmp_path / "nas" / "accrue").mkdir(parents=True)  # the remote's directory, on the mounted disk
        return str(tmp_path / "nas" / "accrue")
    endpoint = request.getfixturevalue("s3_env")
    bucket = f"b-{uuid.uuid4().hex[:12]}"
    s3_client(endpoint).create_bucket(Bucket=bucket)
    return f"s3://{bucket}/team/store"


def remote_file_keys(url: str, under: str) -> dict[str, bytes]:
    """Every key under a part of the remote (e.g. objects/, refs/), with its bytes."""
    if url.startswith("s3://"):
        bucket, _, prefix = url[5:].partition("/")
        client = s3_client(os.environ["AWS_ENDPOINT_URL"])
        out = {}
        for page in client.get_paginator("list_objects_v2").paginate(Bucket=bucket, Prefix=f"{prefix}/{under}"):
            for item in page.get("Contents", []):
                out[item["Key"][len(prefix) + 1 :]] = client.get_object(Bucket=bucket, Key=item["Key"])["Body"].read()
        return out
    root = Path(url)
    base = root / under
    files = [base] if base.is_file() else [p for p in base.rglob("*") if p.is_file()] if base.is_dir() else []
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in files}


def overwrite_remote_key(url: str, key: str, data: bytes) -> None:
    if url.startswith("s3://"):
        bucket, _, prefix = url[5:].partition("/")
        s3_client(os.environ["AWS_ENDPOINT_URL"]).put_object(Bucket=bucket, Key=f"{prefix}/{key}", Body=data)
    else:
        path = Path(url) / key
        os.chmod(path, 0o644)
        path.write_bytes(data)


def delete_remote_key(url: str, key: str) -> None:
    if url.startswith("s3://"):
        bucket, _, prefix = url[5:].partition("/")
        s3_client(os.environ["AWS_ENDPOINT_URL"]).delete_object(Bucket=bucket, Key=f"{prefix}/{key}")
    else:
        (Path(url) / key).unlink()


def cli(store: Path, *args: str):
    """`accrue ARGS --store STORE` in a subprocess."""
    return accrue(*args, "--store", str(store))


def with_remote(store: Path, url: str, name: str = "origin") -> None:
    assert cli(store, "remote", "add", name, url).returncode == 0


def make_store(path: Path, files: int = 6, seed: int = 3) -> Store:
    """A store with a directory artifact (handoff), a file artifact (replay) and a committed step
    record whose input is the handoff, so lineage has something to walk."""
    from stages.runner import Runner
    from stages.runner_types import StagePlan

    assert accrue("init", "--store", str(path)).returncode == 0
    src = path.parent / f"src-{path.name}"
    (src / "policy").mkdir(parents=True)
    rng = __import__("random").Random(seed)
    for i in range(files):
        (src / "policy" / f"part{i}.bin").write_bytes(rng.randbytes(1000 + 37 * i))
    (src / "policy" / "seed.txt").write_text(str(seed))  # the test step reads it
    (src / "replay.bin").write_bytes(rng.randbytes(300_000))
    assert (
        accrue(
            "add", str(src / "policy"), "--kind", "handoff", "--ref", "team/handoff", "--store", str(path)
        ).returncode
        == 0
    )
    assert (
        accrue(
            "add", str(src / "replay.bin"), "--kind", "replay", "--ref", "team/replay", "--store", str(path)
        ).returncode
        == 0
    )
    store = Store.open(path)
    handoff = (store.refs_dir / "team" / "handoff").read_text().strip()
    Runner(store, console=Console(file=open(os.devnull, "w"))).run_plan(
        StagePlan("wf", 1, (count_invocation(3, seed=seed, inputs={"seed": handoff}),))
    )
    return store


def user_refs(store_path: Path) -> dict[str, str]:
    import json

    refs = json.loads(accrue("refs", "--json", "--store", str(store_path)).stdout)
    return {n: i for n, i in refs.items() if not n.startswith(("remotes/", "remote-logs/"))}


def snapshot(store_path: Path) -> dict[str, bytes]:
    """What a failed remote command must leave alone: objects, refs, config, log, records."""
    out = {}
    for part in ("objects", "refs", "records", "log", "config", "remotes"):
        base = store_path / part
        files = [base] if base.is_file() else sorted(p for p in base.rglob("*") if p.is_file()) if base.is_dir() else []
        for p in files:
            out[p.relative_to(store_path).as_posix()] = p.read_bytes()
    return out
