"""The actor's side of the learner: a background thread that keeps the learner fed and the weights fresh.

The actor's control loop never waits on it: `latest()` returns the newest weights it has (or None),
`push()` only queues. The thread sends heartbeats; when the learner does not answer for `dead_after_s`
the loss is reported (once) and, for a learner this actor started itself, the process is started again
and re-initialised from the last sealed checkpoint and every sealed episode - so a killed learner loses
only the updates since its last checkpoint.

A restarted learner resumes from the newest checkpoint of this run (the one this link received, when it is
newer than what `init_payload` holds), so its update count continues; it numbers its weights above every
version this link has exposed (`version_floor` at Init), so a version names one set of weights per run.
Every call carries `auth.token`; a learner this actor starts itself gets it in its environment (an
ephemeral token when no `auth` is given). A learner that refuses this actor's token, or whose TLS
certificate the CA does not verify, is not "unreachable": the link reports it once, in one line saying
what to fix (event robot-link-refused-by-learner), keeps it in `refused` and raises it from `check()`,
and tries again only every REFUSED_RETRY_S. Refusals the learner reports in its Heartbeat answers are
reported here (event robot-link-refused), so they reach the actor's audit log.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path
from typing import Callable

from accrue.process_tmp import owned_tmpdir, sweep_dead
from accrue.robot.link_auth import TOKEN_ENV, LinkAuth
from accrue.robot.transport import PROTOCOL, LinkRefused, Peer, PeerDown, tar_dir, untar

TMP_PREFIX = "accrue-actor-"
REFUSED_RETRY_S = 5.0  # a refused link is tried again this seldom: the learner logs every refused call

__all__ = ["LearnerLink", "LinkRefused", "refusal_line", "sweep_dead_actor_dirs"]


def refusal_line(address: str | None, exc: LinkRefused, auth: LinkAuth) -> str:
    """What the operator does about a learner that refused this actor (its token, or TLS), in one line."""
    if exc.reason == "tls":
        ca = f"robot.link.tls.ca {auth.tls_ca}" if auth.tls_ca is not None else "robot.link.tls.ca"
        return (
            f"TLS with the learner at {address} failed ({exc}): {ca} must be the learner's --tls-cert (or "
            "the CA that signed it), and the learner must run with --tls-cert/--tls-key"
        )
    source = f" (from {auth.token_from})" if auth.token_from is not None else ""
    return (
        f"the learner at {address} refused this actor's link token{source}: start the learner with this "
        "token (`accrue robot token --out FILE` here, then --token-file FILE there) or set "
        "robot.link.token_file to the learner's token"
    )


def sweep_dead_actor_dirs() -> list[Path]:
    """Remove `accrue-actor-<pid>-*` dirs whose process is gone (a kill -9 skips every cleanup)."""
    return sweep_dead(TMP_PREFIX)


def learner_command(dead_after_s: float) -> list[str]:
    """The command line of a learner an actor starts on loopback (its token goes in the environment)."""
    return [
        sys.executable,
        "-m",
        "accrue.robot.learner_service",
        "--listen",
        "127.0.0.1:0",
        "--parent-pid",
        str(os.getpid()),
        "--orphan-after",
        str(max(10.0, 4 * dead_after_s)),
    ]


class SpareLearner:
    """This actor's own learner process, started ahead of the step that needs it (the robot's warmup starts
    the one train will use, so that its start-up - a torch import, tens of seconds on a busy machine - runs
    while the operator does warmup, not in train's robot time). A thread starts it and keeps it from taking
    itself for an orphan (Hello every few seconds) until a LearnerLink takes it (`take_spare`), or until
    `close()`, or the end of this process."""

    KEEP_S = 2.0

    def __init__(self, dead_after_s: float = 3.0, start_timeout_s: float = 120.0):
        self.auth = LinkAuth.ephemeral()
        self.proc: subprocess.Popen | None = None
        self.port: int | None = None
        self.error: str | None = None
        self.started = threading.Event()  # the port is known, or the start failed (error)
        self.taken = threading.Event()
        self.dead_after_s, self.start_timeout_s = dead_after_s, start_timeout_s
        self.thread = threading.Thread(target=self._run, name="spare-learner", daemon=True)

    def start(self) -> "SpareLearner":
        self.thread.start()
        return self

    def alive(self) -> bool:
        return self.error is None and (self.proc is None or self.proc.poll() is None)

    def _run(self) -> None:
        import select

        env = dict(os.environ, **{TOKEN_ENV: self.auth.token})  # never on the command line
        try:
            self.proc = subprocess.Popen(
                learner_command(self.dead_after_s), stdout=subprocess.PIPE, stderr=None, text=True, env=env
            )
            deadline, line = time.monotonic() + self.start_timeout_s, ""
            while time.monotonic() < deadline and not self.taken.is_set() and self.proc.poll() is None:
                if select.select([self.proc.stdout], [], [], 0.2)[0]:
                    line = self.proc.stdout.readline()
                    break
            if "port" not in line:
                self.error = f"learner process did not start (exit {self.proc.poll()})"
                return
            self.port = int(line.split("port")[1].split()[0])
            threading.Thread(target=self.proc.stdout.read, daemon=True).start()  # drain its later output
        except OSError as exc:
            self.error = f"learner process did not start ({exc.strerror})"
            return
        finally:
            self.started.set()
        peer = Peer(f"127.0.0.1:{self.port}", self.auth.token)
        try:
            while not self.taken.wait(self.KEEP_S):
                try:  # its orphan watch counts any call: this actor is alive and wants it
                    peer.call("Hello", {"protocol": PROTOCOL}, timeout=2.0)
                except Exception:  # noqa: BLE001 - a learner that died is found by the link that takes it
                    pass
        finally:
            peer.close()

    def close(self) -> None:
        """Stop the process (nobody took it)."""
        self.taken.set()
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.proc.kill()


_SPARE: list[SpareLearner] = []
_SPARE_LOCK = threading.Lock()
_AHEAD = {"on": False}  # `accrue run` / `stage run` turn it on: the robot's warmup then starts train's learner


def start_learner_ahead(on: bool = True) -> None:
    """Whether the robot's warmup starts the learner its train will take (prestart_learner) in this process:
    on for the commands that run warmup and then train in one process; off (the default) elsewhere, where no
    train may follow to take it."""
    _AHEAD["on"] = on


def learner_ahead() -> bool:
    return _AHEAD["on"]


def prestart_learner(dead_after_s: float = 3.0) -> SpareLearner:
    """Start this actor's next learner now, in the background (one at a time; an existing live one is kept)."""
    import atexit

    with _SPARE_LOCK:
        if _SPARE and _SPARE[0].alive():
            return _SPARE[0]
        if _SPARE:
            _SPARE.pop().close()
        spare = SpareLearner(dead_after_s).start()
        _SPARE.append(spare)
        if not getattr(prestart_learner, "registered", False):
            atexit.register(drop_spare)
            prestart_learner.registered = True
        return spare


def take_spare() -> SpareLearner | None:
    """The learner prestart_learner started, now this caller's (None when there is none, or it died)."""
    with _SPARE_LOCK:
        spare = _SPARE.pop() if _SPARE else None
    if spare is None:
        return None
    if not spare.alive():
        spare.close()
        return None
    return spare


def drop_spare() -> None:
    """Stop a spare learner nobody took (the end of the process, or a run that stops before train)."""
    with _SPARE_LOCK:
        spares, _SPARE[:] = list(_SPARE), []
    for spare in spares:
        spare.close()


class LearnerLink:
    def __init__(
        self,
        init_payload: Callable[[], tuple[dict, bytes]],
        sealed_episodes: Callable[[], list[tuple[dict, bytes]]],
        on_snapshot: Callable[[dict, Path], None],
        report: Callable[[str, dict], None],
        address: str | None = None,
        heartbeat_s: float = 0.5,
        dead_after_s: float = 3.0,
        start_timeout_s: float = 120.0,
        auth: LinkAuth | None = None,
        version_floor: int = -1,
    ):
        self.init_payload, self.sealed_episodes = init_payload, sealed_episodes
        self.on_snapshot, self.report = on_snapshot, report
        self.address, self.local = address, address is None
        self.heartbeat_s, self.dead_after_s, self.start_timeout_s = heartbeat_s, dead_after_s, start_timeout_s
        self.run_id = uuid.uuid4().hex
        self.auth = auth if auth is not None else LinkAuth.ephemeral()
        # the newest weights version the run used before this link (e.g. in episodes of an earlier session)
        self.version_floor = version_floor
        self.checkpoint: Path | None = None  # the newest checkpoint snapshot received
        self.weights_received_at: float | None = None
        self.last_heartbeat: float | None = None
        self.learner_pid: int | None = None
        self.refused_seen = 0  # refusals the current learner process has reported so far
        self.proc: subprocess.Popen | None = None
        self.peer: Peer | None = None
        self.ready = False
        self.version = -1
        self.updates = 0
        self.queue: list[tuple[dict, bytes]] = []
        self.lock = threading.Lock()
        # final_snapshot's Pull (the actor's thread) and the link thread's can answer at once: one takes
        self.take_lock = threading.Lock()
        self.stop = threading.Event()
        self.lost_reported = False
        # the learner refused this actor (its token or TLS): a LinkRefused with the operator's line, until
        # a call gets through; see check()
        self.refused: LinkRefused | None = None
        self.last_ok = time.monotonic()
        self.last_error: str | None = None  # why the last failed call failed (said when the actor gives up)
        # every weights snapshot received lands here; removed at close(), or at exit if close() never ran,
        # or by the next link on this machine when this process was killed (the pid is in the name)
        self.tmp, self._remove_tmp = owned_tmpdir(self, TMP_PREFIX)
        self.thread = threading.Thread(target=self._run, name="learner-link", daemon=True)

    # ------------------------------------------------------------------ the actor's calls (never block)
    def start(self) -> None:
        self.thread.start()

    def push(self, header: dict, blob: bytes) -> None:
        with self.lock:
            self.queue.append((dict(header, run_id=self.run_id), blob))

    def final_snapshot(self, wait_s: float = 15.0) -> bool:
        """At stage end: ask for the learner's current state once every queued episode is in (bounded)."""
        deadline = time.monotonic() + wait_s
        while time.monotonic() < deadline and (self.queue or not self.ready):
            time.sleep(0.05)
        if not self.ready or self.peer is None:
            return False
        try:
            h, blob = self.peer.call("Pull", {"have": self.version, "fresh": True, "wait_s": 10.0}, timeout=15.0)
        except Exception as exc:  # noqa: BLE001 - the last snapshot we hold is used instead
            self.report(f"learner: final pull failed ({exc}); using the last weights received", {})
            return False
        if h.get("version") is not None:
            self._take(h, blob)
        return True

    def close(self) -> None:
        self.stop.set()
        if self.thread.ident is not None:  # started (a link that failed before start() is closed too)
            self.thread.join(timeout=5)
        if self.local and self.proc is not None and self.proc.poll() is not None and not self.lost_reported:
            # died after the last heartbeat: still say so, the session's log must show it
            self.lost_reported = True
            self.report(
                f"learner process exited (code {self.proc.returncode}) before the session ended",
                {"event": "robot-learner-lost", "code": self.proc.returncode},
            )
        if self.peer is not None and self.local:
            try:
                self.peer.call("Shutdown", {}, timeout=2.0)
            except Exception:  # noqa: BLE001 - it may already be gone
                pass
        if self.proc is not None:
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=5)
        if self.peer is not None:
            self.peer.close()
        if not self.thread.is_alive():  # a thread still in a call could write into it afterwards
            self._remove_tmp()  # the caller has sealed what it keeps (session.seal_learner copies)

    # ------------------------------------------------------------------ the thread
    def _adopt(self) -> bool:
        """Take the learner this actor started ahead (prestart_learner), once it is up; False if none."""
        spare = take_spare()
        if spare is None:
            return False
        spare.started.wait(self.start_timeout_s)
        if spare.port is None or not spare.alive():
            spare.close()
            return False
        spare.taken.set()
        self.proc, self.auth, self.address = spare.proc, spare.auth, f"127.0.0.1:{spare.port}"
        self.report(
            f"learner process started (pid {self.proc.pid}, port {spare.port}, ahead of train)",
            {"event": "robot-learner-started", "pid": self.proc.pid, "port": spare.port},
        )
        return True

    def _spawn(self) -> None:
        import select

        if self.proc is None and self._adopt():
            return
        env = dict(os.environ, **{TOKEN_ENV: self.auth.token})  # never on the command line
        cmd = learner_command(self.dead_after_s)
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=None, text=True, env=env)
        deadline = time.monotonic() + self.start_timeout_s
        line = ""
        while time.monotonic() < deadline and not self.stop.is_set():
            ready, _, _ = select.select([self.proc.stdout], [], [], 0.2)
            if ready:
                line = self.proc.stdout.readline()
                break
            if self.proc.poll() is not None:
                break
        if "port" not in line:
            raise PeerDown(f"learner process did not start (exit {self.proc.poll()})")
        port = int(line.split("port")[1].split()[0])
        self.address = f"127.0.0.1:{port}"
        threading.Thread(target=self.proc.stdout.read, daemon=True).start()  # drain its later output
        self.report(
            f"learner process started (pid {self.proc.pid}, port {port})",
            {"event": "robot-learner-started", "pid": self.proc.pid, "port": port},
        )

    def _connect(self) -> None:
        if self.local and (self.proc is None or self.proc.poll() is not None):
            if self.proc is not None:
                self.report(
                    f"learner process exited (code {self.proc.returncode}); starting it again",
                    {"event": "robot-learner-lost", "code": self.proc.returncode},
                )
                self.lost_reported = True  # so that "learner is back" follows once it answers
            self.ready = False
            if self.peer is not None:
                self.peer.close()
                self.peer = None
            self._spawn()
        if self.peer is None:
            # a learner this actor started is on loopback: TLS only for one on another host
            self.peer = Peer(self.address, self.auth.token, tls_ca=None if self.local else self.auth.tls_ca)
        hello, _ = self.peer.call("Hello", {"protocol": PROTOCOL}, timeout=3.0)
        if hello.get("pid") != self.learner_pid:
            self.learner_pid, self.refused_seen = hello.get("pid"), 0
        if hello.get("run_id") != self.run_id:
            header, blob = self.resume_payload()
            floor = max(self.version, self.version_floor)
            self.peer.call("Init", dict(header, run_id=self.run_id, version_floor=floor), blob, timeout=120.0)
            sealed = self.sealed_episodes()
            with self.lock:  # everything sealed so far, then what is queued
                queued = [q for q in self.queue if not any(q[0]["index"] == s[0]["index"] for s in sealed)]
                self.queue = [(dict(h, run_id=self.run_id), b) for h, b in sealed] + queued
            # self.version stays: the actor acts with those weights until newer ones (above the floor) come
        self.ready = True
        self.refused = None
        if self.lost_reported:
            self.report("learner is back", {"event": "robot-learner-back"})
        self.lost_reported = False

    def resume_payload(self) -> tuple[dict, bytes]:
        """`init_payload()`, with the learner replaced by this link's newest checkpoint when that is newer
        (it may not be sealed yet): a restarted learner loses only the updates since that checkpoint."""
        header, blob = self.init_payload()
        if self.checkpoint is None:
            return header, blob
        d = untar(blob, Path(tempfile.mkdtemp(dir=self.tmp, prefix="init-")))
        try:
            info = json.loads((d / "init.json").read_text())
            ck = json.loads((self.checkpoint / "learner.json").read_text())
            if int(ck["updates"]) <= int(info["updates"]):
                return header, blob
            shutil.rmtree(d / "learner")
            shutil.copytree(self.checkpoint / "learner", d / "learner")
            info.update(updates=int(ck["updates"]), version=int(ck["version"]))
            (d / "init.json").write_text(json.dumps(info))
            return header, tar_dir(d)
        finally:
            shutil.rmtree(d, ignore_errors=True)

    def _take(self, h: dict, blob: bytes) -> None:
        with self.take_lock:
            if int(h["version"]) <= self.version:  # the other Pull brought these weights or newer ones first
                return
            d = untar(blob, self.tmp / f"v{h['version']}")
            self.version, self.updates = int(h["version"]), int(h["updates"])
            self.weights_received_at = time.monotonic()
            if h.get("checkpoint"):
                self.checkpoint = d
            self.on_snapshot(h, d)

    def check(self) -> None:
        """Raise the LinkRefused of a learner that refuses this actor (its token, or TLS): retrying with the
        same token and CA cannot succeed, so a caller waiting for the learner should stop here."""
        refused = self.refused
        if refused is not None:
            raise refused

    def healthy(self) -> bool:
        """The learner answered a heartbeat within dead_after_s."""
        return self.last_heartbeat is not None and time.monotonic() - self.last_heartbeat < self.dead_after_s

    def _refusals(self, hb: dict) -> None:
        """Report each call the learner refused since the last heartbeat (it keeps the newest few)."""
        total = int(hb.get("refused", 0))
        if total <= self.refused_seen:
            return
        new = [r for r in hb.get("refusals", []) if int(r["seq"]) > self.refused_seen]
        for r in new:
            self.report(
                f"learner at {self.address} refused {r['method']} from {r['peer']} at {r['at']}: "
                "no or wrong link token",
                {"event": "robot-link-refused", "peer": r["peer"], "method": r["method"], "at": r["at"]},
            )
        if total - self.refused_seen > len(new):
            missed = total - self.refused_seen - len(new)
            self.report(
                f"learner at {self.address} refused {missed} more call(s) without the link token",
                {"event": "robot-link-refused", "count": missed},
            )
        self.refused_seen = total

    def _run(self) -> None:
        while not self.stop.is_set():
            try:
                if not self.ready:
                    self._connect()
                hb, _ = self.peer.call("Heartbeat", {}, timeout=2.0)
                self.last_heartbeat = time.monotonic()
                self._refusals(hb)
                while self.queue and not self.stop.is_set():
                    with self.lock:
                        header, blob = self.queue[0]
                    self.peer.call("Episode", header, blob, timeout=10.0)
                    with self.lock:
                        self.queue.pop(0)
                h, blob = self.peer.call("Pull", {"have": self.version}, timeout=10.0)
                if h.get("version") is not None:
                    self._take(h, blob)
                self.last_ok = time.monotonic()
            except LinkRefused as exc:  # not a learner that is away: one that will not take this actor
                self.ready = False
                line = refusal_line(self.address, exc, self.auth)
                if self.refused is None or str(self.refused) != line:
                    self.refused = LinkRefused(line, exc.reason)
                    self.lost_reported = True  # "learner is back" follows if it takes this actor later
                    self.report(line, {"event": "robot-link-refused-by-learner", "reason": exc.reason})
                self.stop.wait(max(self.heartbeat_s, REFUSED_RETRY_S))
                continue
            except Exception as exc:  # noqa: BLE001 - any failure: the learner is unreachable for now
                self.ready = False
                self.last_error = str(exc)
                gone = time.monotonic() - self.last_ok
                if gone >= self.dead_after_s and not self.lost_reported and self.last_heartbeat is None:
                    self.lost_reported = True  # never answered: the actor holds before acting (LearnerHold)
                    self.report(
                        f"the learner{'' if self.local else f' at {self.address}'} has not answered yet ({exc})",
                        {"event": "robot-learner-lost", "error": str(exc)},
                    )
                elif gone >= self.dead_after_s and not self.lost_reported:
                    self.lost_reported = True
                    self.report(
                        f"learner unreachable for {gone:.1f} s ({exc}); the actor goes on with "
                        + (
                            f"weights v{self.version}, the newest it received"
                            if self.version >= 0  # -1: nothing received, not a version anyone acts with
                            else "the stage's starting weights (none received from the learner yet)"
                        ),
                        {"event": "robot-learner-lost", "error": str(exc)},
                    )
                time.sleep(min(self.heartbeat_s, 0.5))
                continue
            self.stop.wait(self.heartbeat_s)
