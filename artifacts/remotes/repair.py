"""remote repair: heal a damaged remote from this store. `verify --remote` finds every reachable
object the remote lacks, holds at the wrong size or (with full) holds corrupt; each one this
store has is re-sent, checked against its id on the way out, over the damaged copy."""

from __future__ import annotations

from dataclasses import dataclass, field

from artifacts.links import children
from artifacts.remotes.check import verify_remote
from artifacts.remotes.closure import bottom_up
from artifacts.remotes.config import get_remote
from artifacts.remotes.connect import open_backend
from artifacts.remotes.present import Presence
from artifacts.remotes.transfer import Meter, default_jobs, parallel
from artifacts.store import Store


@dataclass
class RepairReport:
    remote: str
    full: bool
    damaged: int = 0
    resent: list[str] = field(default_factory=list)
    bytes_sent: int = 0
    unhealed: list[str] = field(default_factory=list)  # damaged there, and not in this store either

    @property
    def ok(self) -> bool:
        return not self.unhealed

    def as_dict(self) -> dict:
        return {"ok": self.ok, **self.__dict__}


def repair_remote(
    store: Store, remote: str, full: bool = False, jobs: int | None = None, meter: Meter | None = None
) -> RepairReport:
    spec = get_remote(store, remote)
    jobs, meter = jobs or default_jobs(), meter or Meter()
    found = verify_remote(store, spec.name, full=full, jobs=jobs, meter=meter)
    report = RepairReport(remote=spec.name, full=full, damaged=len(found.damaged))
    here = [o for o in found.damaged if store.has_object(o)]
    report.unhealed = [o for o in found.damaged if o not in here]
    if not here:
        return report
    backend = open_backend(spec)
    sizes = {o: store.object_size(o) or 0 for o in here}
    meter.start(f"repair → {spec.name}", len(here), sum(sizes.values()))

    def send(oid: str) -> None:
        backend.upload_object(oid, store.object_path(oid), sizes[oid], replace=True)
        meter.advance(sizes[oid])

    # data first, then manifests bottom up: a reader never meets a manifest naming what is not back yet
    named = {o: [k for k, _ in children(o, store.read_json(o))] for o in here if o in found.manifests}
    try:
        parallel(send, [o for o in here if o not in named], jobs)
        for group in bottom_up(named):
            parallel(send, group, jobs)
    finally:
        meter.stop()
    report.resent, report.bytes_sent = here, sum(sizes.values())
    Presence(store, spec.name).confirm(here)
    return report
