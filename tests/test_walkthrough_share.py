"""The "Sharing a store" walk-through of docs/sharing.md, without running it (scripts/walkthrough_share.sh does,
in minutes): its blocks extract through the script's own extractor, every command parses against
the real CLI (subcommands, flags and arguments), and the script's cache-hit check fails on a run
that executed a step."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
from pathlib import Path

import pytest
import typer.main
import typer.testing

from cli.main import app

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "walkthrough_share.sh"
MACHINES = {"robot PC", "workstation", "auditor"}


def script(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", str(SCRIPT), *args], cwd=cwd, capture_output=True, text=True, timeout=60)


def walkthrough() -> list[tuple[str, str]]:
    done = script("--list")
    assert done.returncode == 0, done.stderr
    return [tuple(line.split("\t", 1)) for line in done.stdout.splitlines()]


def test_blocks_extract_in_the_order_a_team_runs_them():
    steps = walkthrough()
    assert {m for m, _ in steps} == MACHINES
    order = [f"{m}: {c}" for m, c in steps]
    want = [
        "robot PC: accrue init",
        'robot PC: accrue remote add origin "$REMOTE" --create',
        "robot PC: accrue push",
        'workstation: accrue clone "$REMOTE" .accrue',
        "workstation: accrue pull",
        "workstation: accrue run workflows/hardware-sim.yaml",
        "workstation: accrue report workflows/hardware-sim.yaml",
    ]
    assert set(want) <= set(order), order
    positions = [order.index(w) for w in want]
    assert positions == sorted(positions), order  # each step after the one it needs
    assert all(c.startswith("accrue ") for _, c in steps)  # no shell glue a reader would miss


def test_a_block_without_its_machine_is_refused(tmp_path):
    scripts = tmp_path / "scripts"
    scripts.mkdir()
    (scripts / SCRIPT.name).write_text(SCRIPT.read_text())
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "sharing.md").write_text(
        "<!-- walkthrough:share:start -->\n```bash\naccrue init\n```\n<!-- walkthrough:share:end -->\n"
    )
    done = subprocess.run(["bash", str(scripts / SCRIPT.name), "--list"], capture_output=True, text=True)
    assert done.returncode != 0 and "must start with" in done.stderr


def is_group(cmd) -> bool:
    return hasattr(cmd, "list_commands")  # typer 0.29 carries its own click: no isinstance


def resolve(argv: list[str]):
    """The (click) command an `accrue ...` line reaches, the arguments left for it, and its name."""
    cmd = typer.main.get_command(app)
    names = []
    while is_group(cmd) and argv and not argv[0].startswith("-"):
        sub = cmd.get_command(cmd.make_context("accrue", [], resilient_parsing=True), argv[0])
        assert sub is not None, f"accrue {' '.join(names + argv[:1])}: no such subcommand"
        names.append(argv.pop(0))
        cmd = sub
    return cmd, argv, " ".join(names)


@pytest.mark.parametrize("machine,line", walkthrough())
def test_every_command_parses_against_the_cli(machine, line, monkeypatch):
    monkeypatch.chdir(ROOT)  # workflow paths are relative to a clone's root
    monkeypatch.setenv("REMOTE", "s3://lab-accrue/cell-3")
    argv = shlex.split(line.replace('"$REMOTE"', "s3://lab-accrue/cell-3"))
    assert argv[0] == "accrue" and "$" not in " ".join(argv)
    cmd, rest, name = resolve(argv[1:])
    assert not is_group(cmd), f"{line}: names a group, not a command"
    help_text = typer.testing.CliRunner().invoke(app, [*name.split(), "--help"]).output
    for flag in (a for a in rest if a.startswith("--")):
        assert flag in help_text, f"{line}: {flag} is not in `accrue {name} --help`"
    cmd.make_context(f"accrue {name}", rest)  # strict parse: unknown flags, missing arguments raise


def test_the_workflow_the_walkthrough_runs_exists_and_has_a_robot():
    import yaml

    runs = {shlex.split(c)[2] for _, c in walkthrough() if c.startswith("accrue run ")}
    for path in runs:
        assert "robot" in yaml.safe_load((ROOT / path).read_text())


@pytest.mark.parametrize(
    "summary,ok",
    [
        ("workflow hardware-sim: stages 1-2 done (0 steps run, 12 cached) in 3 s", True),
        ("workflow hardware-sim: stages 1-2 done (1 steps run, 11 cached) in 40 s", False),
        ("workflow hardware-sim: stages 1-1 done (6 steps run, 0 cached) in 150 s", False),
        ("workflow hardware-sim: stages 1-2 done (0 steps run, 0 cached) in 0 s", False),
        ("error: workflow.yaml: no such file", False),
    ],
)
def test_the_cache_hit_check(tmp_path, summary, ok):
    log = tmp_path / "run.log"
    log.write_text(f"step train: committed record abc in 1.0 s\n{summary}\n")
    done = script("--check-cached", str(log))
    assert (done.returncode == 0) == ok, done.stdout + done.stderr


def transcript_runs(kind: str) -> dict[str, str]:
    """Each `accrue run` of a committed walk-through transcript: machine -> its summary line."""
    path = ROOT / "benchmarks" / "results" / f"walkthrough_share_{kind}.txt"
    if not path.exists():
        pytest.skip(f"{path.name} not committed")
    runs, machine = {}, None
    for line in path.read_text().splitlines():
        head = re.match(r"\+ \[(.+?)\] accrue run ", line)
        if head:
            machine = head.group(1)
        elif machine and re.search(r"done \(\d+ steps run, \d+ cached\)", line):
            runs.setdefault(machine, []).append(line)
            machine = None
    return runs


@pytest.mark.parametrize("kind", ["dir", "s3"])
def test_the_check_on_the_real_runs_of_a_transcript(tmp_path, kind):
    """The robot PC's real first run executed its steps: the check refuses it; the workstation's
    passes."""
    runs = transcript_runs(kind)
    for machine, want in (("robot PC", False), ("workstation", True)):
        log = tmp_path / f"{machine}.log"
        log.write_text(runs[machine][0] + "\n")
        assert (script("--check-cached", str(log)).returncode == 0) == want, runs[machine][0]


def run_in_repo(tmp_path, block: str) -> subprocess.CompletedProcess:
    """The script on a throwaway repository whose docs/sharing.md walk-through is `block`."""
    repo = tmp_path / "repo"
    (repo / "scripts").mkdir(parents=True)
    (repo / "scripts" / SCRIPT.name).write_text(SCRIPT.read_text())
    (repo / "docs").mkdir()
    (repo / "docs" / "sharing.md").write_text(
        f"<!-- walkthrough:share:start -->\n```bash\n{block}```\n<!-- walkthrough:share:end -->\n"
    )
    (repo / ".venv").symlink_to(ROOT / ".venv")
    (repo / ".gitignore").write_text(".venv\n")
    for cmd in (["init", "-q"], ["add", "."], ["-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "x"]):
        subprocess.run(["git", *cmd], cwd=repo, check=True)
    env = {**os.environ, "WALKTHROUGH_DIR": str(tmp_path / "work")}
    return subprocess.run(
        ["bash", str(repo / "scripts" / SCRIPT.name), "dir"], capture_output=True, text=True, env=env, timeout=120
    )


def test_the_script_stops_at_the_first_failing_command(tmp_path):
    """A walk-through with a bad command: the script runs up to it and exits non-zero without
    running the next."""
    done = run_in_repo(tmp_path, "# robot PC\naccrue version\naccrue no-such-command\naccrue init\n")
    assert done.returncode == 1, done.stdout + done.stderr
    assert "+ [robot PC] accrue version" in done.stdout and "= rc 0" in done.stdout
    assert "accrue no-such-command exited 2" in done.stderr
    assert "accrue init" not in done.stdout and not (tmp_path / "work" / "robot-PC" / ".accrue").exists()


def test_a_walkthrough_without_a_workstation_run_fails(tmp_path):
    """Renaming the machine or dropping its run must not let the cache-hit check pass unchecked."""
    done = run_in_repo(tmp_path, "# robot PC\naccrue version\n")
    assert done.returncode == 1 and "no workstation 'accrue run'" in done.stderr, done.stdout + done.stderr
