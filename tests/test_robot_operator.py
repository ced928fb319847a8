"""The terminal operator on a real pseudo-terminal (what a person types): an unknown key gets one line
naming the keys that work at that moment, `l` before any episode says there is nothing to re-label, and
every action is audited with the view it came from; labels carry `via`."""

from __future__ import annotations

import io
import os
import pty
import sys

import pytest

from accrue.errors import AccrueError


@pytest.fixture
def tty_keys(monkeypatch):
    """sys.stdin is a pseudo-terminal; yields type_keys(keys), what a person types at it (also used by
    tests/test_robot_operator_page.py)."""
    master, slave = pty.openpty()
    tty_in = os.fdopen(slave, "r")
    monkeypatch.setattr(sys, "stdin", tty_in)
    yield lambda keys: os.write(master, keys.encode())
    tty_in.close()
    os.close(master)


@pytest.fixture
def terminal(tty_keys):
    """A TerminalOperator on a pty; yields (operator, type_keys, console output, audit records)."""
    from rich.console import Console

    from accrue.robot.operator import TerminalOperator

    out = io.StringIO()
    audited: list[tuple[str, dict]] = []
    op = TerminalOperator(
        "ann", console=Console(file=out, width=300), audit=lambda event, fields: audited.append((event, fields))
    )
    yield op, tty_keys, out, audited
    op.close()


def lines(out: io.StringIO) -> list[str]:
    return [line for line in out.getvalue().splitlines() if line.strip()]


def test_an_unknown_key_names_the_keys_that_work_now(terminal):
    op, type_keys, out, _ = terminal
    type_keys("xr")
    assert op.wait_reset(0, "nist/rect_peg", None).go
    said = [line for line in lines(out) if "'x'" in line]
    assert said == ["key 'x' does nothing here; keys now: r=reset done  p=pause/resume  l=re-label last  a=abort"]
    type_keys("qs")  # at the label prompt the keys are others
    assert op.label(0, "done, 40 steps").success
    assert lines(out)[-1] == "key 'q' does nothing here; keys now: s=success  f=failure  p=pause/resume  a=abort"
    type_keys("z")  # during an episode
    assert op.poll() is None
    assert lines(out)[-1] == "key 'z' does nothing here; keys now: e=end episode  p=pause/resume  a=abort"
    type_keys("\n\x1b[A")  # Enter is skipped; an arrow key (an escape sequence) is one key, not three
    assert op.poll() is None
    assert lines(out)[-1] == "key 'Esc' does nothing here; keys now: e=end episode  p=pause/resume  a=abort"
    assert sum("does nothing here" in line for line in lines(out)) == 4


def test_relabel_before_any_episode_says_so(terminal):
    op, type_keys, out, audited = terminal
    type_keys("lr")
    answer = op.wait_reset(0, "nist/rect_peg", None)
    assert answer.go and answer.relabel is None
    assert "no episode to re-label yet" in lines(out)
    assert [f["action"] for _, f in audited] == ["reset"]


def test_every_action_is_audited_with_via_and_labels_carry_it(terminal):
    op, type_keys, out, audited = terminal
    type_keys("lxfpr")  # re-label episode 3 (a stray key inside), pause: r refused until p
    type_keys("pr")
    answer = op.wait_reset(4, "nist/rect_peg", 3)
    assert answer.go and answer.relabel.success is False and answer.relabel.via == "terminal"
    assert "key 'x' does nothing here; keys now: s=success  f=failure  a=abort" in lines(out)
    assert "paused: press p to resume, then r" in lines(out)
    type_keys("pe")  # pause during the episode (it takes effect at the next reset), end it now
    assert op.poll() == "end"
    type_keys("s")
    label = op.label(4, "operator, 12 steps")
    assert label.success and label.by == "ann" and label.via == "terminal"
    assert label.to_json()["via"] == "terminal"
    type_keys("rpa")  # still paused from the episode: r refused; resume; abort
    assert op.wait_reset(5, "nist/rect_peg", 4).go is False
    assert {e for e, _ in audited} == {"robot-operator-action"}
    assert [(f["action"], f.get("episode")) for _, f in audited] == [
        ("relabel", 3),
        ("pause", None),
        ("resume", None),
        ("reset", 4),
        ("pause", 4),
        ("end", 4),
        ("label", 4),
        ("resume", None),
        ("abort", 5),
    ]
    assert all(f["via"] == "terminal" and f["operator"] == "ann" for _, f in audited)
    assert audited[0][1]["success"] is False and audited[6][1]["success"] is True


def test_show_is_a_no_op_for_operators_without_a_page(terminal):
    from accrue.robot.operator import Operator, ScriptedOperator

    op, *_ = terminal
    state = {"task": "nist/rect_peg", "episode": 3, "window": [True], "frame": None}
    for o in (Operator(), ScriptedOperator(oracle=lambda: True), op):
        assert o.show(state) is None


def test_scripted_labels_say_scripted():
    from accrue.robot.operator import ScriptedOperator

    op = ScriptedOperator(oracle=lambda: True, mistakes={1}, corrects={1})
    assert op.label(0, "done").via == "scripted"
    assert op.label(1, "done").success is False
    fix = op.wait_reset(2, "nist/rect_peg", 1).relabel
    assert fix.success and fix.via == "scripted"


def test_terminal_needs_a_tty(monkeypatch):
    from accrue.robot.operator import TerminalOperator

    monkeypatch.setattr(sys, "stdin", io.StringIO())
    with pytest.raises(AccrueError, match="needs an interactive terminal"):
        TerminalOperator("ann")
