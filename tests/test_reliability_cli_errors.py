"""Issue 13, clean errors everywhere: every bad input or hostile machine state the issue lists gives
one `error:` line naming the path or field and exit 2 (1 when verify or lineage found problems),
never a traceback — one case per class of error."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from reliability_support import remount, small_fs  # noqa: E402
from test_cli_store import accrue, one_line_error  # noqa: E402

from artifacts.ingest import add_path  # noqa: E402
from artifacts.store import Store  # noqa: E402

WORKFLOW = {
    "name": "wf",
    "tasks": ["nist/rect_peg"],
    "method": "accrue",
    "budgets": {"env_steps": 100, "eval_every": 50},
}


@pytest.fixture
def store(tmp_path: Path) -> Path:
    path = tmp_path / "store"
    assert accrue("init", "--store", str(path)).returncode == 0
    return path


def workflow(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "wf.yaml"
    path.write_text(text)
    return path


def short(line: str) -> str:
    assert len(line) < 600, f"{len(line)} characters: {line[:300]}…"
    return line


# ----------------------------------------------------------------------------- store commands
def test_log_with_a_huge_count_shows_everything(store):
    out = accrue("log", "-n", "1" + "0" * 30, "--store", str(store))
    assert out.returncode == 0


def test_non_utf8_file_names_are_refused_by_name(store, tmp_path):
    ds = tmp_path / "ds"
    ds.mkdir()
    (Path(os.fsdecode(bytes(ds) + b"/caf\xe9.bin"))).write_bytes(b"x")
    line = one_line_error(accrue("add", str(ds), "--kind", "demos", "--store", str(store)))
    assert "caf\\udce9.bin: file name is not valid UTF-8" in line
    odd = Path(os.fsdecode(bytes(tmp_path) + b"/\xff-file"))
    odd.write_bytes(b"y")
    assert "not valid UTF-8" in one_line_error(accrue("add", str(odd), "--kind", "demos", "--store", str(store)))


def test_a_path_too_long_is_one_short_line(store, tmp_path):
    line = short(one_line_error(accrue("add", str(tmp_path / ("x" * 5000)), "--kind", "demos", "--store", str(store))))
    assert "File name too long" in line


@pytest.mark.parametrize(
    "where, pattern",
    [
        (lambda tmp: Path("/proc/accrue-store"), r"cannot create a store at /proc/accrue-store"),
        (
            lambda tmp: (tmp / "file").write_text("x") and tmp / "file" / "store",
            r"cannot create a store at .*Not a directory",
        ),
    ],
)
def test_init_where_no_store_can_be(tmp_path, where, pattern):
    import re

    line = one_line_error(accrue("init", "--store", str(where(tmp_path))))
    assert re.search(pattern, line), line


def test_read_only_filesystem_init_add_gc_and_verify(tmp_path):
    with small_fs(tmp_path / "ro") as fs:
        st = Store.init(fs / "store")[0]
        src = tmp_path / "data.bin"
        src.write_bytes(os.urandom(3000))
        aid, _ = add_path(st, src, "demos", ref="d")
        content = Store.open(st.root).read_json(aid)["content"]
        obj = st.object_path(content)
        os.chmod(obj, 0o644)
        obj.write_bytes(b"Y" * 3000)  # corrupt, same size
        st.close()
        remount(fs, read_only=True)
        try:
            assert "Read-only file system" in one_line_error(accrue("init", "--store", str(fs / "other")))
            line = one_line_error(accrue("add", str(src), "--kind", "base-policy", "--store", str(st.root)))
            assert "Read-only file system" in line
            assert "cannot be written: gc can only report" in one_line_error(
                accrue("gc", "--yes", "--grace", "0", "--store", str(st.root))
            )
            assert accrue("gc", "--grace", "0", "--store", str(st.root)).returncode == 0  # a dry run reports
            full = accrue("verify", "--full", "--json", "--store", str(st.root))
            report = json.loads(full.stdout)
            assert full.returncode == 1 and report["quarantined"] == []
            assert any(f"object {content[:12]} is corrupt" in p for p in report["problems"])
            assert any("cannot be written" in n for n in report["notes"])
            assert obj.exists()
        finally:
            remount(fs, read_only=False)


def test_store_config_that_is_json_but_not_an_object(store):
    (store / "config").write_text("[1, 2]")
    assert "not a store config" in one_line_error(accrue("refs", "--store", str(store)))


def test_binary_and_foreign_refs(store, tmp_path):
    src = tmp_path / "a.bin"
    src.write_bytes(b"a" * 100)
    assert accrue("add", str(src), "--kind", "demos", "--ref", "good", "--store", str(store)).returncode == 0
    (store / "refs" / "binary").write_bytes(os.urandom(200))
    line = short(one_line_error(accrue("show", "binary", "--store", str(store))))
    assert "ref binary is damaged" in line
    listed = accrue("refs", "--json", "--store", str(store))
    assert listed.returncode == 0 and "good" in json.loads(listed.stdout)
    assert "warning: ref binary is damaged" in listed.stderr
    assert accrue("verify", "--store", str(store)).returncode == 1
    assert accrue("lineage", "good", "--store", str(store)).returncode == 0


def test_outputs_inside_the_store_are_refused(store):
    line = one_line_error(accrue("sim", "demos", "nist/rect_peg", "-n", "1", "-o", str(store / "refs" / "x")))
    assert "is inside the accrue store" in line and not (store / "refs" / "x").exists()


def test_lineage_of_a_corrupt_or_missing_target_fails(store, tmp_path):
    src = tmp_path / "a.bin"
    src.write_bytes(b"a" * 100)
    aid = accrue("add", str(src), "--kind", "demos", "--store", str(store)).stdout.strip()
    st = Store.open(store)
    manifest = st.object_path(aid)
    os.chmod(manifest, 0o644)
    manifest.write_bytes(b"{}" + manifest.read_bytes()[2:])
    assert "is corrupt" in one_line_error(accrue("lineage", aid, "--store", str(store)))
    manifest.unlink()
    assert "missing" in one_line_error(accrue("lineage", aid, "--store", str(store)))
    # an input that cannot be read: the tree is shown, and the exit code says it is incomplete
    parent = st.put_json(
        {
            "type": "artifact",
            "kind": "eval",
            "layout": "file",
            "content": "cd" * 32,
            "size": 1,
            "inputs": {"demos": aid},
            "producer": {"step": "x"},
        }
    )
    out = accrue("lineage", parent, "--store", str(store))
    assert out.returncode == 1 and "lineage incomplete: 1 input" in out.stderr


# ----------------------------------------------------------------------------- other commands
def test_metrics_on_deeply_nested_json(tmp_path):
    path = tmp_path / "m.json"
    path.write_text("[" * 200_000 + "]" * 200_000)
    assert "nested too deeply" in one_line_error(accrue("metrics", str(path)))


def test_sim_negative_seed_and_watch_into_a_directory(tmp_path):
    assert "--seed" in one_line_error(
        accrue("sim", "demos", "nist/rect_peg", "-n", "1", "-o", str(tmp_path / "d"), "--seed", "-1")
    )
    assert "is a directory" in one_line_error(accrue("sim", "watch", "nist/rect_peg", "-o", str(tmp_path)))


@pytest.mark.parametrize(
    "extra, pattern",
    [
        ("learner: {beta: .inf}", r"learner\.beta: must be a finite number \(got inf\)"),
        ("learner: {lam: .nan}", r"learner\.lam: must be a finite number"),
        ("learner: {actor_lr: -.inf}", r"learner\.actor_lr: must be a finite number"),
        ("base_policy: {lr: .inf}", r"base_policy\.lr: input should be a finite number"),
        ("seed: true", r"seed: must be a number, not true"),
        ("horizon: false", r"horizon: must be a number, not false"),
        ("method: accrue", r"duplicate key 'method'"),
    ],
)
def test_workflow_values_that_used_to_pass(store, tmp_path, extra, pattern):
    import re

    text = (
        "name: wf\ntasks: [nist/rect_peg]\nmethod: accrue\nbudgets: {env_steps: 100, eval_every: 50}\n" + extra + "\n"
    )
    line = one_line_error(accrue("stage", "status", str(workflow(tmp_path, text)), "--store", str(store)))
    assert re.search(pattern, line), line


def test_env_steps_true_is_not_one(store, tmp_path):
    text = "name: wf\ntasks: [nist/rect_peg]\nmethod: accrue\nbudgets: {env_steps: true, eval_every: 1}\n"
    line = one_line_error(accrue("stage", "status", str(workflow(tmp_path, text)), "--store", str(store)))
    assert "budgets.env_steps: must be a number, not true" in line


def test_a_yaml_alias_bomb_gives_a_short_message(store, tmp_path):
    levels = ["a: &a [x, x, x, x, x, x, x, x, x]"]
    for prev, name in zip("abcdefgh", "bcdefghi"):
        levels.append(f"{name}: &{name} [" + ", ".join([f"*{prev}"] * 9) + "]")
    text = "\n".join(levels) + "\nname: wf\ntasks: *i\nmethod: accrue\nbudgets: {env_steps: 1, eval_every: 1}\n"
    line = short(one_line_error(accrue("stage", "status", str(workflow(tmp_path, text)), "--store", str(store))))
    assert "tasks.0: input should be a valid string" in line or "tasks" in line


def test_an_oserror_of_any_command_is_one_line_naming_the_path(tmp_path, monkeypatch, capsys):
    """The general rule in cli.main: OSError, UnicodeError and ValueError become one line, exit 2."""
    import typer

    import cli.main as cli_main

    before = list(cli_main.app.registered_commands)

    @cli_main.app.command("boom-os")
    def _os() -> None:
        open(tmp_path / "nope" / ("y" * 300))

    @cli_main.app.command("boom-unicode")
    def _uni() -> None:
        b"\xff".decode("utf-8")

    @cli_main.app.command("boom-value")
    def _val() -> None:
        raise ValueError("x" * 5000)

    try:
        for name, pattern in (
            ("boom-os", "No such file or directory"),
            ("boom-unicode", "not valid utf-8"),
            ("boom-value", "xxx"),
        ):
            monkeypatch.setattr(sys, "argv", ["accrue", name])
            with pytest.raises(SystemExit) as done:
                cli_main.main()
            err = capsys.readouterr().err.strip().splitlines()
            assert done.value.code == 2 and len(err) == 1 and err[0].startswith("error: "), err
            assert pattern in err[0] and len(err[0]) <= cli_main.MESSAGE_LIMIT + 10
        assert typer  # the app is typer's
    finally:
        cli_main.app.registered_commands[:] = before
