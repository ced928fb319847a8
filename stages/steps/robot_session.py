"""A robot session: the robot, the operator, and sealing every labelled episode at once.

On a robot, warmup, train and evaluate-all (their robot part: stages.steps.robot_env) are sequences of
operator-labelled robot episodes. Each finished, labelled episode is sealed immediately as an intra-step checkpoint artifact (fsynced by
the store) holding every episode sealed so far - `episodes/<index>/` with `episode.json` (label with
who/when, re-labels, robot time, faults, weights version, session), `transitions.npz` and
`episode.mcap` - plus the learner's last checkpoint and `sessions.json`. Unchanged files are the same
objects, so each seal writes only the new episode. `--continue` after any interruption materialises the
newest such checkpoint: every sealed episode comes back exactly once; an episode that was started and
not sealed is discarded, and the audit log says so.

Settings that do not change what a step computes (the operator, the learner's address, fault injection,
the clock) are session settings: bound to the step body, outside its cache key, so a resumed session
may use another operator or host.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from stages.errors import StageError
from stages.runner_context import StepContext
from stages.steps.common import copy_tree, read_json, write_json

SESSIONS_FILE = "sessions.json"
EPISODES_DIR = "episodes"
SHOW_EVERY_S = 0.2  # robot time between live-state updates to the operator during an episode (at chunk ends)


@dataclass
class SessionSettings:
    """The unkeyed part of a workflow's robot section (see stages.workflow.RobotSpec)."""

    operator: str = "terminal"  # terminal | scripted | page
    operator_name: str = ""
    scripted: dict = field(default_factory=dict)  # delay_s, mistakes, corrects, abort_before
    operator_page: dict = field(default_factory=dict)  # listen HOST:PORT
    learner_address: str | None = None  # host:port of `accrue robot learner`; None: a local process
    link: dict | None = None  # robot.link: token_file, tls
    hold_staleness_s: float = 30.0  # robot time acted without an answering learner before the robot is held
    hold_wait_s: float = 300.0  # wall time held for the learner before the step ends
    handoff_wait_s: float = 120.0  # wall time train waits for the learner's update target at the end
    clock: float = 1.0
    faults: dict = field(default_factory=dict)  # accrue_sim fault fields
    timeouts: dict = field(default_factory=dict)
    heartbeat_s: float = 0.5
    dead_after_s: float = 3.0
    # robot.intervention (teleop, config, imports, signal, action_map, action_scale); None: off (the paper)
    intervention: dict | None = None
    tracking: dict | None = None  # the workflow's tracking: section (None: accrue.tracking's defaults)
    stop_window: int = 20  # robot.stop_window: the running success the operator is shown, in every phase


class SessionStop(KeyboardInterrupt):
    """Ctrl-C or SIGTERM during a hardware session. A KeyboardInterrupt, so the runner records the attempt
    as abandoned (resumable); `code` is the exit status (130 / 143), str() the one line to print."""

    def __init__(self, line: str, how: str, code: int, forced: bool = False):
        super().__init__(line)
        self.how, self.code, self.forced = how, code, forced


_STOPS = {signal.SIGINT: ("stopped by operator (Ctrl-C)", 130), signal.SIGTERM: ("stopped by signal (SIGTERM)", 143)}


class StopSignals:
    """While a hardware step runs: the first Ctrl-C or SIGTERM raises SessionStop in the main thread
    (where a blocking wait is interrupted too), except inside a `critical()` section (a seal being
    written), which finishes first; a second one forces - it is raised at once, wherever the clean stop
    is. Outside the main thread (nothing can receive signals there) it does nothing."""

    active: "StopSignals | None" = None

    def __init__(self):
        self.first: int | None = None
        self.quiet = 0
        self.pending = False
        self.saved: dict = {}

    def __enter__(self) -> "StopSignals":
        if threading.current_thread() is threading.main_thread() and StopSignals.active is None:
            self.saved = {sig: signal.signal(sig, self._handler) for sig in _STOPS}
            StopSignals.active = self
        return self

    def __exit__(self, *exc) -> None:
        if StopSignals.active is self:
            for sig, handler in self.saved.items():
                signal.signal(sig, handler)
            StopSignals.active = None

    def stop(self, forced: bool = False) -> SessionStop:
        how, code = _STOPS[self.first]
        return SessionStop(how + (": forced, cleanup skipped" if forced else ""), how, code, forced)

    def _handler(self, signum, frame) -> None:
        if self.first is not None:
            raise self.stop(forced=True)  # the second: no more waiting for the cleanup
        self.first = signum
        if self.quiet:
            self.pending = True  # raised when the seal in progress is written
            return
        raise self.stop()

    @classmethod
    @contextlib.contextmanager
    def critical(cls):
        """A section a first stop does not cut (the store's checkpoint and the session record)."""
        me = cls.active
        if me is None:
            yield
            return
        me.quiet += 1
        try:
            yield
        finally:
            me.quiet -= 1
            if not me.quiet and me.pending:
                me.pending = False
                raise me.stop()


@contextlib.contextmanager
def children_keep_sigint():
    """Threads started inside (the learner link's, which spawns the learner) have SIGINT blocked, and
    so do the processes they start: a Ctrl-C at the terminal, sent to the whole process group, reaches
    this actor only, which then shuts its learner down (no traceback from a learner killed mid-call)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


class LearnerHold:
    """The actor acts only on weights from a learner that answers (paper Sec. V-C's asynchrony, bounded).

    A learner that has not answered yet in this session holds the robot before its first action: the
    operator is told, and the actor waits up to `first_wait_s` (at least wait_s) of wall time for it - a
    learner this actor starts itself needs its start-up - then the step ends in one line saying it never
    connected, nothing moved. Once it has answered, `stale_s` is the robot time acted since it last
    answered (link.healthy()); once it reaches `staleness_s` the episode in progress is discarded (as at a
    kill), no command is sent (the robot holds its last target), the operator is told, and the actor waits
    up to `wait_s` of wall time for the learner: back in time, the session goes on; else the step ends in
    one line, every sealed episode kept. A learner that answers is training on every sealed episode, so its
    weights are as fresh as it can make them. A learner that refuses this actor (`refused()` returns its
    LinkRefused: a wrong link token, or TLS) cannot come back by waiting, so the hold ends at once, in one
    line saying what to fix. `learner` names it in the lines ("the learner at HOST:PORT"), `last_error()`
    says why the last call failed."""

    def __init__(
        self,
        healthy: Callable[[], bool],
        staleness_s: float,
        wait_s: float,
        step: str,
        poll_s: float = 0.1,
        refused: Callable[[], Exception | None] = lambda: None,
        first_wait_s: float = 0.0,
        learner: str = "the learner",
        last_error: Callable[[], str | None] = lambda: None,
    ):
        self.healthy, self.staleness_s, self.wait_s, self.step, self.poll_s = healthy, staleness_s, wait_s, step, poll_s
        self.refused, self.learner, self.last_error = refused, learner, last_error
        self.first_wait_s = max(wait_s, first_wait_s)
        self.stale_s = 0.0
        self.holding = False
        self.answered = False  # the learner answered at least once in this session

    def acted(self, robot_s: float) -> None:
        self.stale_s = 0.0 if self.healthy() else self.stale_s + robot_s

    def due(self) -> bool:
        if self.healthy():
            self.answered = True
            self.stale_s = 0.0
            return False
        return not self.answered or self.stale_s >= self.staleness_s - 1e-9

    def wait(self, session: "HardwareSession", operator, show, console) -> None:
        """Hold until the learner answers (again), or end the step (StageError) after the wait."""
        never = not self.answered
        limit = self.first_wait_s if never else self.wait_s
        if never:
            why = f"{self.learner} has not answered yet"
            line = f"robot held before its first action: {why}; waiting up to {limit:g} s for it"
        else:
            why = (
                f"the learner has not answered for {self.stale_s:.1f} s of robot time "
                f"(robot.hold.staleness_s {self.staleness_s:g})"
            )
            line = f"robot held: {why}; waiting up to {limit:g} s for it"
        self.holding = True
        session._log("robot-hold-started", stale_s=round(self.stale_s, 3), staleness_s=self.staleness_s, never=never)
        console.print(f"{self.step}: {line}", soft_wrap=True)
        operator.tell(line)
        show(learner_health="holding", status=line)
        started = time.monotonic()
        try:
            while not self.healthy():
                err = self.refused()
                if err is not None:
                    session._log("robot-hold-ended", outcome="refused", held_s=round(time.monotonic() - started, 3))
                    session.close(f"held: {err}")
                    raise StageError(
                        f"{self.step}: {err}; {len(session.episodes)} episodes are sealed: fix that and resume "
                        f"with `accrue stage run ... --step {self.step} --continue`"
                    )
                if time.monotonic() - started >= limit:
                    self._give_up(session, started, never, limit, why)
                if operator.poll() == "abort":
                    session.close("aborted by the operator")
                    raise StageError(
                        f"aborted by the operator while the robot was held; {len(session.episodes)} episodes "
                        "are sealed (resume with --continue)"
                    )
                time.sleep(self.poll_s)
        finally:
            self.holding = False
        held = time.monotonic() - started
        self.answered = True
        session._log("robot-hold-ended", outcome="learner back", held_s=round(held, 3))
        what = "answered" if never else "is back"
        operator.tell(f"the learner {what} after {held:.1f} s: going on")
        console.print(f"{self.step}: the learner {what} after {held:.1f} s; going on")
        self.stale_s = 0.0

    def _give_up(self, session: "HardwareSession", started: float, never: bool, limit: float, why: str) -> None:
        held = round(time.monotonic() - started, 3)
        session._log("robot-hold-ended", outcome="never connected" if never else "gave up", held_s=held)
        last = self.last_error()
        last = f"; last try: {last}" if last else ""
        sealed = len(session.episodes)
        resume = f"resume with `accrue stage run ... --step {self.step} --continue`"
        if never:
            session.close(f"held: the learner never connected in {limit:g} s")
            raise StageError(
                f"{self.step}: {self.learner} never answered within {limit:g} s (robot.hold.wait_s){last}; the "
                f"robot was held before its first action ({sealed} episodes are sealed): start the learner and "
                + resume
            )
        session.close(f"held: learner unreachable for {limit:g} s")
        raise StageError(
            f"{self.step}: the learner did not come back within robot.hold.wait_s {limit:g} s ({why}{last}); "
            f"{sealed} episodes are sealed: start the learner and {resume}"
        )


def release_robot(bridge, session: "HardwareSession") -> None:
    """Disconnect the robot (always, at any stop) and say so in the audit log."""
    if bridge.robot is None:
        return
    bridge.disconnect()
    session._log("robot-disconnected", session=session.session["id"])


def task_fields(r: dict, task: str) -> dict:
    """robot.config with robot.task_config's fields for `task` over it: that task's robot, wherever it is built."""
    return {**r["config"], **(r.get("task_config") or {}).get(task, {})}


def robot_config_for(c: dict, task: str) -> dict:
    """The fields of the robot's config for `task` (the rule any robot follows, a lab's arm included):
    robot.config, with robot.task_config's fields for that task over it; then, where the robot's config
    class has a `seed` field the workflow leaves unset, a seed per workflow seed, stage and phase (warmup,
    train, evaluate-all each see other scenes). accrue_sim also gets the task id and the session's faults."""
    import dataclasses

    from accrue.robot.robot_types import config_class

    r = c["robot"]
    config = task_fields(r, task)
    if r["type"] == "accrue_sim":
        config.update(task=task)
    cls = config_class("robot", r["type"], tuple(r.get("imports", ())), where="robot", type_key="type")
    if "seed" in {f.name for f in dataclasses.fields(cls)}:
        config.setdefault("seed", c["seed"] * 1000 + c["stage"] * 10 + {"warmup": 1, "train": 2}.get(c["phase"], 3))
    return config


def make_bridge(c: dict, settings: SessionSettings, task: str, report):
    """The robot of the workflow for `task` (robot_config_for) behind deadlines."""
    from accrue.robot.bridge import RobotBridge, Timeouts, robot_factory
    from accrue.robot.mapping import RobotMapping
    from accrue.robot.safety import ActionEnvelope, SafetyEnvelope

    r = c["robot"]
    config = robot_config_for(c, task)
    if r["type"] == "accrue_sim":
        config.update(settings.faults)
    return RobotBridge(
        robot_factory(r["type"], config, tuple(r.get("imports", ()))),
        RobotMapping.from_dict(r),
        Timeouts.from_dict(settings.timeouts),
        report=report,
        actions=ActionEnvelope.from_dict(r.get("safety")),
        safety=SafetyEnvelope.from_dict(r.get("safety")),
    )


def make_operator(settings: SessionSettings, bridge, console, *, store_root: Path | None = None, audit=None):
    """The workflow's operator. `bridge` is asked for the simulated robot's success when a label is due
    (anything with the bridge's hook(), so one operator can outlive several bridges); `audit(event,
    fields)` records each action of a terminal or page operator, `store_root` gives the page its token."""
    from accrue.robot.operator import ScriptedOperator, TerminalOperator

    name = settings.operator_name or os.environ.get("USER", "operator")
    if settings.operator == "page":
        from accrue.errors import AccrueError
        from accrue.robot.link_auth import store_token

        try:
            from accrue.robot.operator_page import PageOperator
        except ImportError as exc:
            raise AccrueError(f"robot.operator: page needs accrue.robot.operator_page ({exc})") from None
        if store_root is None:
            raise AccrueError("robot.operator: page needs the store (its link token is the page's token)")
        op = PageOperator(
            name,
            console=console,
            listen=settings.operator_page.get("listen", "127.0.0.1:0"),
            token=store_token(store_root),
            audit=audit,
        )
        # the token is never printed: it is the store's link token, read from its file
        console.print(f"operator page: {op.url} (token: {Path(store_root) / 'robot' / 'link-token'})")
        return op
    if settings.operator == "scripted":
        s = settings.scripted
        return ScriptedOperator(
            oracle=lambda: bool(bridge.hook("episode_success")()),
            name=settings.operator_name or "scripted",
            delay_s=float(s.get("delay_s", 0.0)),
            mistakes=set(s.get("mistakes", ())),
            corrects=set(s.get("corrects", ())),
            abort_before=s.get("abort_before"),
        )
    return TerminalOperator(name, console=console, audit=audit)  # every key audited, via=terminal


class HardwareSession:
    def __init__(self, ctx: StepContext, settings: SessionSettings):
        self.ctx, self.settings = ctx, settings
        c = ctx.config
        self.where = {"workflow": c["workflow"], "stage": c["stage"], "phase": c["phase"]}
        self.dir = ctx.scratch_dir("sealed")
        resume = ctx.last_checkpoint()
        if resume is not None:
            copy_tree(resume[0], self.dir)
        self.episodes: dict[int, dict] = {}
        for p in sorted((self.dir / EPISODES_DIR).glob("*/episode.json")):
            e = read_json(p)
            self.episodes[e["index"]] = e
        self.sessions: list[dict] = read_json(self.dir / SESSIONS_FILE) if (self.dir / SESSIONS_FILE).is_file() else []
        # the chain: this step's sessions since it last started from scratch (a --rerun starts a new one)
        self.chain = self.sessions[0]["chain"] if self.sessions else uuid.uuid4().hex[:16]
        self.where["chain"] = self.chain
        for s in self.sessions:
            if s["ended"] == "running":
                s["ended"] = "interrupted (process ended without closing the session)"
        self.in_progress: int | None = None  # the episode started and not yet sealed or discarded
        self._tracker = None  # opened at the first sealed episode (accrue.tracking)
        self._discard_unsealed()
        self.session = {
            "id": len(self.sessions) + 1,
            "chain": self.chain,
            "started": _now(),
            "last": _now(),
            "host": socket.gethostname(),
            "pid": os.getpid(),
            "operator": settings.operator_name or settings.operator,
            "episodes": 0,
            "robot_time_s": 0.0,
            "ended": "running",
        }
        self.sessions.append(self.session)
        self._log(
            "robot-session-started",
            session=self.session["id"],
            host=self.session["host"],
            operator=self.session["operator"],
            sealed=len(self.episodes),
        )
        self._save()  # the session is on record before its first episode starts
        if resume is not None:
            ctx.console.print(
                f"{ctx.step}: resumed with {len(self.episodes)} sealed episodes, "
                f"robot time {self.robot_time_s():.1f} s (session {self.session['id']})"
            )

    # ------------------------------------------------------------------ queries
    def ordered(self, phase: str | None = None) -> list[dict]:
        return [self.episodes[i] for i in sorted(self.episodes) if phase is None or self.episodes[i]["phase"] == phase]

    def robot_time_s(self) -> float:
        return float(sum(e["robot_time_s"] for e in self.episodes.values()))

    def next_index(self, base: int) -> int:
        used = list(self.episodes) + self._started_indices()
        return max([base - 1, *used]) + 1

    def arrays(self, index: int) -> dict:
        import numpy as np

        with np.load(self.dir / EPISODES_DIR / f"{index:06d}" / "transitions.npz") as z:
            return {k: z[k] for k in z.files}

    def window(self, size: int, phase: str = "train") -> tuple[int, int]:
        """(successes, episodes) over the last `size` episodes of `phase`."""
        last = self.ordered(phase)[-size:]
        return sum(bool(e["label"]["success"]) for e in last), len(last)

    # ------------------------------------------------------------------ sealing
    def seal_episode(self, index: int, record: dict, arrays: dict, mcap: Path | None) -> None:
        with StopSignals.critical():
            self._seal_episode(index, record, arrays, mcap)
        self.in_progress = None

    def _seal_episode(self, index: int, record: dict, arrays: dict, mcap: Path | None) -> None:
        import numpy as np

        d = self.dir / EPISODES_DIR / f"{index:06d}"
        d.mkdir(parents=True, exist_ok=True)
        np.savez(d / "transitions.npz", **arrays)
        if mcap is not None and mcap.is_file():
            shutil.copyfile(mcap, d / "episode.mcap")
        record = dict(record, index=index, session=self.session["id"], relabels=[])
        write_json(d / "episode.json", record)
        self.episodes[index] = record
        self.session["episodes"] += 1
        self.session["robot_time_s"] = round(self.session["robot_time_s"] + record["robot_time_s"], 6)
        cid = self._save()
        self._track(record)
        self._log(
            "robot-episode-sealed",
            index=index,
            success=record["label"]["success"],
            label_by=record["label"]["by"],
            label_at=record["label"]["at"],
            end=record["end"],
            faults=record["faults"] or None,
            robot_time_s=round(record["robot_time_s"], 3),
            limited_commands=record.get("limited_commands") or None,
            weights_version=record.get("weights_version"),
            interventions=record.get("interventions"),
            checkpoint=cid,
        )

    def intervention_window(self, phase: str | None = None, size: int | None = None) -> float:
        """Intervened control steps over all control steps of the last `size` (stop_window) episodes."""
        from accrue.robot.teleop import window_rate

        size = size or self.ctx.config.get("stop_window", 20)
        phase = phase or self.ctx.config["phase"]
        return window_rate([(e.get("interventions", 0), e["control_steps"]) for e in self.ordered(phase)], size)

    def _track(self, record: dict) -> None:
        """The episode's scalars for TensorBoard / W&B (accrue.tracking; never raises once open)."""
        from accrue.tracking import open_tracker, run_name, tracking_dir

        c = self.ctx.config
        if self._tracker is None:
            name = run_name(c["workflow"], c["stage"], self.ctx.step)
            self._tracker = open_tracker(self.settings.tracking, tracking_dir(self.ctx.store.root, name), name)
        succ, n = self.window(c.get("stop_window", 20), c["phase"])
        values = {
            "robot/success": float(bool(record["label"]["success"])),
            "robot/success_window": succ / n if n else 0.0,
            "robot/robot_time_s": self.robot_time_s(),
            "robot/episode_steps": float(record["control_steps"]),
        }
        if "interventions" in record:
            values |= {
                "robot/interventions": float(record["interventions"]),
                "robot/intervention_rate_window": self.intervention_window(),
            }
        if record.get("weights_version") is not None:
            values["learner/version"] = float(record["weights_version"])
        self._tracker.scalars(values, int(record["index"]))
        self._tracker.flush()

    def relabel(self, index: int, label: dict, gamma: float) -> dict:
        with StopSignals.critical():
            return self._relabel(index, label, gamma)

    def _relabel(self, index: int, label: dict, gamma: float) -> dict:
        import numpy as np

        from accrue.robot.episode import relabelled

        e = self.episodes[index]
        arrays = relabelled(self.arrays(index), bool(label["success"]), gamma)
        d = self.dir / EPISODES_DIR / f"{index:06d}"
        np.savez(d / "transitions.npz", **arrays)
        e["relabels"] = e.get("relabels", []) + [e["label"]]
        e["label"] = label
        write_json(d / "episode.json", e)
        cid = self._save()
        self._log(
            "robot-episode-relabelled",
            index=index,
            success=label["success"],
            label_by=label["by"],
            label_at=label["at"],
            was=e["relabels"][-1]["success"],
            checkpoint=cid,
        )
        return arrays

    def seal_learner(self, snapshot: Path) -> None:
        with StopSignals.critical():
            self._seal_learner(snapshot)

    def _seal_learner(self, snapshot: Path) -> None:
        if (self.dir / "learner").exists():
            shutil.rmtree(self.dir / "learner")
        copy_tree(snapshot / "learner", self.dir / "learner")
        shutil.copyfile(snapshot / "learner.json", self.dir / "learner.json")
        info = read_json(self.dir / "learner.json")
        cid = self._save()
        self._log("robot-learner-checkpoint", updates=info["updates"], version=info["version"], checkpoint=cid)

    def close(self, how: str) -> None:
        if self._tracker is not None:
            self._tracker.close()
        with StopSignals.critical():
            self.session["ended"] = how
            self._save()
            self._log(
                "robot-session-ended",
                session=self.session["id"],
                how=how,
                episodes=self.session["episodes"],
                robot_time_s=round(self.session["robot_time_s"], 3),
            )

    def started(self, index: int) -> None:
        self._log("robot-episode-started", index=index, session=self.session["id"])
        self.in_progress = index

    def discard(self, index: int, why: str) -> None:
        self._log("robot-episode-discarded", index=index, reason=why)
        if self.in_progress == index:
            self.in_progress = None

    def stopped(self, stop: SessionStop) -> SessionStop:
        """Ctrl-C or SIGTERM: the episode in progress is discarded (as at a kill), the session closed with
        how it was stopped; the SessionStop to raise carries the one line to print."""
        with StopSignals.critical():
            index, dropped = self.in_progress, ""
            if index is not None:
                self.discard(index, f"{stop.how}: in progress, not sealed, so not counted")
                dropped = f"episode {index} discarded, "
            if self.session["ended"] == "running":
                self.close(stop.how)
        return SessionStop(
            f"{self.ctx.step}: {stop.how}{' (forced)' if stop.forced else ''}; {dropped}{len(self.episodes)} "
            f"episodes sealed (resume with `accrue stage run ... --step {self.ctx.step} --continue`)",
            stop.how,
            stop.code,
            stop.forced,
        )

    # ------------------------------------------------------------------ internals
    def _save(self) -> str:
        self.session["last"] = _now()
        write_json(self.dir / SESSIONS_FILE, self.sessions)
        c = self.ctx.config
        succ, n = (
            self.window(c.get("stop_window", 20))
            if c["phase"] == "train"
            else (sum(bool(e["label"]["success"]) for e in self.episodes.values()), len(self.episodes))
        )
        progress = {
            "episodes": len(self.episodes),
            "success": f"{succ}/{n}",
            "robot_time_s": round(self.robot_time_s(), 1),
            "session": self.session["id"],
        }
        if (self.dir / "learner.json").is_file():
            progress["updates"] = read_json(self.dir / "learner.json")["updates"]
        return self.ctx.save_checkpoint(self.dir, progress)

    def _log(self, event: str, **fields: Any) -> None:
        self.ctx.log_event(event, **self.where, **fields)

    def audit(self, event: str, fields: dict) -> None:
        """An operator's action (the page operator's audit callback), under this session's workflow/stage."""
        self._log(event, session=self.session["id"], **fields)

    def _events(self, name: str) -> list[dict]:
        from artifacts.auditlog import iter_events

        return [
            e
            for e in iter_events(self.ctx.store)
            if e.get("event") == name
            and e.get("step") == self.ctx.step
            and all(e.get(k) == v for k, v in self.where.items())
        ]

    def _started_indices(self) -> list[int]:
        return [int(e["index"]) for e in self._events("robot-episode-started")]

    def _discard_unsealed(self) -> None:
        """Episodes started by an earlier session and never sealed died with it: say so, once each."""
        told = {int(e["index"]) for e in self._events("robot-episode-discarded")}
        for index in sorted(set(self._started_indices()) - set(self.episodes) - told):
            self.discard(index, "in progress when the session ended; not sealed, so not counted")
            self.ctx.console.print(
                f"{self.ctx.step}: episode {index} was in progress when the last session "
                "ended: discarded (it was never sealed)"
            )


def _now() -> str:
    import datetime as dt

    return dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds")


@dataclass
class EpisodeLoop:
    """What a run of operator-labelled episodes on one task needs (episode_loop).

    policy_now() -> (policy(s, ref, fresh) -> chunk, weights version or None), asked at each episode start
    (the actor acts with the newest weights it has); on_sealed(index, arrays, relabel) after each seal or
    re-label; between() before each episode; learner_state() adds the learner's version and health to the
    operator's view; a `hold` (train) stops the actor while the learner does not answer."""

    task: str
    done: Callable[[], bool]
    policy_now: Callable[[], tuple]
    reference: Callable
    features: Callable
    settings: Any  # accrue.robot.episode.EpisodeSettings
    gamma: float
    index_base: int
    metadata: dict
    on_sealed: Callable = lambda index, arrays, relabel=False: None
    between: Callable[[], None] = lambda: None
    learner_state: Callable[[], dict] = dict
    hold: LearnerHold | None = None
    classifier: Any = None  # robot.success_classifier (stages.steps.robot_classifier.ClassifierGate); None: off


def episode_loop(ctx: StepContext, session: HardwareSession, operator, bridge, loop: EpisodeLoop) -> None:
    """Operator-labelled episodes on loop.task until loop.done() says enough; each sealed at once.

    A robot fault ends the episode as a failure labelled by "system"; the robot is reconnected, or the
    step stops with one line (everything sealed stays). The operator is shown the live state
    (operator.show) at each episode's start and end and every SHOW_EVERY_S of robot time in between.
    With a `hold` (train), the actor stops acting when the learner has not answered for its staleness
    (checked at every chunk and before each episode) and waits for it (LearnerHold).
    With robot.intervention (warmup and train), the operator may take over through a teleoperator
    (accrue.robot.teleop): those control steps execute and store the teleop's action, are marked
    `intervention` in the sealed transitions (what the learner receives) and counted in episode.json."""
    from accrue.robot.bridge import RobotFault

    def lost(why: str):
        session.close(f"robot lost: {why}")
        raise StageError(
            f"robot not reachable ({why}); {len(session.episodes)} episodes are sealed: fix the robot "
            f"and resume with `accrue stage run ... --step {ctx.step} --continue`"
        )

    phase = ctx.config["phase"]
    take = None  # robot.intervention: the operator may take over (warmup and train; never in evaluation)
    if session.settings.intervention and phase in ("warmup", "train"):
        from accrue.robot.teleop import Intervention

        take = Intervention.from_dict(session.settings.intervention)  # a bad section: one line, robot untouched
    try:
        bridge.connect()
    except RobotFault as exc:
        if not bridge.reconnect():
            lost(str(exc))
    if loop.classifier is not None:  # the mapping is bound now: the classifier's columns of s
        loop.classifier.bind(bridge.mapping)
    if take is not None:
        take.connect(bridge.mapping)
        if hasattr(operator, "takeover_key"):
            operator.takeover_key = take.signal == "key"
    try:
        _episodes(ctx, session, operator, bridge, take, lost, loop)
    finally:
        if take is not None:
            take.close()


def _episodes(ctx, session, operator, bridge, take, lost, loop: EpisodeLoop) -> None:
    import tempfile

    from accrue.logs.mcap_episodes import EpisodeRecorder
    from accrue.robot.episode import intervention_count, intervention_rows, run_episode, transitions
    from accrue.robot.operator import Label, now_iso

    sealed = session.ordered()
    last = sealed[-1]["index"] if sealed else None
    logs = Path(tempfile.mkdtemp(dir=ctx.scratch_dir("mcap")))
    phase = ctx.config["phase"]
    chunk_s = loop.settings.horizon / loop.settings.control_hz  # robot time of one chunk
    live = {"index": None, "step": 0, "acted_s": 0.0, "shown_s": 0.0, "held": False}

    def show(**state) -> None:
        fn = getattr(operator, "show", None)  # an operator without a view has nothing to update
        if fn is None:
            return
        from accrue.errors import AccrueError

        frames = []
        if bridge.mapping.camera_keys and bridge.robot is not None:
            try:  # before the first observation there is no frame yet: show none rather than fail the episode
                frames = bridge.frames()
            except AccrueError:
                frames = []
        size = ctx.config.get("stop_window", session.settings.stop_window)  # train's is keyed; warmup's is not
        window = [bool(e["label"]["success"]) for e in session.ordered(phase)][-size:]
        taking = (
            {}
            if take is None
            else {
                "intervening": bool(take.active or take.toggled),
                "interventions": take.steps if live["index"] is not None else 0,
                "intervention_rate_window": round(session.intervention_window(), 4),
            }
        )
        fn(
            {
                "task": loop.task,
                "phase": phase,
                "episode": live["index"],
                "step": live["step"],
                "window": window,
                "window_size": size,
                "max_steps": loop.settings.max_steps,
                "robot_time_s": round(session.robot_time_s() + live["acted_s"], 2),
                "frame": frames[0] if frames else None,
                **loop.learner_state(),
                **taking,
                **state,
            }
        )

    def poll() -> str | None:
        command = operator.poll()
        live["step"] = min(live["step"] + loop.settings.horizon, loop.settings.max_steps)  # a chunk may be cut
        live["acted_s"] += chunk_s
        if live["acted_s"] - live["shown_s"] >= SHOW_EVERY_S - 1e-9:
            live["shown_s"] = live["acted_s"]
            show(status=f"episode {live['index']} running")
        if loop.hold is not None and command is None:
            loop.hold.acted(chunk_s)
            if loop.hold.due():
                live["held"] = True
                return "abort"  # ends the episode now; discarded below, not an operator's abort
        return command

    finished = False
    while not finished:
        if loop.done():  # the operator may still re-label the step's last episode (which may undo the stop rule)
            finished = _finish(session, operator, loop, last, show, phase)
            continue
        loop.between()
        if loop.done():
            continue
        if loop.hold is not None and loop.hold.due():
            loop.hold.wait(session, operator, show, ctx.console)
            continue
        index = session.next_index(loop.index_base)
        # the page shows the phase and the window at every reset prompt (the first one, after --continue)
        show(status=f"episode {index}: waiting for the scene to be reset")
        _answered(session, loop, last, operator.wait_reset(index, loop.task, last))
        reset_scene = bridge.hook("reset_scene")
        if reset_scene is not None:  # a simulated robot: the scene is put back when any operator says reset
            reset_scene()
        policy, version = loop.policy_now()
        session.started(index)
        live.update(index=index, step=0, acted_s=0.0, shown_s=0.0)
        show(status=f"episode {index} started")
        recorder = EpisodeRecorder(
            logs, control_hz=loop.settings.control_hz, state_names=list(bridge.mapping.state_keys)
        )
        meta = {**loop.metadata, "index": index, "weights_version": version, "session": session.session["id"]}
        out = run_episode(
            bridge, loop.settings, loop.reference, policy, loop.features, recorder, meta, poll=poll, intervene=take
        )
        live.update(step=out.control_steps, acted_s=0.0)
        if out.end == "abort" and live["held"]:
            live["held"] = False
            recorder.abort(0)
            session.discard(index, "the learner stopped answering: the robot was held, the episode not sealed")
            loop.hold.wait(session, operator, show, ctx.console)
            continue
        if out.end == "abort":
            recorder.abort(0)
            session.discard(index, "aborted by the operator")
            session.close("aborted by the operator")
            raise StageError(f"aborted by the operator; episode {index} discarded, {len(session.episodes)} sealed")
        if out.can_succeed:
            # the page shows the episode ended, with the steps it ran, while the operator labels it
            show(status=f"episode {index} ended ({out.end}, {out.control_steps} steps): label it")
            label, judged = _label(operator, bridge, loop, index, out)
            if label is None:
                recorder.abort(0)
                session.discard(index, "the operator aborted instead of labelling")
                session.close("aborted by the operator")
                raise StageError(f"aborted by the operator; episode {index} discarded, {len(session.episodes)} sealed")
        else:
            label, judged = Label(success=False, by="system", at=now_iso(), note=out.reason), None
            operator.tell(f"episode {index} ended: {out.reason} (not a success)")
        mcap = recorder.end(
            0,
            success=label.success,
            truncated=out.end == "time-limit",
            metadata={"label_by": label.by, "label_at": label.at, "end": out.end, "reason": out.reason},
        )
        arrays = transitions(out, label.success, loop.gamma, index)
        record = {
            "phase": ctx.config["phase"],
            "task": loop.task,
            "label": label.to_json(),
            "end": out.end,
            "reason": out.reason,
            "faults": out.faults,
            "control_steps": out.control_steps,
            "chunks": int(len(out.action)),
            "robot_time_s": out.robot_time_s,
            "limited_commands": out.limited,
            "wall_s": round(out.wall_s, 3),
            "weights_version": version,
            "ended_at": now_iso(),
        }
        if take is not None:  # control steps the teleop drove, and the chunk transitions they touched
            record.update(
                interventions=intervention_count(arrays), intervened_chunks=int(intervention_rows([arrays]).sum())
            )
        if judged is not None:
            record.update(judged)
        session.seal_episode(index, record, arrays, mcap)
        loop.on_sealed(index, arrays, relabel=False)
        last = index
        show(status=f"episode {index} sealed: {'success' if label.success else 'failure'} ({out.end})")
        if out.end == "fault":
            if not bridge.reconnect():
                lost(out.reason)
    recorder_dir = logs
    shutil.rmtree(recorder_dir, ignore_errors=True)


def _label(operator, bridge, loop: EpisodeLoop, index: int, out) -> tuple:
    """(the episode's Label, or None when the operator aborted; what its episode.json adds, or None): the
    operator's label, or robot.success_classifier's way (its proposal confirmed, or its label alone), with
    the simulator's own outcome recorded beside it where the robot reports one (the classifier's audit)."""
    summary = f"{out.end}, {out.control_steps} steps"
    if loop.classifier is None:
        return operator.label(index, summary), None
    oracle = bridge.hook("episode_success")
    extra = {} if oracle is None else {"sim_success": bool(oracle())}
    label, entry = loop.classifier.label(index, summary, out.s[-1], operator)
    return label, {"classifier": entry, **extra}


def _finish(session: HardwareSession, operator, loop: EpisodeLoop, last: int | None, show, phase: str) -> bool:
    """The step's episodes are all sealed: the operator's last chance to re-label the last one (which a reset
    prompt gives every other episode). True: the step ends; False: a re-label undid loop.done() (train's
    stop rule), so more episodes follow."""
    if last is None:
        return True
    n = len(session.ordered(phase))
    show(status=f"{phase}: {n} episodes sealed; r finishes the step, l re-labels episode {last} first")
    _answered(session, loop, last, operator.finish(f"{phase} ({loop.task}): {n} episodes sealed", last))
    return loop.done()


def _answered(session: HardwareSession, loop: EpisodeLoop, last: int | None, answer) -> None:
    """An operator's answer at a prompt between episodes (a ResetAnswer): its re-label of the last episode
    applied (and sent on, as a sealed one), or its abort ending the session in one line."""
    if answer.relabel is not None and last is not None:
        arrays = session.relabel(last, answer.relabel.to_json(), loop.gamma)
        loop.on_sealed(last, arrays, relabel=True)
    if not answer.go:
        session.close("aborted by the operator")
        raise StageError(
            f"aborted by the operator; {len(session.episodes)} episodes are sealed (resume with --continue)"
        )


def episodes_output(ctx: StepContext, session: HardwareSession, phase: str | None = None) -> Path:
    """The step's `episodes` output: every sealed episode (json + mcap, no transitions) and the sessions."""
    out = ctx.new_output("episodes", "episodes")
    for e in session.ordered(phase):
        src = session.dir / EPISODES_DIR / f"{e['index']:06d}"
        dst = out / f"{e['index']:06d}"
        dst.mkdir(parents=True)
        shutil.copyfile(src / "episode.json", dst / "episode.json")
        if (src / "episode.mcap").is_file():
            shutil.copyfile(src / "episode.mcap", dst / "episode.mcap")
    write_json(out / SESSIONS_FILE, session.sessions)
    return out
