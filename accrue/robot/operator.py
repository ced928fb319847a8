"""The operator: labels each episode's success, says when the scene is reset, can pause, abort, end an
episode early and re-label the last one. Labels carry who gave them, when and through what (they are
sealed with the episode, so an audit finds every one).

    TerminalOperator(name)            single keys on a terminal (rich): s/f label, r reset done, p pause,
                                      e end the episode now, l re-label the last episode, a abort, and
                                      i take over / give back while robot.intervention has signal: key
    PageOperator(name, ...)           the same keys as buttons on a local web page with the live state
                                      (accrue.robot.operator_page), and on the terminal too when there is one
    ScriptedOperator(name, ...)       for tests and unattended dry runs: labels what the simulated robot
                                      reports, with an optional delay and deliberate mistakes

The terminal and the page share one state machine (KeyOperator): a key means the same from either, an
unknown key gets one line naming the keys that work at that moment, and every action is audited with
the view it came from (`via`).
"""

from __future__ import annotations

import datetime as _dt
import os
import threading
import time
from dataclasses import asdict, dataclass, field, replace
from typing import Callable

from accrue.errors import AccrueError


def now_iso() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds")


@dataclass(frozen=True)
class Label:
    success: bool
    by: str  # the operator's name, or "system" for an episode a fault ended
    at: str  # ISO time the label was given
    note: str = ""
    via: str = ""  # "terminal" | "page" | "scripted" | "system": the view the label came through

    def to_json(self) -> dict:
        return asdict(self)


@dataclass
class ResetAnswer:
    go: bool  # False: the operator aborted the session
    relabel: Label | None = None  # a corrected label for the last episode, if the operator gave one


class Operator:
    name = "operator"

    def tell(self, line: str) -> None:
        """Show the operator something (a safety stop, a fault, the running success)."""

    def show(self, state: dict) -> None:
        """The live state for a view that can show it (the page): task, phase, episode, step, window,
        robot_time_s, learner_version, learner_health, interventions (control steps the operator drove
        in this episode), intervening, intervention_rate_window, status, frame. Thread-safe where
        implemented; the terminal and the scripted operator have nothing to show it on."""

    def wait_reset(self, episode: int, task: str, last: int | None) -> ResetAnswer:
        raise NotImplementedError

    def label(self, episode: int, summary: str) -> Label | None:
        """None: the operator aborted instead of labelling (the episode is then discarded)."""
        raise NotImplementedError

    def label_proposed(self, episode: int, summary: str, success: bool, p: float) -> Label | None:
        """label() with robot.success_classifier's proposal in the prompt: the operator confirms it with its
        key or overrules it with the other; the label says so (via ...+classifier-proposal, and the note)."""
        word = "success" if success else "failure"
        label = self.label(episode, f"{summary}; the classifier proposes {word}, p(success) {p:.2f}")
        if label is None:
            return None
        how = "confirmed" if label.success == success else "overruled"
        return replace(
            label, via=f"{label.via}+classifier-proposal", note=f"classifier proposed {word}, p(success) {p:.4f}: {how}"
        )

    def poll(self) -> str | None:
        """Non-blocking, during an episode: "end" (stop it now), "abort", or None."""
        return None

    def finish(self, line: str, last: int) -> ResetAnswer:
        """The step has all its episodes (`line` says so): the last chance to re-label the last one, `last`,
        before the step ends. go=False: the operator aborted. An operator nobody answers for finishes."""
        return ResetAnswer(go=True)

    def close(self) -> None:
        """Release what the operator holds (the terminal's mode, the page's server)."""


@dataclass
class ScriptedOperator(Operator):
    """Labels from the simulated robot's own success (what a person would see), `delay_s` to answer, and
    a wrong label on the episodes listed in `mistakes`; those also in `corrects` are re-labelled at the
    next reset (as a person who notices the slip would)."""

    oracle: Callable[[], bool] | None = None
    reset_scene: Callable[[], None] | None = None
    name: str = "scripted"
    delay_s: float = 0.0
    mistakes: set[int] = field(default_factory=set)
    corrects: set[int] = field(default_factory=set)
    abort_before: int | None = None  # abort the session before this episode index
    told: list[str] = field(default_factory=list)
    _pending: Label | None = None

    def tell(self, line: str) -> None:
        self.told.append(line)

    def wait_reset(self, episode: int, task: str, last: int | None) -> ResetAnswer:
        if self.abort_before is not None and episode >= self.abort_before:
            return ResetAnswer(go=False)
        if self.reset_scene is not None:
            self.reset_scene()
        fix, self._pending = self._pending, None
        return ResetAnswer(go=True, relabel=fix)

    def finish(self, line: str, last: int) -> ResetAnswer:
        fix, self._pending = self._pending, None  # a slip on the step's last episode is corrected too
        return ResetAnswer(go=True, relabel=fix)

    def label(self, episode: int, summary: str) -> Label | None:
        if self.oracle is None:
            raise AccrueError(
                "the scripted operator needs a robot that reports its episode's success "
                "(the simulated robot accrue_sim does); use robot.operator: terminal"
            )
        time.sleep(self.delay_s)
        truth = bool(self.oracle())
        wrong = episode in self.mistakes
        label = Label(
            success=truth != wrong,
            by=self.name,
            at=now_iso(),
            note="deliberate mistake (scripted)" if wrong else "",
            via="scripted",
        )
        if wrong and episode in self.corrects:
            self._pending = Label(
                success=truth, by=self.name, at=now_iso(), note=f"corrects episode {episode}", via="scripted"
            )
        return label


# what each key does; the prompts name the ones that work at that moment
KEYS = {
    "r": "reset done",
    "s": "success",
    "f": "failure",
    "e": "end episode",
    "p": "pause/resume",
    "l": "re-label last",
    "a": "abort",
    "i": "take over / give back",  # only while robot.intervention (signal: key) is on
}
RESET_KEYS, LABEL_KEYS, RELABEL_KEYS, EPISODE_KEYS, FINISH_KEYS = "rpla", "sfpa", "sfa", "epa", "rla"
FINISH_LINE = "r=finish  l=re-label last  a=abort"  # at a step's end r finishes it (no scene to reset)
AUDIT_EVENT = "robot-operator-action"


def keys_line(keys: str) -> str:
    return "  ".join(f"{k}={KEYS[k]}" for k in keys)


class KeyOperator(Operator):
    """The operator's single keys, from whichever view they come (`_next` gives (via, key)): what each
    key does at each moment, the lines that say so, and the audit of every action."""

    # class defaults too: a subclass that replaces __init__ (a test's keyed terminal) still works
    _audit: Callable[[str, dict], None] | None = None
    _audit_lock = threading.Lock()
    paused = False
    _episode: int | None = None
    takeover_key = False  # robot.intervention with signal: key - `i` hands the robot to the teleop and back

    def __init__(self, name: str, audit: Callable[[str, dict], None] | None = None):
        self.name = name
        self._audit = audit
        self._audit_lock = threading.Lock()  # the page's server threads audit refusals too
        self.paused = False
        self._episode: int | None = None  # the episode in progress (poll's actions name it)

    # ------------------------------------------------------------------ what a view provides
    def _next(self, timeout: float | None) -> tuple[str, str] | None:
        """The next key as (via, key); None when none came within `timeout` (0: only one already there)."""
        raise NotImplementedError

    def _say(self, line: str) -> None:
        raise NotImplementedError

    def _expect(self, what: str, episode: int | None, keys: str, line: str) -> None:
        """What the operator is asked now (the page enables those buttons); nothing for a terminal."""

    def _acted(self, via: str, action: str, fields: dict) -> None:
        """An action was taken (the page counts them); nothing for a terminal."""

    # ------------------------------------------------------------------ shared
    def audit(self, event: str, fields: dict) -> None:
        if self._audit is not None:
            with self._audit_lock:
                self._audit(event, fields)

    def _action(self, via: str, action: str, **fields) -> None:
        fields = {"via": via, "action": action, "operator": self.name, **fields}
        self.audit(AUDIT_EVENT, fields)
        self._acted(via, action, fields)

    def _unknown(self, key: str, keys: str, line: str | None = None) -> None:
        shown = {"\x1b": "Esc", "\x7f": "Backspace", "\t": "Tab"}.get(key, key if key.isprintable() else repr(key))
        self._say(f"key {shown!r} does nothing here; keys now: {line or keys_line(keys)}")

    def _pause(self, via: str, during_episode: bool = False) -> None:
        self.paused = not self.paused
        self._action(via, "pause" if self.paused else "resume", episode=self._episode)
        if not self.paused:
            self._say("resumed: press r when the scene is reset")
        elif during_episode:
            self._say("paused: this episode runs to its end, then the robot waits until p resumes")
        else:
            self._say("paused: press p to resume")

    def _keys(self):
        """Keys as they come; whitespace is skipped (Enter after a key is habit, not a mistake)."""
        while True:
            got = self._next(None)
            if got is not None and not got[1].isspace():
                yield got

    def wait_reset(self, episode: int, task: str, last: int | None) -> ResetAnswer:
        self._episode = None
        line = f"episode {episode} ({task}): reset the scene, then press r"
        self._expect("reset", episode, RESET_KEYS, line)
        self._say(f"{line}  ({keys_line(RESET_KEYS)})")
        relabel = None
        for via, key in self._keys():
            if key == "a":
                self._action(via, "abort", episode=episode)
                return ResetAnswer(go=False, relabel=relabel)
            if key == "p":
                self._pause(via)
            elif key == "l":
                if last is None:
                    self._say("no episode to re-label yet")
                    continue
                got = self._relabel(last)
                if got is None:  # aborted while re-labelling
                    return ResetAnswer(go=False, relabel=relabel)
                relabel = got
                self._expect("reset", episode, RESET_KEYS, line)
            elif key == "r":
                if self.paused:
                    self._say("paused: press p to resume, then r")
                    continue
                self._action(via, "reset", episode=episode)
                self._episode = episode
                keys = EPISODE_KEYS + ("i" if self.takeover_key else "")
                self._expect("episode", episode, keys, f"episode {episode} running: e ends it now")
                return ResetAnswer(go=True, relabel=relabel)
            else:
                self._unknown(key, RESET_KEYS)
        raise AssertionError("unreachable")  # _keys never ends

    def finish(self, line: str, last: int) -> ResetAnswer:
        self._episode = None
        prompt = f"{line}: press r to finish the step, or l to re-label episode {last} first"
        self._expect("finish", last, FINISH_KEYS, prompt)
        self._say(f"{prompt}  ({FINISH_LINE})")
        relabel = None
        for via, key in self._keys():
            if key == "a":
                self._action(via, "abort", episode=last)
                return ResetAnswer(go=False, relabel=relabel)
            if key == "l":
                got = self._relabel(last)
                if got is None:  # aborted while re-labelling
                    return ResetAnswer(go=False, relabel=relabel)
                relabel = got
                self._expect("finish", last, FINISH_KEYS, prompt)
            elif key == "r":
                self._action(via, "finish", episode=last)
                return ResetAnswer(go=True, relabel=relabel)
            else:
                self._unknown(key, FINISH_KEYS, FINISH_LINE)
        raise AssertionError("unreachable")  # _keys never ends

    def _relabel(self, last: int) -> Label | None:
        line = f"re-label episode {last}: s=success  f=failure"
        self._expect("relabel", last, RELABEL_KEYS, line)
        self._say(line)
        for via, key in self._keys():
            if key in ("s", "f"):
                label = Label(
                    success=key == "s", by=self.name, at=now_iso(), note=f"re-label of episode {last}", via=via
                )
                self._action(via, "relabel", episode=last, success=label.success)
                self._say(f"episode {last} re-labelled {'success' if label.success else 'failure'}")
                return label
            if key == "a":
                self._action(via, "abort", episode=last)
                return None
            self._unknown(key, RELABEL_KEYS)
        raise AssertionError("unreachable")

    def label(self, episode: int, summary: str) -> Label | None:
        self._episode = None
        line = f"episode {episode} ended ({summary}): s=success  f=failure"
        self._expect("label", episode, LABEL_KEYS, line)
        self._say(f"{line}  a=abort")
        for via, key in self._keys():
            if key in ("s", "f"):
                label = Label(success=key == "s", by=self.name, at=now_iso(), via=via)
                self._action(via, "label", episode=episode, success=label.success)
                self._expect("idle", episode, "p", f"episode {episode} labelled")
                return label
            if key == "a":
                self._action(via, "abort", episode=episode)
                return None
            if key == "p":
                self._pause(via)
            else:
                self._unknown(key, LABEL_KEYS)
        raise AssertionError("unreachable")

    def poll(self) -> str | None:
        while (got := self._next(0)) is not None:
            via, key = got
            if key == "e":
                self._action(via, "end", episode=self._episode)
                return "end"
            if key == "a":
                self._action(via, "abort", episode=self._episode)
                return "abort"
            if key == "i" and self.takeover_key:
                self._action(via, "takeover", episode=self._episode)
                return "intervene"
            if key == "p":
                self._pause(via, during_episode=True)
            elif not key.isspace():
                self._unknown(key, EPISODE_KEYS + ("i" if self.takeover_key else ""))
        return None


class TtyKeys:
    """stdin in cbreak mode for the operator's whole session: keys typed at any moment are read one by one."""

    def __init__(self, what: str):
        import sys

        if not sys.stdin.isatty():
            raise AccrueError(
                f"{what} needs an interactive terminal (stdin is not a tty); "
                "use robot.operator: scripted for an unattended run on the simulated robot"
            )
        import termios
        import tty

        self.fd = sys.stdin.fileno()
        self._saved = termios.tcgetattr(self.fd)
        tty.setcbreak(self.fd, termios.TCSANOW)

    def key(self, timeout: float | None, wake: int | None = None) -> str | None:
        """One key within `timeout`; None on timeout or when `wake` (a pipe's read end) becomes readable."""
        import select

        ready, _, _ = select.select([self.fd] + ([wake] if wake is not None else []), [], [], timeout)
        if self.fd not in ready:
            return None
        # os.read, not sys.stdin.read: a buffered read would swallow keys typed together, and the next
        # select() would wait for keys already read
        key = os.read(self.fd, 1).decode(errors="replace").lower()
        if key == "\x1b":  # an arrow or function key is an escape sequence: one key, not three
            while select.select([self.fd], [], [], 0)[0]:
                os.read(self.fd, 16)
        return key

    def restore(self) -> None:
        """Give the terminal back as it was."""
        import termios

        if self._saved is not None:
            try:
                termios.tcsetattr(self.fd, termios.TCSADRAIN, self._saved)
            except termios.error:
                pass
            self._saved = None


class TerminalOperator(KeyOperator):
    """Single keys on the terminal the stage runs in (stdin in cbreak mode while the operator lives)."""

    KEYS = keys_line("sfrpela")
    _tty: TtyKeys | None = None

    def __init__(self, name: str, console=None, audit: Callable[[str, dict], None] | None = None):
        import atexit

        from rich.console import Console

        self._tty = TtyKeys("robot.operator: terminal")
        super().__init__(name, audit)
        self.console = console or Console(stderr=True)
        atexit.register(self.close)

    def close(self) -> None:
        if self._tty is not None:
            self._tty.restore()

    def _key(self, timeout: float | None) -> str | None:
        return self._tty.key(timeout)

    def _next(self, timeout: float | None) -> tuple[str, str] | None:
        key = self._key(timeout)
        return None if key is None else ("terminal", key)

    def _say(self, line: str) -> None:
        self.console.print(line, markup=False, highlight=False)

    def tell(self, line: str) -> None:
        self.console.print(f"[bold yellow]robot:[/] {line}")
