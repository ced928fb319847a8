"""`accrue bench --remote NAME` on nodes that share only an S3 remote (issue 22): two Ray nodes on this
machine (two raylets, each with its own worker processes and its own store directory), a local S3
server (moto) as the only thing they share with each other and with the bench's store. The first
cell runs on node A and pushes its results; the second, on node B, finds A's step records through the
remote (cache hits) and fetches the data its steps read from it; the bench's store pulls both cells
back, so `bench status` and `bench report` read it, and no step ever ran in it."""

from __future__ import annotations

import io
import sys
import uuid
from pathlib import Path

import pytest
from rich.console import Console

sys.path.insert(0, str(Path(__file__).resolve().parent))
from remote_support import S3_ENV, moto_endpoint, s3_client  # noqa: E402,F401
from test_bench_ray import step_records, write_spec  # noqa: E402

from artifacts.records import list_attempts
from artifacts.refs import list_refs, read_ref
from artifacts.remotes.config import add_remote, set_setting
from artifacts.store import Store
from stages.bench.execute import run_bench
from stages.bench.report import build_report
from stages.bench.spec import load_spec
from stages.bench.state import cell_states, counts, is_done


@pytest.fixture
def two_nodes(moto_endpoint, monkeypatch):
    """A Ray cluster of two nodes on this machine, one CPU each, told apart by a custom resource;
    the S3 credentials are in the environment the raylets (and so their workers) start with."""
    ray = pytest.importorskip("ray")
    from ray.cluster_utils import Cluster

    for k, v in S3_ENV.items():
        monkeypatch.setenv(k, v)
    monkeypatch.delenv("AWS_ENDPOINT_URL", raising=False)  # the remote's own endpoint setting reaches it
    monkeypatch.setenv("RAY_USAGE_STATS_ENABLED", "0")
    cluster = Cluster(
        initialize_head=True,
        head_node_args={"num_cpus": 1, "resources": {"node_a": 1}, "include_dashboard": False},
    )
    cluster.add_node(num_cpus=1, resources={"node_b": 1})
    ray.init(address=cluster.address, log_to_driver=False)
    try:
        yield cluster
    finally:
        ray.shutdown()
        cluster.shutdown()


def ran_here(store: Store) -> list[dict]:
    """Attempts of steps run in this store (not step records entered by a pull)."""
    return [a for a in list_attempts(store) if not a.get("imported_from")]


def _spec(tmp_path: Path):
    path = write_spec(tmp_path, "shared", [0])
    data = __import__("yaml").safe_load(path.read_text())
    data["methods"] = {  # each method's cells on one node
        "accrue": {"resources": {"num_cpus": 1, "custom": {"node_a": 1}}},
        "sequential": {"resources": {"num_cpus": 1, "custom": {"node_b": 1}}},
    }
    data["remote"] = "team"
    path.write_text(__import__("yaml").safe_dump(data))
    return load_spec(path)


@pytest.mark.slow  # two raylets and two tiny cells, one after the other: ~35 s on the shared 2-core machine
def test_cells_on_two_nodes_share_only_the_s3_remote(two_nodes, moto_endpoint, tmp_path):
    bucket = f"b-{uuid.uuid4().hex[:12]}"
    s3_client(moto_endpoint).create_bucket(Bucket=bucket)
    store = Store.init(tmp_path / "head")[0]
    add_remote(store, "team", f"s3://{bucket}/bench")
    set_setting(store, "team", "endpoint", moto_endpoint)
    spec = _spec(tmp_path)
    first, second = spec.cell("accrue", "A", 0), spec.cell("sequential", "A", 0)
    nodes = tmp_path / "nodes" / "{node}"
    quiet = Console(file=io.StringIO())

    [a] = run_bench(spec, store, cells=[first], console=quiet, logs_dir=tmp_path / "logs", node_store=str(nodes))
    [b] = run_bench(spec, store, cells=[second], console=quiet, logs_dir=tmp_path / "logs", node_store=str(nodes))
    assert (a.state, b.state) == ("done", "done"), (a.error, b.error)
    assert a.steps_cached == 0 and b.steps_cached > 0  # B's cache hits are A's step records, via the remote

    node_stores = sorted(p.parent for p in (tmp_path / "nodes").glob("*/config"))
    assert len(node_stores) == 2  # one store per node, neither of them the bench's
    ran_in = {n: {a_["workflow"] for a_ in ran_here(Store.open(n))} for n in node_stores}
    assert sorted(map(sorted, ran_in.values())) == [[first.name], [second.name]]
    node_b = next(Store.open(n) for n, wfs in ran_in.items() if wfs == {second.name})
    assert (node_b.root / "remotes" / "team" / "promised").is_file()  # data left on the remote until read
    reused = [
        read_ref(node_b, ref)
        for ref in list_refs(node_b, f"workflow/{second.name}/")
        if read_ref(node_b, ref) in set(list_refs(node_b, f"workflow/{first.name}/").values())
    ]
    assert reused  # the same step records under both cells' refs
    promised = set((node_b.root / "remotes" / "team" / "promised").read_text().split())
    fetched = [oid for oid in promised if node_b.has_object(oid)]
    assert fetched  # data of A's that a step of B read: fetched from the remote when read

    # the bench's store: both cells pulled back, status and report from it, no step run in it
    assert ran_here(store) == [] and len(list_attempts(store)) > 0  # the pulled step records only
    assert all(is_done(store, c) for c in (first, second))
    assert counts(cell_states(store, spec)) == {"done": 2, "running": 0, "failed": 0, "partial": 0, "pending": 0}
    runs = {m["method"]: m["runs"] for m in build_report(store, spec)["aggregate"]["methods"]}
    assert runs == {"accrue": 1, "sequential": 1}
    assert step_records(store, first) == step_records(node_b, first)  # the very records A committed
    again = run_bench(spec, store, console=quiet, logs_dir=tmp_path / "logs", node_store=str(nodes))
    assert [r.state for r in again] == ["skipped", "skipped"]


def test_an_unknown_remote_is_one_line_before_anything_starts(tmp_path):
    from test_cli_store import accrue, one_line_error

    store = tmp_path / "store"
    assert accrue("init", "--store", str(store)).returncode == 0
    spec = write_spec(tmp_path, "shared", [0])
    line = one_line_error(accrue("bench", "run", str(spec), "--remote", "team", "--store", str(store)))
    assert "no remote named 'team'" in line
    assert not (store / "refs" / "bench").exists()


def test_a_node_that_cannot_write_the_bench_logs_directory_keeps_the_log_in_its_temp_dir(tmp_path, monkeypatch):
    import tempfile

    from stages.bench.cell import CellJob, run_cell

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))  # the node's temporary directory
    monkeypatch.chdir(tmp_path)  # run_cell changes directory to job.cwd; monkeypatch restores it
    blocked = tmp_path / "not-a-dir"
    blocked.write_text("a file where the bench's logs directory would be")
    job = CellJob(store=str(tmp_path / "none"), workflow={}, source="t", log=str(blocked / "c.log"), cwd=str(tmp_path))
    out = run_cell(job)
    assert not out["ok"]  # an empty workflow: the cell fails, and says why in its log
    assert "Traceback" in (tmp_path / "tmp" / "accrue-bench-logs" / "c.log").read_text()


def test_a_store_that_ran_a_bench_verifies_pushes_and_pulls(tmp_path):
    """A cell's outcome (ref bench/<spec>/<cell>) names a JSON record that is no artifact manifest:
    verify, push and pull take it as a leaf instead of refusing the whole store."""
    from test_cli_store import accrue

    from stages.bench.state import outcome_ref, record_outcome

    a, b = tmp_path / "a", tmp_path / "b"
    store = Store.init(a)[0]
    spec = load_spec(write_spec(tmp_path, "shared", [0]))
    record_outcome(store, spec, spec.cells[0], "failed", tries=1, seconds=0.5, error="x")
    assert accrue("verify", "--store", str(a)).returncode == 0
    assert accrue("remote", "add", "nas", str(tmp_path / "nas"), "--create", "--store", str(a)).returncode == 0
    assert accrue("push", "--store", str(a)).returncode == 0
    assert accrue("clone", str(tmp_path / "nas"), str(b)).returncode == 0
    assert read_ref(Store.open(b), outcome_ref(spec, spec.cells[0])) == read_ref(
        store, outcome_ref(spec, spec.cells[0])
    )
    assert accrue("verify", "--remote", "nas", "--store", str(a)).returncode == 0
