"""Push leases (restic's lock files, for the same race): a push puts pushes/<store id>-<pid>-<nonce>
on the remote and `remote prune` deletes nothing while one is live, because the push may have found
an old unreachable object present and be about to point a ref at it.

A lease names its holder (host, boot, pid and the process's start time) and is renewed every RENEW_S
while its push runs, so it expires by liveness, not by a fixed age: one not renewed for LEASE_S is
stale whatever host it came from, and one whose holder is provably gone (this host, same boot, that
pid no longer running, or running another program) is stale at once. Prune and push take stale
leases over (delete them); `accrue remote unlock` deletes stale ones, `--all` every one."""

from __future__ import annotations

import contextlib
import json
import os
import socket
import threading
import time
import uuid
from dataclasses import dataclass
from typing import Iterator

from artifacts.errors import StoreError
from artifacts.hashing import canonical_json
from artifacts.remotes.backends import Backend

PUSH_LEASES = "pushes"  # pushes/<store id>-<pid>-<nonce>: one per push in progress
LEASE_S = 900.0  # a lease not renewed for this long belongs to a push that is gone
RENEW_S = 60.0


def _boot_id() -> str | None:
    try:
        with open("/proc/sys/kernel/random/boot_id") as f:
            return f.read().strip() or None
    except OSError:
        return None


def _proc_start(pid: int) -> str | None:
    """The process's start time in clock ticks since boot (Linux): tells a reused pid apart."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            stat = f.read()
    except OSError:
        return None
    fields = stat[stat.rfind(b")") + 2 :].split()
    return fields[19].decode() if len(fields) > 19 else None


def lease_info(sid: str) -> dict:
    pid = os.getpid()
    return {
        "store": sid,
        "host": socket.gethostname(),
        "boot": _boot_id(),
        "pid": pid,
        "proc_start": _proc_start(pid),
        "started": time.time(),
    }


def holder_gone(info: dict) -> bool:
    """Provably gone: it ran on this host (same name and boot) and its pid is no longer that process.
    A holder on another host is never judged here (its lease expires, or `remote unlock --all`)."""
    if not isinstance(info, dict) or info.get("host") != socket.gethostname():
        return False
    boot = _boot_id()
    if info.get("boot") and boot and info["boot"] != boot:
        return True  # this host was restarted since
    pid = info.get("pid")
    if not isinstance(pid, int) or isinstance(pid, bool) or pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:
        pass  # alive, another user's
    start = info.get("proc_start")
    now = _proc_start(pid)
    return bool(start and now and start != now)  # the pid was reused by another process


@dataclass
class Lease:
    key: str
    info: dict
    age_s: float  # since it was last renewed (the remote's clock)
    state: str  # live | expired | gone

    def describe(self) -> str:
        who = f"host {self.info.get('host', '?')} pid {self.info.get('pid', '?')}"
        return f"{self.key} ({who}, renewed {self.age_s:.0f}s ago)"


def read_leases(backend: Backend) -> list[Lease]:
    now = time.time()
    out = []
    for key, (_size, mtime) in sorted(backend.list_aged(PUSH_LEASES).items()):
        raw = backend.get_bytes(key)
        if raw is None:
            continue  # its push ended meanwhile
        try:
            info = json.loads(raw)
        except ValueError:
            info = {}
        info = info if isinstance(info, dict) else {}
        age = max(0.0, now - mtime)
        state = "expired" if age >= LEASE_S else "gone" if holder_gone(info) else "live"
        out.append(Lease(key, info, age, state))
    return out


def take_over(backend: Backend, leases: list[Lease], every: bool = False) -> list[Lease]:
    """Delete the stale leases (with every: all of them); returns those deleted."""
    dropped = [lease for lease in leases if every or lease.state != "live"]
    for lease in dropped:
        backend.remove(lease.key)
    return dropped


@dataclass
class Held:
    """What a push learnt putting its lease: the stale leases it took over, and whether another push was
    live then."""

    taken: list[Lease]
    others_live: bool
    backend: Backend
    key: str

    def written_at(self) -> float | None:
        """When the lease was written, by the remote's clock (one listing; None if it cannot tell)."""
        found = self.backend.list_aged(PUSH_LEASES).get(self.key)
        return found[1] if found else None


@contextlib.contextmanager
def held_lease(backend: Backend, sid: str) -> Iterator[Held]:
    """A lease for the push inside, renewed every RENEW_S on a thread; stale leases met on the way in
    are taken over. Removed at the end; a killed push's goes stale by itself."""
    leases = read_leases(backend)
    taken = take_over(backend, leases)
    info = lease_info(sid)
    key = f"{PUSH_LEASES}/{sid}-{info['pid']}-{uuid.uuid4().hex[:8]}"
    body = canonical_json(info) + b"\n"
    backend.put_bytes(key, body)
    stop = threading.Event()

    def renew() -> None:
        while not stop.wait(RENEW_S):
            try:
                backend.put_bytes(key, body)
            except Exception:  # noqa: BLE001 - a missed renewal only lets the lease age; the push goes on
                pass

    renewer = threading.Thread(target=renew, name="accrue-lease", daemon=True)
    renewer.start()
    try:
        yield Held(taken, any(lease.state == "live" for lease in leases), backend, key)
    finally:
        stop.set()
        renewer.join()
        try:
            backend.remove(key)
        except StoreError:
            pass  # a stale lease only makes prune wait until it expires


def unlock_remote(store, remote: str, every: bool = False) -> tuple[list[Lease], list[Lease], list[str]]:
    """`accrue remote unlock`: delete the stale leases (every: all, and a directory remote's ref lock
    files too). Returns (deleted, kept live, ref lock files deleted)."""
    from artifacts.remotes.config import get_remote
    from artifacts.remotes.connect import open_backend
    from artifacts.remotes.pointers import check_remote_config

    backend = open_backend(get_remote(store, remote))
    check_remote_config(backend, create=False)
    leases = read_leases(backend)
    dropped = take_over(backend, leases, every)
    locks: list[str] = []
    if every and backend.spec.kind == "dir":
        locks = sorted(k for k in backend.list_sizes("locks") if k.endswith(".lock"))
        for key in locks:
            backend.remove(key)
    return dropped, [lease for lease in leases if lease not in dropped], locks
