"""A spec's claims about its reference method, judged on the measured paired differences.

A claim (declared in the spec, usually a sentence of the paper) says the reference is lower or higher than
each of some methods on one metric, or not lower / not higher. Its evidence is the paired difference
d = method − reference over the (ordering, seed) pairs both ran, with its bootstrap CI [lo, hi]:

    reference_is   holds                          contradicted
    lower          lo > 0 (reference lower)       hi < 0 (reference higher)    otherwise: not resolved
    higher         hi < 0                         lo > 0                       otherwise: not resolved
    not-lower      unless contradicted            lo > 0 (reference lower)
    not-higher     unless contradicted            hi < 0 (reference higher)

A claim over several methods holds when it holds against each, is contradicted when it is contradicted
against any, and is otherwise not resolved. A comparison with fewer than MIN_PAIRS pairs is not judged
("too few pairs", or "no runs"), and leaves its claim not resolved.
"""

from __future__ import annotations

from dataclasses import dataclass

from stages.report.tables import fmt_ci, markdown_table

DIRECTIONS = ("lower", "higher", "not-lower", "not-higher")
HOLDS, CONTRADICTED, UNRESOLVED, NO_DATA = "holds", "contradicted", "not resolved", "no runs"
TOO_FEW = "too few pairs"
# a percentile bootstrap of two values is just their range: it says nothing about the spread, so a
# comparison is judged from this many pairs on
MIN_PAIRS = 3


@dataclass(frozen=True)
class Claim:
    text: str  # the claim in words (the paper's, where it is the paper's)
    metric: str  # one of TABLE_METRICS
    reference_is: str  # one of DIRECTIONS
    than: tuple[str, ...]  # the methods it is compared with
    reference: str | None = None  # the method it is about (None: the spec's reference)


def verdict(reference_is: str, lo: float | None, hi: float | None) -> str:
    """The verdict of one comparison from the CI [lo, hi] of d = method − reference."""
    if lo is None or hi is None:
        return NO_DATA
    reference_lower, reference_higher = lo > 0, hi < 0  # resolved by the CI
    if reference_is == "lower":
        return HOLDS if reference_lower else CONTRADICTED if reference_higher else UNRESOLVED
    if reference_is == "higher":
        return HOLDS if reference_higher else CONTRADICTED if reference_lower else UNRESOLVED
    if reference_is == "not-lower":
        return CONTRADICTED if reference_lower else HOLDS
    if reference_is == "not-higher":
        return CONTRADICTED if reference_higher else HOLDS
    raise ValueError(reference_is)


def combine(verdicts: list[str]) -> str:
    if CONTRADICTED in verdicts:
        return CONTRADICTED
    if verdicts and all(v == HOLDS for v in verdicts):
        return HOLDS
    return UNRESOLVED


def judge(claims: list[Claim], differences: list[dict]) -> list[dict]:
    """Each claim with its per-method evidence and overall verdict (JSON-able)."""
    by_method = {d["method"]: d for d in differences}
    out = []
    for c in claims:
        against = []
        for m in c.than:
            d = by_method.get(m)
            s = d["metrics"][c.metric] if d else {"mean": None, "ci_low": None, "ci_high": None, "n": 0}
            if s["n"] == 0:
                judged = NO_DATA
            elif s["n"] < MIN_PAIRS:
                judged = TOO_FEW
            else:
                judged = verdict(c.reference_is, s["ci_low"], s["ci_high"])
            against.append({"method": m, "pairs": s["n"], "difference": s, "verdict": judged})
        out.append(
            {
                "claim": c.text,
                "reference": c.reference,
                "metric": c.metric,
                "reference_is": c.reference_is,
                "verdict": combine([a["verdict"] for a in against]),
                "against": against,
            }
        )
    return out


def judge_against(claims: list[Claim], records: list[dict], reference: str | None, methods: list[str]) -> list[dict]:
    """Judge claims that may name references of their own: each on the paired differences from its
    reference (accrue.metrics.paired_differences over the runs' records), in the claims' order."""
    from accrue.metrics import paired_differences

    diffs: dict[str, list[dict]] = {}
    out = []
    for c in claims:
        ref = c.reference or reference
        if ref not in diffs:
            diffs[ref] = paired_differences(records, ref, methods)
        out.extend({**j, "reference": ref} for j in judge([c], diffs[ref]))
    return out


def claims_markdown(judged: list[dict], reference: str | None = None, what: str = "claim") -> str:
    rows = [
        [
            c["claim"] if i == 0 else "",
            f"{c.get('reference') or reference} {c['reference_is']} on {c['metric']}" if i == 0 else "",
            a["method"],
            fmt_ci(a["difference"], signed=True),
            a["verdict"],
            f"**{c['verdict']}**" if i == 0 else "",
        ]
        for c in judged
        for i, a in enumerate(c["against"])
    ]
    refs = {c.get("reference") or reference for c in judged}
    delta = f"Δ (vs − {refs.pop()}) [CI]" if len(refs) == 1 else "Δ (vs − reference) [CI]"
    return markdown_table([what, "test", "vs", delta, "verdict", f"{what} verdict"], rows)
