"""Ray workers get the remote's settings and the credentials the bench's process was given (issue 51):
the endpoint and region as resolved on the head, the keys (from the environment or a profile) in the
cell job's environment only — never in its repr, a log or a store's config."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_bench_ray import write_spec  # noqa: E402

from artifacts.remotes.config import add_remote, set_setting  # noqa: E402
from artifacts.store import Store  # noqa: E402
from stages.bench.execute import make_job  # noqa: E402
from stages.bench.node_store import open_node_store, remote_target, worker_credentials  # noqa: E402
from stages.bench.spec import load_spec  # noqa: E402

SECRET = "wJalrXUtnFEMI-not-a-real-secret"


@pytest.fixture
def aws_env(monkeypatch, tmp_path):
    for key in ("AWS_PROFILE", "AWS_ENDPOINT_URL_S3", "AWS_ENDPOINT", "AWS_DEFAULT_REGION", "AWS_SESSION_TOKEN"):
        monkeypatch.delenv(key, raising=False)
    monkeypatch.setenv("AWS_CONFIG_FILE", str(tmp_path / "no-config"))
    monkeypatch.setenv("AWS_SHARED_CREDENTIALS_FILE", str(tmp_path / "no-credentials"))
    return monkeypatch


def test_a_worker_gets_the_heads_endpoint_region_and_keys_in_its_environment_only(tmp_path, aws_env):
    aws_env.setenv("AWS_ENDPOINT_URL", "http://minio.lab:9000")
    aws_env.setenv("AWS_REGION", "eu-central-1")
    aws_env.setenv("AWS_ACCESS_KEY_ID", "AKIDLAB")
    aws_env.setenv("AWS_SECRET_ACCESS_KEY", SECRET)
    store = Store.init(tmp_path / "head")[0]
    add_remote(store, "team", "s3://lab/bench")
    target, keys = remote_target(store, "team"), worker_credentials(store, "team")
    assert target == {
        "name": "team",
        "url": "s3://lab/bench",
        "settings": {"endpoint": "http://minio.lab:9000", "region": "eu-central-1"},
    }
    assert keys == {"AWS_ACCESS_KEY_ID": "AKIDLAB", "AWS_SECRET_ACCESS_KEY": SECRET}
    spec = load_spec(write_spec(tmp_path, "shared", [0]))
    job = make_job(spec, store, spec.cells[0], tmp_path / "logs", target, None, keys)
    assert job.env["AWS_SECRET_ACCESS_KEY"] == SECRET and job.remote == target
    assert SECRET not in repr(job) and "AKIDLAB" not in repr(job)
    # the node store keeps the settings as its remote's, never the keys
    node = open_node_store(str(tmp_path / "node"), target)
    config = (node.root / "config").read_text()
    assert "http://minio.lab:9000" in config and "eu-central-1" in config
    assert SECRET not in config and "AKIDLAB" not in config


def test_a_profiles_credentials_are_resolved_on_the_head_and_the_profile_left_out(tmp_path, aws_env):
    (tmp_path / "credentials").write_text(
        f"[lab]\naws_access_key_id = AKIDPROFILE\naws_secret_access_key = {SECRET}\naws_session_token = tok\n"
    )
    aws_env.setenv("AWS_SHARED_CREDENTIALS_FILE", str(tmp_path / "credentials"))
    aws_env.setenv("AWS_ACCESS_KEY_ID", "AKIDENV")  # the remote's own profile wins over the environment's keys
    aws_env.setenv("AWS_SECRET_ACCESS_KEY", "env-secret")
    store = Store.init(tmp_path / "head")[0]
    add_remote(store, "team", "s3://lab/bench")
    set_setting(store, "team", "profile", "lab")
    set_setting(store, "team", "endpoint", "http://ceph.lab:7480")
    assert worker_credentials(store, "team") == {
        "AWS_ACCESS_KEY_ID": "AKIDPROFILE",
        "AWS_SECRET_ACCESS_KEY": SECRET,
        "AWS_SESSION_TOKEN": "tok",
    }
    assert remote_target(store, "team")["settings"] == {"endpoint": "http://ceph.lab:7480"}  # a worker may lack it
    set_setting(store, "team", "profile", "missing")
    assert worker_credentials(store, "team") == {}  # the worker's own credentials apply
    assert remote_target(store, "team")["settings"]["profile"] == "missing"


def test_a_directory_remote_passes_no_credentials(tmp_path, aws_env):
    aws_env.setenv("AWS_ACCESS_KEY_ID", "AKIDLAB")
    aws_env.setenv("AWS_SECRET_ACCESS_KEY", SECRET)
    store = Store.init(tmp_path / "head")[0]
    add_remote(store, "nas", str(tmp_path / "nas"))
    assert worker_credentials(store, "nas") == {}
    assert remote_target(store, "nas")["settings"] == {}
