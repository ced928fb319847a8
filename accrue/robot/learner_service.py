"""The asynchronous learner: a process that trains from the episodes the actor seals and serves weights.

    python -m accrue.robot.learner_service --listen 127.0.0.1:0 [--parent-pid PID]   (token: $ACCRUE_LINK_TOKEN)
    accrue robot learner --listen 0.0.0.0:50051 --tls-cert F --tls-key F --token-file F   (a GPU box)

It holds nothing durable: the actor (which owns the store) sends it everything at `Init` - the learner
to start from (the last sealed checkpoint), the warmup buffer, the prior memory and teacher targets - and
then every sealed episode (`Episode`, idempotent by index; a re-labelled episode replaces its rows). It
trains `utd` updates per chunk transition of the current task (like the simulated loop's one train_step
per chunk step), publishes a snapshot every `publish_every` updates and marks one as a checkpoint every
`checkpoint_every` updates; the actor pulls them (`Pull`). Started by an actor (--parent-pid), it exits
when that actor dies or stops calling for `orphan_after_s`; started by hand it waits for the next actor.

RPCs (accrue.robot.transport): Hello, Init, Episode, Pull, Heartbeat, Shutdown; each needs the link token.
A refused call is counted, printed (peer, method, time) and passed to `audit` (the store's audit log when
the learner has one); the actor also hears of refusals in every Heartbeat answer.

Tracking (accrue.tracking, docs/TRACKING.md): when `Init` carries a `tracking` section the learner writes
learner/<losses, q_mean>, learner/updates, learner/version, learner/episodes and
learner/intervention_transitions (rows of its buffer the operator drove; also in every Heartbeat answer)
against its update count, one point per `every` updates: under the actor's log directory when the actor
started it (same host); a learner started by hand writes under `--tracking-dir` (`accrue robot learner --store
DIR`: the store's log/tracking/<run>), and with neither keeps none - never into the working directory.

A re-initialised learner continues the run: it starts from the update count of the checkpoint it is sent
and numbers its weights above `version_floor` (the newest version the actor has seen), so one version
number never names two different weights within a run.
"""

from __future__ import annotations

import argparse
import collections
import datetime
import io
import json
import os
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Callable

from accrue.errors import AccrueError
from accrue.process_tmp import owned_tmpdir
from accrue.robot.link_auth import TOKEN_ENV, is_loopback, parse_address, read_token_file
from accrue.robot.transport import PROTOCOL, serve, tar_dir, untar

TMP_PREFIX = "accrue-learner-"

RECENT_REFUSALS = 50  # the refusals a Heartbeat answer carries (the count covers all of them)


def say(line: str) -> None:
    """One line to the learner's log. The actor that reads the spawned learner's stdout may be gone (a
    kill -9): then the line goes nowhere instead of ending the learner in a BrokenPipeError traceback."""
    try:
        print(line, flush=True)
    except BrokenPipeError:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # later writes, the interpreter's final flush too, go nowhere
        os.close(devnull)


def accrue_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("accrue")
    except PackageNotFoundError:
        return "0+unknown"


def episode_npz(arrays: dict) -> bytes:
    import numpy as np

    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def read_npz(blob: bytes) -> dict:
    import numpy as np

    with np.load(io.BytesIO(blob)) as z:
        return {k: z[k] for k in z.files}


class LearnerService:
    def __init__(
        self,
        orphan_after_s: float = 0.0,
        audit: Callable[[str, dict], None] | None = None,
        spawned: bool = False,
        tracking_root: Path | None = None,
    ):
        self.lock = threading.Lock()
        self.spawned = spawned  # started by its actor, on the actor's host: the actor's log dir is ours
        # a learner started by hand writes its runs here (--tracking-dir; `accrue robot learner --store DIR`:
        # the store's log/tracking); None: it keeps no scalars, and never writes into the working directory
        self.tracking_root = tracking_root
        self.tracker = None
        self.track_mark = 0
        self.run_id: str | None = None
        self.learner = None
        # received inits and served snapshots; removed at exit, or by the next learner if this one is killed
        self.tmp, self.remove_tmp = owned_tmpdir(self, TMP_PREFIX)
        self.episodes: dict[int, dict] = {}  # index -> transition arrays
        self.dirty = False  # episodes changed since the buffer was built
        self.intervened = 0  # transitions of the buffer the operator drove (its `intervention` column)
        self.updates = self.version = 0
        # version, updates, the newest checkpoint's version (this one's when it is one), tar: one tuple,
        # replaced whole, so that a Pull (on a server thread, without the lock) never sees a snapshot
        # without its checkpoint mark
        self.snapshot: tuple[int, int, int, bytes] | None = None
        self.checkpoint_version = -1  # the newest snapshot marked as a checkpoint
        self.want_snapshot = threading.Event()
        self.last_call = time.monotonic()
        self.orphan_after_s = orphan_after_s
        self.stop = threading.Event()
        self.busy = False
        self.last_publish = self.last_ckpt = None  # update counts at the last snapshot and checkpoint
        self.audit = audit
        self.refused = 0
        self.refusals: collections.deque[dict] = collections.deque(maxlen=RECENT_REFUSALS)
        self.refusal_lock = threading.Lock()

    def handlers(self) -> dict:
        return {
            "Hello": self.hello,
            "Init": self.init,
            "Episode": self.episode,
            "Pull": self.pull,
            "Heartbeat": self.heartbeat,
            "Shutdown": self.shutdown,
        }

    def on_refused(self, peer: str, method: str) -> None:
        """A call without the link token: counted, one line in this learner's log, the audit log."""
        at = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
        with self.refusal_lock:
            self.refused += 1
            entry = {"seq": self.refused, "peer": peer, "method": method, "at": at}
            self.refusals.append(entry)
        say(
            f"accrue robot learner: refused {method} from {peer} at {at}: no or wrong link token "
            f"({entry['seq']} refused so far)"
        )
        if self.audit is not None:
            self.audit("robot-link-refused", {"peer": peer, "method": method, "at": at, "by": "learner"})

    # ------------------------------------------------------------------ RPCs
    def hello(self, h: dict, blob: bytes):
        self.last_call = time.monotonic()
        if h.get("protocol") != PROTOCOL:
            raise RuntimeError(
                f"protocol mismatch: actor speaks {h.get('protocol')}, learner {PROTOCOL} "
                f"(accrue {accrue_version()}); run the same accrue version on both hosts"
            )
        return {
            "protocol": PROTOCOL,
            "accrue": accrue_version(),
            "run_id": self.run_id,
            "pid": os.getpid(),
            "updates": self.updates,
            "episodes": sorted(self.episodes),
        }, b""

    def init(self, h: dict, blob: bytes):
        import torch

        from accrue.learner import ReplayBuffer, load_learner

        self.last_call = time.monotonic()
        with self.lock:
            self.snapshot = None  # no Pull is answered with the previous Init's weights from here on
            d = untar(blob, Path(tempfile.mkdtemp(dir=self.tmp)))
            info = json.loads((d / "init.json").read_text())
            torch.set_num_threads(int(info.get("torch_threads", 1)))
            self.learner = load_learner(d / "learner", device=info.get("device", "cpu"))
            self.warm = ReplayBuffer.load(d / "warmup")
            self.prior = ReplayBuffer.load(d / "prior") if (d / "prior").is_dir() else None
            self.teacher = self.fresh_ref = None
            if (d / "teacher.safetensors").is_file():
                from safetensors.torch import load_file

                tensors = load_file(str(d / "teacher.safetensors"))
                self.teacher, self.fresh_ref = tensors["targets"], tensors.get("fresh_ref")
            self.info = info
            # the version floor keeps a restarted learner's versions above every one the run has used
            floor = int(h.get("version_floor", -1))
            self.updates, self.version = int(info["updates"]), max(int(info["version"]), floor)
            self.last_publish = self.last_ckpt = None
            self.episodes, self.dirty, self.snapshot, self.checkpoint_version = {}, True, None, -1
            self.buffer, self.intervened = None, 0
            self.run_id = h["run_id"]
            self._open_tracking(info.get("tracking"))
        return {"ok": True}, b""

    def _open_tracking(self, tracking: dict | None) -> None:
        """The learner's tracker for this Init (a re-Init closes the previous one). Never fails the Init."""
        from accrue.tracking import open_tracker

        self.close_tracking()
        if not tracking:
            return
        name = str(tracking.get("run_name") or "learner")
        if self.spawned and tracking.get("log_dir"):
            log_dir = Path(tracking["log_dir"])
        elif self.tracking_root is not None:
            log_dir = self.tracking_root / name
        else:
            say(
                "accrue robot learner: tracking off for this run (no --store or --tracking-dir: "
                "nothing is written into the working directory)"
            )
            return
        try:
            self.tracker = open_tracker(
                tracking.get("spec"), log_dir, name, warn=lambda line: say(f"accrue robot learner: {line}")
            )
        except (TypeError, ValueError) as exc:  # a spec the actor's schema let through: no tracking, one line
            say(f"accrue robot learner: tracking off ({exc})")
            return
        self.track_mark = self.updates // self.tracker.every
        if self.tracker.enabled:
            say(f"accrue robot learner: tracking {', '.join(self.tracker.sinks)} under {log_dir}")

    def close_tracking(self) -> None:
        if self.tracker is not None:
            self.tracker.close()
            self.tracker = None

    def _track(self, info: dict) -> None:
        """Losses and Q once per `every` updates, against the update count."""
        tracker = self.tracker
        if tracker is None or not info or self.updates // tracker.every <= self.track_mark:
            return
        self.track_mark = self.updates // tracker.every
        values = {f"learner/{key}": value for key, value in info.items()}
        values.update(
            {
                "learner/updates": self.updates,
                "learner/version": self.version,
                "learner/episodes": len(self.episodes),
                "learner/intervention_transitions": self.intervened,
            }
        )
        tracker.scalars(values, self.updates)

    def episode(self, h: dict, blob: bytes):
        self.last_call = time.monotonic()
        with self.lock:
            if h.get("run_id") != self.run_id:
                raise RuntimeError(f"episode of run {h.get('run_id')} but this learner serves {self.run_id}")
            new = int(h["index"]) not in self.episodes or h.get("relabel")
            if new:
                self.episodes[int(h["index"])] = read_npz(blob)
                self.dirty = True
        return {"ok": True, "episodes": len(self.episodes)}, b""

    def pull(self, h: dict, blob: bytes):
        self.last_call = time.monotonic()
        if h.get("fresh"):  # the actor wants the learner as it is now (stage end)
            self.want_snapshot.set()
            deadline = time.monotonic() + float(h.get("wait_s", 10.0))
            while self.want_snapshot.is_set() and time.monotonic() < deadline:
                time.sleep(0.02)
        snap, have = self.snapshot, int(h.get("have", -1))
        if snap is None or snap[0] <= have:
            return {"version": None, "updates": self.updates}, b""
        # a checkpoint the actor has not pulled was overtaken by newer weights: those are one too
        return {"version": snap[0], "updates": snap[1], "checkpoint": snap[2] > have}, snap[3]

    def heartbeat(self, h: dict, blob: bytes):
        self.last_call = time.monotonic()
        return {
            "run_id": self.run_id,
            "updates": self.updates,
            "version": self.version,
            "episodes": len(self.episodes),
            "intervention_transitions": self.intervened,
            "busy": self.busy,
            "refused": self.refused,
            "refusals": list(self.refusals),
        }, b""

    def shutdown(self, h: dict, blob: bytes):
        self.stop.set()
        return {"ok": True}, b""

    # ------------------------------------------------------------------ training
    def _rebuild(self):
        """B^k = the warmup rows + every episode's rows, in episode order (a re-label rewrites them)."""
        from accrue.robot.episode import replay_from_episodes

        self.buffer = replay_from_episodes(
            self.warm, [self.episodes[i] for i in sorted(self.episodes)], int(self.info["task_index"])
        )
        self.rl_rows = len(self.buffer) - len(self.warm)
        self.intervened = int(self.buffer.column("intervention").sum())

    def _snapshot(self, checkpoint: bool):
        from accrue.learner import save_learner

        d = Path(tempfile.mkdtemp(dir=self.tmp))
        save_learner(self.learner, d / "learner")
        (d / "learner.json").write_text(
            json.dumps({"updates": self.updates, "version": self.version + 1, "episodes": sorted(self.episodes)})
        )
        self.version += 1
        if checkpoint:
            self.checkpoint_version = self.version
        # published with its checkpoint mark in one assignment: a Pull answered in between would give the
        # actor a checkpoint unmarked, and the later snapshots (above the version it then holds) unmarked too
        self.snapshot = (self.version, self.updates, self.checkpoint_version, tar_dir(d))
        shutil.rmtree(d, ignore_errors=True)  # the tar is what is served

    def train_forever(self):
        while not self.stop.is_set():
            if self.learner is None:
                time.sleep(0.05)
                continue
            with self.lock:
                if self.dirty:
                    self._rebuild()
                    self.dirty = False
                if self.last_publish is None:
                    self.last_publish = self.last_ckpt = self.updates
                target = self.rl_rows * self.learner.cfg.utd
                work = self.updates < target and len(self.buffer) > 0
                if work:
                    self.busy = True
                    if self.fresh_ref is not None:
                        info = self.learner.train_step(self.buffer, self.prior, self.teacher, self.fresh_ref)
                    else:
                        info = self.learner.train_step(self.buffer, self.prior, self.teacher)
                    self.updates += self.learner.cfg.utd
                    self._track(info)
                    self.busy = False
                every, ck = int(self.info["publish_every"]), int(self.info["checkpoint_every"])
                checkpoint = self.updates - self.last_ckpt >= ck
                if (
                    self.updates - self.last_publish >= every
                    or checkpoint
                    or self.want_snapshot.is_set()
                    or self.snapshot is None
                ):
                    self._snapshot(checkpoint)
                    self.last_publish = self.updates
                    if checkpoint:
                        self.last_ckpt = self.updates
                    self.want_snapshot.clear()
            if not work:
                time.sleep(0.02)


def link_token(token_file: str | None) -> str:
    """The token from an inherited environment variable (an actor's own learner) or a 0600 file."""
    token = os.environ.pop(TOKEN_ENV, "")  # popped: nothing this process starts inherits it
    if token:
        return token
    if token_file:
        return read_token_file(token_file, "accrue robot learner --token-file")
    raise AccrueError(
        "accrue robot learner: no link token; give --store DIR (the actor's store, or a copy of its "
        "robot/link-token) or --token-file FILE"
    )


def check_listen(listen: str, tls: bool, insecure: bool, prog: str = "accrue robot learner") -> None:
    host, _ = parse_address(listen, f"{prog} --listen", allow_zero=True)
    if not is_loopback(host) and not tls and not insecure:
        raise AccrueError(
            f"{prog}: listening on {listen} without TLS sends the token and the weights in the clear; "
            "give --tls-cert/--tls-key (`accrue robot certs DIR --host NAME` makes a pair) or --insecure"
        )


def main(argv: list[str] | None = None, audit: Callable[[str, dict], None] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="accrue robot learner")
    parser.add_argument("--listen", default="127.0.0.1:0")
    parser.add_argument("--parent-pid", type=int, default=0)
    parser.add_argument("--orphan-after", type=float, default=10.0)
    parser.add_argument("--token-file", default=None)
    parser.add_argument("--tls-cert", default=None)
    parser.add_argument("--tls-key", default=None)
    parser.add_argument("--insecure", action="store_true")
    parser.add_argument("--tracking-dir", default=None, help="where a learner started by hand writes its scalars")
    args = parser.parse_args(argv)
    if (args.tls_cert is None) != (args.tls_key is None):
        raise AccrueError("accrue robot learner: give --tls-cert and --tls-key together")
    check_listen(args.listen, args.tls_cert is not None, args.insecure)
    token = link_token(args.token_file)

    # the port is bound (and a port in use refused) before the slow imports below
    service = LearnerService(
        args.orphan_after,
        audit=audit,
        spawned=bool(args.parent_pid),
        tracking_root=Path(args.tracking_dir).expanduser().absolute() if args.tracking_dir else None,
    )
    server, port = serve(
        service.handlers(),
        args.listen,
        token=token,
        tls_cert=args.tls_cert and Path(args.tls_cert),
        tls_key=args.tls_key and Path(args.tls_key),
        on_refused=service.on_refused,
    )
    import torch

    import accrue.learner  # noqa: F401

    # torch's optimisers import torch._dynamo on first use (tens of seconds on a busy CPU): pay it before
    # the port is announced, so that Init answers at once
    torch.optim.AdamW([torch.nn.Parameter(torch.zeros(1))])

    service.last_call = time.monotonic()  # the imports above are not the actor's silence
    say(f"accrue robot learner listening on port {port} (pid {os.getpid()})")
    trainer = threading.Thread(target=service.train_forever, daemon=True)
    trainer.start()
    silent = False
    while not service.stop.is_set():
        time.sleep(0.2)
        quiet = time.monotonic() - service.last_call > args.orphan_after
        if args.parent_pid and (os.getppid() != args.parent_pid or quiet):
            say("accrue robot learner: the actor that started it is gone; exiting")
            break
        if quiet != silent and service.run_id is not None:  # a standalone learner waits for its actor
            say(
                "accrue robot learner: "
                + (
                    f"no call from the actor for {args.orphan_after:g} s; waiting for it"
                    if quiet
                    else "the actor is back"
                )
            )
            silent = quiet
    server.stop(grace=0.5)
    with service.lock:  # the trainer thread writes under the lock
        service.close_tracking()
    service.remove_tmp()
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except AccrueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(2)
