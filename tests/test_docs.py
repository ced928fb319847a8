"""README.md is the front page and docs/ the documentation site (mkdocs.yml; `.ci/run` builds it with
--strict, which catches broken links and anchors). Here: the README stays short and gives the two commands
CI runs, the generated reference pages match the code, every page is in the site's navigation, every
`accrue` command a page shows exists with the flags it uses, and what a user reads names no tracker issue."""

from __future__ import annotations

import re
import shlex
import sys
from pathlib import Path

import pytest
import typer.testing
import yaml
from test_walkthrough_share import is_group, resolve

from cli.main import app

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
sys.path.insert(0, str(ROOT / "scripts"))
import gen_docs  # noqa: E402

TRACKER = re.compile(r"\b(issues?[- ]\d+|session \d+)", re.I)
# the developer's pages (the nav's Development section) keep their record of the work
DEVELOPER_PAGES = {"development.md", "INTERFACES.md", "MUTATION.md"}
# pages a user reads that may still carry tracker numbers (none now)
KNOWN: set[str] = set()


def nav_pages(nav) -> list[str]:
    """Every page the mkdocs.yml nav lists, in order."""
    found = []
    for entry in nav:
        value = next(iter(entry.values())) if isinstance(entry, dict) else entry
        found += nav_pages(value) if isinstance(value, list) else [value]
    return found


NAV = nav_pages(yaml.safe_load((ROOT / "mkdocs.yml").read_text())["nav"])


def bash_lines(text: str) -> list[str]:
    """The command lines of a page's ```bash blocks, continuation lines joined, comments left on."""
    lines = []
    for block in re.findall(r"^```bash\n(.*?)^```", text, re.S | re.M):
        lines += [line.strip() for line in block.replace("\\\n", " ").splitlines() if line.strip()]
    return lines


def without_generated_tables(text: str) -> str:
    """A page less its bench tables, which scripts/bench_tables.py writes from the specs' descriptions."""
    return re.sub(r"<!-- bench:([\w.-]+) -->.*?<!-- /bench:\1 -->", "", text, flags=re.S)


def test_readme_is_a_front_page():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 250, f"README.md has {len(lines)} lines: move the detail into a docs/ page"


def test_readme_gives_the_two_commands_and_ci_runs_its_test_command():
    commands = [shlex.split(line, comments=True) for line in bash_lines(README.read_text(encoding="utf-8"))]
    assert ["bash", "scripts/quickstart.sh"] in commands and ["bash", "scripts/test.sh"] in commands
    ci = (ROOT / ".ci" / "run").read_text()
    assert re.search(r"^bash scripts/test\.sh$", ci, re.M), ".ci/run must run the README's test command"
    assert re.search(r"\.venv/bin/mkdocs build --strict ", ci), ".ci/run must build the site strict"


def test_readme_links_and_picture_exist():
    text = README.read_text(encoding="utf-8")
    targets = re.findall(r"\]\(([^)\s]+)\)", text)
    assert "docs/images/quickstart-success-matrix.png" in targets
    for target in targets:
        if not re.match(r"[a-z]+://", target):
            assert (ROOT / target.split("#")[0]).exists(), f"README.md links to {target}, which does not exist"


def test_generated_reference_pages_are_current():
    stale = [str(p.relative_to(ROOT)) for p in gen_docs.stale_pages()]
    assert not stale, f"{', '.join(stale)} out of date: run python scripts/gen_docs.py and commit the result"


def test_every_page_is_in_the_nav_and_every_nav_entry_is_a_page():
    pages = {str(p.relative_to(DOCS)) for p in DOCS.rglob("*.md")}
    assert sorted(pages - set(NAV)) == [], "add these pages to mkdocs.yml's nav"
    assert sorted(set(NAV) - pages) == [], "mkdocs.yml's nav names pages that do not exist"


def page_commands() -> list[tuple[str, str]]:
    pages = [README, *(DOCS / p for p in NAV)]
    return [
        (str(page.relative_to(ROOT)), line)
        for page in pages
        if page.is_file()
        for line in bash_lines(page.read_text(encoding="utf-8"))
    ]


@pytest.mark.parametrize("page,line", [c for c in page_commands() if c[1].startswith("accrue ")])
def test_every_accrue_command_a_page_shows_exists(page, line):
    argv = shlex.split(line.replace('"$REMOTE"', "s3://lab/accrue"), comments=True)
    if argv[1] == "bench" and argv[2] not in ("status", "report", "budget", "run"):
        argv.insert(2, "run")  # `accrue bench SPEC` is `accrue bench run SPEC`
    cmd, rest, name = resolve(argv[1:])
    assert not is_group(cmd), f"{page}: `{line}` names a group, not a command"
    help_text = typer.testing.CliRunner().invoke(app, [*name.split(), "--help"]).output
    for flag in (a.split("=")[0] for a in rest if a.startswith("--")):
        assert flag in help_text, f"{page}: {flag} is not in `accrue {name} --help`"


@pytest.mark.parametrize(
    "page,line",
    [c for c in page_commands() if re.match(r"(bash|python|\.venv/bin/python) (scripts|benchmarks)/", c[1])],
)
def test_every_script_a_page_runs_exists(page, line):
    script = shlex.split(line, comments=True)[1]
    assert (ROOT / script).is_file(), f"{page}: `{line}` runs {script}, which does not exist"


def test_no_tracker_numbers_in_what_a_user_reads():
    pages = [README, *(DOCS / p for p in NAV if p not in DEVELOPER_PAGES | KNOWN)]
    found = [
        f"{page.relative_to(ROOT)}: {m.group(0)}"
        for page in pages
        if page.is_file()
        for m in TRACKER.finditer(without_generated_tables(page.read_text(encoding="utf-8")))
    ]
    assert not found, "tracker numbers belong in git, not in a page a user reads: " + "; ".join(found)


@pytest.mark.parametrize("spec", sorted((ROOT / "workflows" / "bench").glob("*.yaml")), ids=lambda p: p.name)
def test_a_bench_spec_header_is_short_and_carries_no_history(spec):
    """A spec's header says what it runs and how its budget was chosen; its history is in git."""
    lines = spec.read_text(encoding="utf-8").splitlines()
    header = lines[: next(i for i, line in enumerate(lines) if re.match(r"[a-z_]+:", line))]
    assert len(header) <= 20, f"{spec.name}: a {len(header)}-line header"
    comments = [line for line in lines if line.lstrip().startswith("#")]
    assert not [c for c in comments if TRACKER.search(c)], f"{spec.name}: tracker numbers in its comments"
