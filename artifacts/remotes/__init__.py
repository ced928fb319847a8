"""Remotes: share a store through object storage (S3 and compatibles) or a plain directory.

Everything is content-addressed, so sharing is copying the objects the other side lacks and then
moving refs carefully. A remote holds, under its URL:

    config                  {"format": 1, "hash": "blake3", "type": "accrue-remote"}
    objects/blake3/ab/cd…   the same write-once objects as a store (verified on every download)
    refs/<name…>            one id and a newline; moved by compare-and-swap only
    logs/<store id>         the id of the newest audit-log segment pushed by that store
    pushes/<store id>-…     a lease per push in progress (remote prune deletes nothing meanwhile)

Locally, `refs/remotes/<remote>/<name…>` records where this store last saw each remote ref (like
git's remote-tracking refs): they are ordinary refs, so gc keeps what they reach and verify checks
it; push and pull never send or receive that namespace. `remote-logs/<remote>/<store id>` refs
keep the audit-log segments pulled from other stores. `remotes/<remote>/` in the store root holds
the ids a partial pull left on the remote (promised), a cache of remote ref versions, and per ref
the id both sides last agreed on (base.json: push and pull fast-forward from it). A --force on a
ref both sides moved keeps the other side's id as `displaced/<ref>/<id12>`.
"""

TRACKING = "remotes"  # local refs/remotes/<remote>/<ref>
LOG_TRACKING = "remote-logs"  # local refs/remote-logs/<remote>/<store id>
RESERVED = (TRACKING + "/", LOG_TRACKING + "/")
