"""What a remote holds, as this store last confirmed it: push checks every object the refs it names
reach, and this keeps that check cheap.

A remote of up to LIST_SMALL objects is listed on every push (two requests: a listing answers a
thousand keys a request), so an object deleted or truncated there is seen at once. A bigger one is listed in full
(a "full check") when the last one is older than ACCRUE_REMOTE_RECHECK seconds (a day by default)
or when `remote prune` has deleted anything since (it leaves a marker, PRUNED, on the remote);
otherwise only the objects not confirmed since that full check get a HEAD each, and what a push
uploads counts as confirmed. `verify --remote` is a full check too.

Kept in remotes/<name>/: present.json {"listed": time of the last full check, "count": objects then,
"pruned": the marker then} and, for a big remote only, present.ids (confirmed ids, one a line)."""

from __future__ import annotations

import os
import time

from artifacts.errors import StoreError
from artifacts.hashing import is_full_id
from artifacts.locks import store_lock
from artifacts.remotes.backends import Backend, object_key
from artifacts.remotes.pointers import HEAD_MAX, load_json, save_json, state_dir
from artifacts.remotes.transfer import parallel
from artifacts.store import Store

LIST_SMALL = 2_000  # up to this many objects (two listing requests) a remote is listed every push
PRUNED = "pruned"  # rewritten by every prune that deletes: a full check must follow


def recheck_s() -> float:
    raw = os.environ.get("ACCRUE_REMOTE_RECHECK", "86400")
    try:
        value = float(raw)
    except ValueError:
        value = -1.0
    if not 0 <= value < 1e9:
        raise StoreError(f"$ACCRUE_REMOTE_RECHECK={raw!r}: not a number of seconds")
    return value


class Presence:
    def __init__(self, store: Store, remote: str) -> None:
        self.store, self.remote = store, remote
        self.dir = state_dir(store, remote)
        self.meta = load_json(self.dir / "present.json")

    def _ids(self) -> set[str]:
        try:
            text = (self.dir / "present.ids").read_text()
        except FileNotFoundError:
            return set()
        return {line for line in text.split("\n") if is_full_id(line)}  # a line cut by a crash is skipped

    def _big(self) -> bool:
        return int(self.meta.get("count") or 0) > LIST_SMALL

    def check(self, backend: Backend, oids: list[str], jobs: int, fresh: bool = False) -> dict[str, int | None]:
        """Which of oids the remote holds: id -> its size there (None: confirmed earlier, size not
        asked again). fresh: the remote has no refs yet, so one listing is cheapest."""
        confirmed = self._ids() if self._big() else set()
        unconfirmed = [o for o in oids if o not in confirmed]
        marker = None
        listing = fresh or not self._big() or len(unconfirmed) > HEAD_MAX
        listing = listing or time.time() - float(self.meta.get("listed") or 0) > recheck_s()
        if not listing:
            marker = prune_marker(backend)  # before any listing: a prune after this read changes it again
            listing = marker != self.meta.get("pruned")
        if listing:
            if marker is None and self._big():
                marker = prune_marker(backend)
            held = backend.remote_object_ids()
            self.listed(held, marker)
            return {o: held[o] for o in oids if o in held}
        sizes = parallel(lambda o: backend.head(object_key(o)), unconfirmed, jobs)
        found = {o: s for o, s in zip(unconfirmed, sizes) if s is not None}
        self.confirm(list(found))
        return {**{o: None for o in oids if o in confirmed}, **found}

    def listed(self, held: dict[str, int], marker: str | None) -> None:
        """A full check found exactly held there (marker: the prune marker read before listing)."""
        was_big, known = self._big(), bool(self.meta)
        self.meta = {"listed": time.time(), "count": len(held), "pruned": marker}
        if known and not was_big and not self._big():
            return  # a small remote is listed every time: nothing to remember but that it is small
        with store_lock(self.store.locks_dir, f"remote-{self.remote}"):
            self.dir.mkdir(parents=True, exist_ok=True)
            ids = self.dir / "present.ids"
            if self._big():
                from artifacts.atomic import write_replace

                write_replace(ids, "".join(o + "\n" for o in sorted(held)).encode())
            else:
                ids.unlink(missing_ok=True)
            save_json(self.dir / "present.json", self.meta)

    def confirm(self, oids: list[str]) -> None:
        """These are there now (uploaded, or a HEAD found them)."""
        if not oids or not self._big():
            return
        with store_lock(self.store.locks_dir, f"remote-{self.remote}"):
            fd = os.open(self.dir / "present.ids", os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
            try:
                os.write(fd, "".join(o + "\n" for o in oids).encode())
            finally:
                os.close(fd)

    def forget(self, oids: list[str]) -> None:
        """These are damaged there: not confirmed until sent again."""
        if not oids or not self._big():
            return
        from artifacts.atomic import write_replace

        drop = set(oids)
        with store_lock(self.store.locks_dir, f"remote-{self.remote}"):
            keep = sorted(self._ids() - drop)
            write_replace(self.dir / "present.ids", "".join(o + "\n" for o in keep).encode())


def prune_marker(backend: Backend) -> str | None:
    raw = backend.get_bytes(PRUNED)
    return raw.decode(errors="replace").strip() if raw is not None else None


def mark_pruned(backend: Backend, note: str) -> None:
    """After a prune deleted objects: every store's next push does a full check."""
    import uuid

    backend.put_bytes(PRUNED, f"{note} {uuid.uuid4().hex}\n".encode())
