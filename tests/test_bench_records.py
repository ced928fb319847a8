"""Cell records (stages/bench/records.py) carry a bench's finished cells past the loss of their store: a
report from an empty store plus the records equals the store's own, a record that disagrees with the
store is listed with both values, a bad record is one line and exit 2, and a record of another spec is
left out and named. The store is test_bench_report's (stand-in steps, no RL)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from test_bench_report import VALUES, bench  # noqa: F401 - tests/ is on sys.path; `bench` is a fixture

from artifacts.store import Store
from stages.bench.records import cpu_description, load_records, write_records
from stages.bench.report import build_report, markdown, report_and_records, write_report
from stages.bench.spec import load_spec
from stages.errors import StageError

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))
import bench_records_from_report  # noqa: E402
import bench_tables  # noqa: E402

PREDICTIONS = [{"prediction": "forgets less", "metric": "NBT", "reference_is": "lower", "than": ["sequential"]}]
COMPARED = ("aggregate", "differences", "predictions", "claims", "stage_curves", "cells_done", "runs_with_report_set")


@pytest.fixture
def recorded_bench(bench, tmp_path):  # noqa: F811 - the fixture imported above
    """The known bench with a declared prediction, its records written from the store into tmp/records."""
    spec, store, path = bench
    data = yaml.safe_load(path.read_text())
    path.write_text(yaml.safe_dump({**data, "predictions": PREDICTIONS}))
    spec = load_spec(path)
    records = tmp_path / "records"
    _, fresh = report_and_records(store, spec, load_records(records, spec))
    assert len(write_records(records, fresh)) == 7  # every done cell; the failed one has nothing to record
    return spec, store, path, records


def empty_store(tmp_path) -> Store:
    return Store.init(tmp_path / "empty-store")[0]


def edit_record(path: Path, change) -> None:
    record = json.loads(path.read_text())
    change(record)
    path.write_text(json.dumps(record))


def one_record(records: Path, spec, method="accrue", ordering="S1", seed=0) -> Path:
    return records / f"{spec.cell(method, ordering, seed).name}.json"


def test_an_empty_store_plus_records_reproduces_the_store_report(recorded_bench, tmp_path):
    spec, store, _, records = recorded_bench
    from_store = build_report(store, spec)
    from_records = build_report(empty_store(tmp_path), spec, load_records(records, spec))
    for key in COMPARED:
        assert from_records[key] == from_store[key], key
    assert from_records["predictions"][0]["verdict"] == from_store["predictions"][0]["verdict"]
    states = {c["cell"]: c["state"] for c in from_records["cells"]}
    assert sorted(states.values()) == ["pending"] + ["recorded"] * 7
    assert from_records["records"]["cells_from_records"] == 7 and from_records["records"]["runs_with_stage_curves"] == 7
    [origin] = from_records["records"]["from"]
    assert origin["cells"] == 7 and origin["provenance"].startswith(f"store {store.root} on ")
    text = markdown(from_records)
    assert "7 of the 7 done cells come from records" in text and "| accrue | 3 of 4 |" in text
    # each record names the store artifacts its curves came from, and its file is deterministic JSON
    path = one_record(records, spec)
    record = json.loads(path.read_text())
    assert [a["stage"] for a in record["provenance"]["artifacts"]] == [1, 2]
    assert all(len(a["train_record"]) == len(a["curve_artifact"]) == 64 for a in record["provenance"]["artifacts"])
    assert path.read_text() == json.dumps(record, sort_keys=True, indent=2) + "\n"


def test_refreshing_leaves_unchanged_records_alone(recorded_bench):
    spec, store, _, records = recorded_bench
    before = {p.name: p.read_text() for p in records.iterdir()}
    _, fresh = report_and_records(store, spec, load_records(records, spec))
    assert write_records(records, fresh) == []  # same measurement: time and commit stay as first written
    assert {p.name: p.read_text() for p in records.iterdir()} == before


def test_the_store_wins_and_a_differing_record_is_listed_with_both_values(recorded_bench):
    spec, store, _, records = recorded_bench
    path = one_record(records, spec)
    stored = json.loads(path.read_text())["run_record"]["metrics"]["FWT"]
    edit_record(path, lambda r: r["run_record"]["metrics"].update(FWT=0.123))
    report = build_report(store, spec, load_records(records, spec))
    assert report["aggregate"] == build_report(store, spec)["aggregate"]  # the store's values are used
    rec = report["records"]
    assert rec["cells_from_records"] == 0 and rec["checked_against_store"] == 7
    [d] = rec["differ"]
    assert d["cell"] == path.stem and d["differ"] == {"FWT": {"store": stored, "record": 0.123}}
    text = markdown(report)
    assert "metrics equal in 6, differ in 1" in text and f"- differs: {path.stem}" in text and "record 0.123" in text


def test_a_record_of_another_spec_is_ignored_and_listed(recorded_bench, tmp_path):
    spec, _, _, records = recorded_bench
    other = records / "other.accrue.S1.s0.0123abcd.json"
    other.write_text(one_record(records, spec).read_text())
    edit_record(other, lambda r: r.update(spec="other", cell="other.accrue.S1.s0.0123abcd"))
    recorded = load_records(records, spec)
    assert len(recorded.by_cell) == 7
    assert recorded.ignored == [{"file": str(other), "spec": "other", "cell": "other.accrue.S1.s0.0123abcd"}]
    report = build_report(empty_store(tmp_path), spec, recorded)
    assert report["cells_done"] == 7 and f"- ignored: {other}" in markdown(report)


def test_records_without_curves_count_in_the_tables_not_in_the_stage_curves(recorded_bench, tmp_path):
    spec, store, _, records = recorded_bench
    edit_record(one_record(records, spec, "accrue", "S2", 0), lambda r: r.update(stage_curves=None))
    report = build_report(empty_store(tmp_path), spec, load_records(records, spec))
    assert report["aggregate"] == build_report(store, spec)["aggregate"]
    assert [s["runs"] for s in report["stage_curves"]["accrue"]] == [2, 2]  # 3 accrue runs, one without curves
    assert report["records"]["runs_without_stage_curves"] == 1
    assert "Stage curves are means over the 6 runs that kept them (1 recorded cells hold metrics only)" in markdown(
        report
    )


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda r: r["run_record"].update(seed=5), "seed 5, but the spec's cell"),
        (lambda r: r["run_record"]["metrics"].update(FWT="high"), "run_record.metrics.FWT must be a number"),
        (lambda r: r.update(success_threshold=0.9), "measured with success threshold 0.9"),
        (lambda r: r["stage_curves"][0].update(current=[0.5]), "stage_curves[1] needs grid, current"),
        (lambda r: r.pop("type"), "not a bench cell record"),
    ],
)
def test_a_record_that_disagrees_with_its_cell_names_the_file(recorded_bench, change, message):
    spec, _, _, records = recorded_bench
    path = one_record(records, spec)
    edit_record(path, change)
    with pytest.raises(StageError, match="^" + str(path).replace(".", r"\.") + ": ") as err:
        load_records(records, spec)
    assert message in str(err.value)


def bench_cli(path: Path, store: Store, *args) -> subprocess.CompletedProcess:
    env = {**os.environ, "ACCRUE_STORE": str(store.root)}
    cmd = [sys.executable, "-m", "cli.main", "bench", "report", str(path), *args]
    return subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env=env)


def test_cli_malformed_record_is_one_line_and_exit_2(recorded_bench, tmp_path):
    spec, store, path, records = recorded_bench
    bad = one_record(records, spec)
    bad.write_text("{not json")
    res = bench_cli(path, store, "--records", str(records), "--out", str(tmp_path / "out"))
    assert res.returncode == 2 and res.stderr.startswith(f"error: {bad}: not valid JSON")
    assert res.stderr.count("\n") == 1 and "Traceback" not in res.stderr
    assert not (tmp_path / "out").exists()  # nothing written before the records are checked
    inside = bench_cli(path, store, "--records", str(store.root / "cells"), "--out", str(tmp_path / "out"))
    assert inside.returncode == 2 and "inside the store" in inside.stderr and inside.stderr.count("\n") == 1
    assert not (store.root / "cells").exists()


def test_cli_with_and_without_records(recorded_bench, tmp_path):
    spec, store, path, records = recorded_bench
    plain = bench_cli(path, store, "--out", str(tmp_path / "plain"))
    assert plain.returncode == 0, plain.stderr
    report = json.loads((tmp_path / "plain" / "report.json").read_text())
    assert "records" not in report and all("record" not in c for c in report["cells"])
    assert {k: report[k] for k in COMPARED} == {k: build_report(store, spec)[k] for k in COMPARED}
    assert "records:" not in plain.stdout
    # a fresh store elsewhere: the CLI folds the records in, and records nothing new (it has no done cell)
    fresh = empty_store(tmp_path)
    res = bench_cli(path, fresh, "--records", str(records), "--out", str(tmp_path / "moved"))
    assert res.returncode == 0, res.stderr
    moved = json.loads((tmp_path / "moved" / "report.json").read_text())
    assert moved["aggregate"] == report["aggregate"] and moved["differences"] == report["differences"]
    assert f"--records {records}" in res.stdout and "records: 0 written or refreshed" in res.stdout
    cells = {r["cell"]: r["state"] for r in moved["cells"]}
    assert list(cells.values()).count("recorded") == 7


def test_bench_tables_reads_records_root(recorded_bench, tmp_path, capsys):
    spec, _, path, records = recorded_bench
    root = tmp_path / "results"
    (root / spec.name).mkdir(parents=True)
    records.rename(root / spec.name / "cells")
    assert bench_tables.main([str(path), "--store", str(empty_store(tmp_path).root), "--records-root", str(root)]) == 0
    text = capsys.readouterr().out
    assert "| accrue | 3 of 4 |" in text and "| sequential | 4 |" in text and "7 of the 7 done cells" in text


def test_records_from_a_committed_report_reproduce_its_tables(recorded_bench, tmp_path, capsys):
    spec, store, _, _ = recorded_bench
    committed = build_report(store, spec)
    write_report(committed, tmp_path / "committed")
    out = tmp_path / "from-report"
    assert bench_records_from_report.main([str(tmp_path / "committed" / "report.json"), "--out", str(out)]) == 0
    assert "7 records written" in capsys.readouterr().out
    record = json.loads(next(out.iterdir()).read_text())
    assert record["stage_curves"] is None and record["provenance"]["source"] == "report"
    assert record["provenance"]["note"] == "store not available"
    report = build_report(empty_store(tmp_path), spec, load_records(out, spec))
    for key in ("aggregate", "differences", "predictions", "claims"):
        assert report[key] == committed[key], key
    assert report["stage_curves"] == {} and report["records"]["runs_without_stage_curves"] == 7
    assert sum(v is not None for v in VALUES.values()) == report["cells_done"]


def test_records_from_a_file_that_is_not_a_report_is_one_line(tmp_path, capsys):
    bad = tmp_path / "report.json"
    bad.write_text(json.dumps({"spec": "x"}))
    assert bench_records_from_report.main([str(bad), "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err.startswith(f"error: {bad}: not a bench report.json")


def test_a_store_record_names_the_cpu_it_was_measured_on(recorded_bench, tmp_path):
    """The same cell differs between CPUs (docs/benchmark/index.md: cell records), so a store record must say which CPU."""
    spec, _, _, records = recorded_bench
    provenance = json.loads(one_record(records, spec).read_text())["provenance"]
    assert provenance["cpu"] == cpu_description()
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text(
        "processor\t: 0\nmodel name\t: Example CPU 9000\ncpu family\t: 26\nmodel\t\t: 2\n"
        "processor\t: 1\nmodel name\t: Example CPU 9000\ncpu family\t: 26\nmodel\t\t: 2\n"
    )
    described = cpu_description(cpuinfo)
    assert described.startswith("Example CPU 9000 (") and "family 26 model 2" in described
    assert f"{os.cpu_count()} cores" in described
    assert "family" not in cpu_description(tmp_path / "no-such-file")  # no /proc: platform's words only


def test_bench_tables_refuses_records_inside_the_store_like_the_cli(recorded_bench, capsys):
    spec, store, path, _ = recorded_bench
    assert bench_tables.main([str(path), "--store", str(store.root), "--records-root", str(store.root)]) == 2
    err = capsys.readouterr().err
    assert "inside the store" in err and err.count("\n") == 1
    assert not (store.root / spec.name).exists()
