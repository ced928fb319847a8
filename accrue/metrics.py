"""The paper's continual metrics (Sec. V-A) from success curves, plus seed means and bootstrap CIs.

Input: c[i][j][e] = success rate of task j evaluated at grid point e of stage i (0-based, j ≤ i); an
earlier task's (j < i) entries may be None except at e_i*, the only point the metrics read of it (runs
that score earlier tasks at the chosen checkpoint alone: accrue.rl_loop.LoopSettings.full_curves).
    c_{i,i}   = max_e c[i][i][e]
    e_i*      = the earliest e attaining that maximum (ties → earliest)
    c_{i,j}   = c[i][j][e_i*]                         (j < i: prior task at stage i's chosen checkpoint)
    FWT_k     = mean_e c[k][k][e]
    NBT_k     = 1/(K−k) Σ_{m>k} (c_{k,k} − c_{m,k})      (k < K)
    AUC_k     = 1/(K−k+1) (FWT_k + Σ_{m>k} c_{m,k})
    FWT, AUC  averaged over all K stages; NBT over the first K−1
    ACC_final = 1/K Σ_k c_{K,k}            F_final = 1/(K−1) Σ_{k<K} (c_{k,k} − c_{K,k})
With K = 1, NBT and F_final are undefined and reported as None.

Transfer figures beside FWT (issue 18), each averaged over the K stages:
    FWT_no0   = mean_{e ≥ 1} c[k][k][e]     FWT without the step-0 point (None with a 1-point grid)
    jumpstart = c[k][k][0]                  success on the new task before any update of its stage
    T_thr     = the env steps of the first grid point with c[k][k][e] ≥ threshold; a stage that never
                gets there counts as its last grid point (its budget), so T_thr is then a lower bound
                (None without the grids)

Selection and report sets. With `report` curves (the same checkpoints scored on a disjoint set of
episodes), e_i* is still chosen on `curves` (the selection set) but every number above is read from
`report`, so the max over correlated checkpoints no longer scores itself. Without them both come from
one set, as in runs made before the split ("disjoint_report": False).
IQM (rliable's interquartile mean): the mean of the values left after dropping floor(n/4) from each end
of the sorted runs, with its own percentile bootstrap CI (`summarize_iqm`).
Confidence intervals: percentile bootstrap of the mean over runs (seeds, or orderings x seeds), 4000
resamples, 95%, numpy seed 0 (the Continual World procedure, at 95% rather than 90%); identical values
give a degenerate interval [v, v].

Runs over task orderings (paper Tables I/II: four orderings x four seeds): the metrics are defined per
run on stage positions, so runs whose task lists differ (permutations or different sequences) are
aggregated by their sequence-level numbers. `aggregate_runs` groups labelled runs by method: per method
the mean and CI over all its runs, and per ordering the same over that ordering's seeds.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from accrue.errors import AccrueError

SEC_VA_METRICS = ("FWT", "NBT", "AUC", "ACC_final", "F_final")  # the paper's (a single run's report)
METRICS = (*SEC_VA_METRICS, "FWT_no0", "jumpstart", "T_thr")
THRESHOLD = 0.5  # T_thr's default success threshold
BOOTSTRAP_RESAMPLES = 4000
CONFIDENCE = 0.95


def _check_curves(curves) -> list[list[list[float]]]:
    if not isinstance(curves, list) or not curves:
        raise AccrueError("curves: expected a non-empty list (one entry per stage)")
    n_points = None
    for i, stage in enumerate(curves):
        if not isinstance(stage, list) or len(stage) != i + 1:
            raise AccrueError(
                f"curves[{i}]: stage {i} must list tasks 0..{i} ({i + 1} curves), "
                f"got {len(stage) if isinstance(stage, list) else type(stage).__name__}"
            )
        for j, curve in enumerate(stage):
            if not isinstance(curve, list) or not curve:
                raise AccrueError(f"curves[{i}][{j}]: expected a non-empty list of success rates")
            if n_points is None:
                n_points = len(curve)
            if len(curve) != n_points:
                raise AccrueError(f"curves[{i}][{j}]: has {len(curve)} evaluation points, expected {n_points}")
            for e, v in enumerate(curve):
                if v is None and j < i:  # not scored there; success_matrix checks e_i* has a value
                    continue
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 <= v <= 1.0:
                    raise AccrueError(f"curves[{i}][{j}][{e}]: success rate must be a number in [0, 1], got {v!r}")
    return curves


def success_matrix(curves, report=None) -> tuple[np.ndarray, list[int]]:
    """c_{i,j} (K × K, NaN above the diagonal) and each stage's earliest maximising checkpoint e_i*,
    chosen on `curves`; the values are read from `report` when given (a disjoint episode set)."""
    curves = _check_curves(curves)
    values = curves if report is None else _check_report(curves, report)
    k = len(curves)
    c = np.full((k, k), np.nan)
    best = []
    for i in range(k):
        own = np.asarray(curves[i][i], dtype=float)
        e_star = int(np.argmax(own))  # argmax returns the first maximum: the earliest checkpoint
        best.append(e_star)
        for j in range(i + 1):
            if values[i][j][e_star] is None:
                raise AccrueError(
                    f"curves[{i}][{j}]: no success rate at stage {i}'s chosen checkpoint (point {e_star})"
                )
            c[i, j] = values[i][j][e_star]
    return c, best


def _check_report(curves, report):
    report = _check_curves(report)
    if len(report) != len(curves) or len(report[0][0]) != len(curves[0][0]):
        raise AccrueError(
            f"report curves: {len(report)} stages x {len(report[0][0])} points, but the selection curves "
            f"have {len(curves)} x {len(curves[0][0])}: both sets score the same checkpoints"
        )
    return report


def steps_to_threshold(curve, grid, threshold: float) -> tuple[float, bool]:
    """(env steps of the first grid point with success ≥ threshold, reached); unreached: (grid[-1], False)."""
    if len(grid) != len(curve):
        raise AccrueError(f"grid has {len(grid)} points but the curve {len(curve)}")
    for g, v in zip(grid, curve):
        if v >= threshold:
            return float(g), True
    return float(grid[-1]), False


def continual_metrics(curves, report=None, grids=None, threshold: float = THRESHOLD) -> dict:
    """FWT, NBT, AUC, ACC_final, F_final, FWT_no0, jumpstart and T_thr for one run (one seed), plus
    per-stage values and c_{i,j}. `report`: the same checkpoints on disjoint episodes (the values);
    `grids`: each stage's grid in env steps (for T_thr)."""
    c, best = success_matrix(curves, report)
    values = curves if report is None else report
    k = len(curves)
    own = [np.asarray(values[s][s], dtype=float) for s in range(k)]
    fwt = [float(np.mean(o)) for o in own]
    nbt = [float(np.mean([c[s, s] - c[m, s] for m in range(s + 1, k)])) for s in range(k - 1)]
    auc = [(fwt[s] + float(sum(c[m, s] for m in range(s + 1, k)))) / (k - s) for s in range(k)]
    fwt_no0 = [float(np.mean(o[1:])) for o in own] if len(own[0]) > 1 else None
    jumpstart = [float(o[0]) for o in own]
    if grids is not None and len(grids) != k:
        raise AccrueError(f"grids: {len(grids)} stage grids for {k} stages")
    reach = [steps_to_threshold(own[s], grids[s], threshold) for s in range(k)] if grids is not None else None
    out = {
        "FWT": float(np.mean(fwt)),
        "NBT": float(np.mean(nbt)) if nbt else None,
        "AUC": float(np.mean(auc)),
        "ACC_final": float(np.mean(c[k - 1, :])),
        "F_final": float(np.mean([c[s, s] - c[k - 1, s] for s in range(k - 1)])) if k > 1 else None,
        "FWT_no0": float(np.mean(fwt_no0)) if fwt_no0 is not None else None,
        "jumpstart": float(np.mean(jumpstart)),
        "T_thr": float(np.mean([r[0] for r in reach])) if reach is not None else None,
        "per_stage": {
            "FWT": fwt,
            "NBT": nbt,
            "AUC": auc,
            "FWT_no0": fwt_no0,
            "jumpstart": jumpstart,
            "T_thr": [r[0] for r in reach] if reach is not None else None,
            "T_thr_reached": [r[1] for r in reach] if reach is not None else None,
        },
        "threshold": threshold,
        "disjoint_report": report is not None,
        "c": [[None if np.isnan(v) else float(v) for v in row] for row in c],
        "best_checkpoint": best,
    }
    return out


def bootstrap_ci(
    values, resamples: int = BOOTSTRAP_RESAMPLES, confidence: float = CONFIDENCE, seed: int = 0
) -> tuple[float, float]:
    """Percentile bootstrap CI of the mean over runs (seeded: the same values give the same interval)."""
    v = np.asarray(values, dtype=float)
    if v.size == 0:
        raise AccrueError("bootstrap_ci: no values")
    if np.all(v == v[0]):  # one run, or identical runs: nothing to resample
        return float(v[0]), float(v[0])
    rng = np.random.default_rng(seed)
    means = v[rng.integers(0, v.size, size=(resamples, v.size))].mean(1)
    tail = (1 - confidence) / 2
    return float(np.quantile(means, tail)), float(np.quantile(means, 1 - tail))


def summarize_values(values) -> dict:
    """Mean and bootstrap CI of the defined values; None (an undefined metric) is counted, never averaged.
    {"mean", "ci_low", "ci_high", "n" (values used), "undefined" (None values)}; all None -> mean None."""
    defined = [float(v) for v in values if v is not None]
    undefined = len(values) - len(defined)
    if not defined:
        return {"mean": None, "ci_low": None, "ci_high": None, "n": 0, "undefined": undefined}
    lo, hi = bootstrap_ci(defined)
    # identical values: report the value itself (a float mean may differ from it in the last bit)
    mean = defined[0] if lo == hi == defined[0] else float(np.mean(defined))
    return {"mean": mean, "ci_low": lo, "ci_high": hi, "n": len(defined), "undefined": undefined}


def iqm(values) -> float:
    """Interquartile mean: the mean after dropping floor(n/4) values from each end of the sorted list
    (scipy.stats.trim_mean(values, 0.25), which rliable uses)."""
    v = np.sort(np.asarray(values, dtype=float))
    if v.size == 0:
        raise AccrueError("iqm: no values")
    cut = v.size // 4
    return float(np.mean(v[cut : v.size - cut]))


def summarize_iqm(values, resamples: int = BOOTSTRAP_RESAMPLES, confidence: float = CONFIDENCE, seed: int = 0) -> dict:
    """IQM of the defined values with a percentile bootstrap CI of the IQM (seeded), in summarize_values'
    shape: {"mean" (the IQM), "ci_low", "ci_high", "n", "undefined"}."""
    defined = [float(v) for v in values if v is not None]
    undefined = len(values) - len(defined)
    if not defined:
        return {"mean": None, "ci_low": None, "ci_high": None, "n": 0, "undefined": undefined}
    v = np.asarray(defined)
    if np.all(v == v[0]):
        return {"mean": defined[0], "ci_low": defined[0], "ci_high": defined[0], "n": v.size, "undefined": undefined}
    rng = np.random.default_rng(seed)
    samples = np.sort(v[rng.integers(0, v.size, size=(resamples, v.size))], axis=1)
    cut = v.size // 4
    stats = samples[:, cut : v.size - cut].mean(1)
    tail = (1 - confidence) / 2
    lo, hi = float(np.quantile(stats, tail)), float(np.quantile(stats, 1 - tail))
    return {"mean": iqm(defined), "ci_low": lo, "ci_high": hi, "n": int(v.size), "undefined": undefined}


def aggregate(runs: list) -> dict:
    """Metrics of each run (seed), and per metric the mean and the bootstrap CI over runs."""
    per_run = [continual_metrics(r) for r in runs]
    summary = {name: summarize_values([m[name] for m in per_run]) for name in METRICS}
    return {"metrics": summary, "runs": per_run, "confidence": CONFIDENCE, "resamples": BOOTSTRAP_RESAMPLES}


def ordering_label(tasks: list[str]) -> str:
    """The name of an unnamed ordering: its task ids in order."""
    return " → ".join(tasks)


def run_record(
    curves,
    *,
    method: str,
    tasks: list[str],
    ordering: str | None = None,
    seed: int | None = None,
    report=None,
    grids=None,
    threshold: float = THRESHOLD,
) -> dict:
    """One labelled run: its method, ordering (a name, else the task sequence), seed, tasks, and the
    Sec. V-A metrics of its curves ("metrics", plus "per_stage", "c", "best_checkpoint", and whether the
    values came from a disjoint report set); `report`, `grids`, `threshold` as in continual_metrics."""
    m = continual_metrics(curves, report, grids, threshold)
    if len(tasks) != len(m["c"]):
        raise AccrueError(f"run of {method}: {len(m['c'])} stages of curves but {len(tasks)} tasks")
    return {
        "method": method,
        "ordering": ordering or ordering_label(tasks),
        "seed": seed,
        "tasks": list(tasks),
        "metrics": {name: m[name] for name in METRICS},
        "per_stage": m["per_stage"],
        "c": m["c"],
        "best_checkpoint": m["best_checkpoint"],
        "disjoint_report": m["disjoint_report"],
    }


def aggregate_runs(records: list[dict]) -> dict:
    """Group labelled runs (run_record's dicts, or any dict with method, ordering, seed, tasks and
    metrics) by method, then by ordering, keeping first-appearance order:

        {"methods": [{"method", "runs", "metrics": {name: summarize_values(...)}, "iqm": {name: summarize_iqm(...)},
                      "orderings": [{"ordering", "tasks", "seeds", "runs", "metrics": {...}}]}],
         "confidence", "resamples", "bootstrap_seed"}

    A method's metrics are the mean and CI over all its runs (orderings x seeds, each run weighted
    alike, as in the paper's tables), and the IQM with its CI; an ordering's are over that ordering's runs.
    A metric a record lacks (a run stored before it existed) is undefined for it."""
    methods: dict[str, dict[str, list[dict]]] = {}
    tasks_of: dict[str, list[str]] = {}
    for r in records:
        known = tasks_of.setdefault(r["ordering"], list(r["tasks"]))
        if known != list(r["tasks"]):
            raise AccrueError(
                f"ordering {r['ordering']!r} names two task sequences: {ordering_label(known)} "
                f"and {ordering_label(r['tasks'])}"
            )
        methods.setdefault(r["method"], {}).setdefault(r["ordering"], []).append(r)
    out = []
    for method, orderings in methods.items():
        runs = [r for group in orderings.values() for r in group]
        out.append(
            {
                "method": method,
                "runs": len(runs),
                "metrics": {name: summarize_values([r["metrics"].get(name) for r in runs]) for name in METRICS},
                "iqm": {name: summarize_iqm([r["metrics"].get(name) for r in runs]) for name in METRICS},
                "orderings": [
                    {
                        "ordering": name,
                        "tasks": list(group[0]["tasks"]),
                        "seeds": [r["seed"] for r in group],
                        "runs": len(group),
                        "metrics": {m: summarize_values([r["metrics"].get(m) for r in group]) for m in METRICS},
                    }
                    for name, group in orderings.items()
                ],
            }
        )
    return {"methods": out, "confidence": CONFIDENCE, "resamples": BOOTSTRAP_RESAMPLES, "bootstrap_seed": 0}


def paired_differences(records: list[dict], reference: str, methods: list[str] | None = None) -> list[dict]:
    """Per method other than `reference`: per metric, the mean and bootstrap CI of (method − reference)
    over the runs both have for the same (ordering, seed) — paired, since such runs share their demos,
    base policies and evaluation episodes. [{"method", "pairs", "metrics": {name: summarize_values(...)}}];
    a method of `methods` without any pair keeps its row (pairs 0, every metric undefined)."""
    ref = {(r["ordering"], r["seed"]): r for r in records if r["method"] == reference}
    order = list(methods or []) + [r["method"] for r in records]
    out = []
    for method in dict.fromkeys(m for m in order if m != reference):  # `methods` first, then any other
        pairs = [
            (r, ref[(r["ordering"], r["seed"])])
            for r in records
            if r["method"] == method and (r["ordering"], r["seed"]) in ref
        ]
        metrics = {}
        for name in METRICS:
            diffs = [
                None
                if a["metrics"].get(name) is None or b["metrics"].get(name) is None
                else a["metrics"][name] - b["metrics"][name]
                for a, b in pairs
            ]
            metrics[name] = summarize_values(diffs)
        out.append({"method": method, "pairs": len(pairs), "metrics": metrics})
    return out


def load_metrics_file(path: str | Path) -> list[dict]:
    """Parse FILE.json: one run {"tasks", "grid", "curves"} or a list of them, each optionally labelled
    with "method", "ordering" and "seed". Runs may have different task lists (orderings). Returns one
    dict per run: {"method" (default "all"), "ordering" (default: the task sequence), "seed" (default:
    the run's index), "tasks", "grid", "curves"}; every problem is a one-line AccrueError."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise AccrueError(f"{path}: no such file") from None
    except json.JSONDecodeError as exc:
        raise AccrueError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno} column {exc.colno})") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise AccrueError(f"{path}: cannot read ({exc})") from None
    runs = data if isinstance(data, list) else [data]
    if not runs:
        raise AccrueError(f"{path}: empty list of runs")
    out = []
    for r, run in enumerate(runs):
        where = f"{path}: run {r}" if isinstance(data, list) else f"{path}"
        if not isinstance(run, dict):
            raise AccrueError(f"{where}: expected an object with tasks, grid, curves")
        for key in ("tasks", "grid", "curves"):
            if key not in run:
                raise AccrueError(f"{where}: missing field '{key}'")
        if not isinstance(run["tasks"], list) or not all(isinstance(t, str) for t in run["tasks"]):
            raise AccrueError(f"{where}: 'tasks' must be a list of names")
        if not isinstance(run["grid"], list) or not all(
            isinstance(g, (int, float)) and not isinstance(g, bool) for g in run["grid"]
        ):
            raise AccrueError(f"{where}: 'grid' must be a list of env-step counts")
        try:
            _check_curves(run["curves"])
        except AccrueError as exc:
            raise AccrueError(f"{where}: {exc}") from None
        if len(run["curves"]) != len(run["tasks"]):
            raise AccrueError(f"{where}: {len(run['curves'])} stages in 'curves' but {len(run['tasks'])} tasks")
        if len(run["curves"][0][0]) != len(run["grid"]):
            raise AccrueError(
                f"{where}: curves have {len(run['curves'][0][0])} points but 'grid' has {len(run['grid'])}"
            )
        for key in ("method", "ordering"):
            if key in run and (not isinstance(run[key], str) or not run[key]):
                raise AccrueError(f"{where}: '{key}' must be a non-empty name")
        seed = run.get("seed", r)
        if isinstance(seed, bool) or not isinstance(seed, int):
            raise AccrueError(f"{where}: 'seed' must be an integer")
        out.append(
            {
                "method": run.get("method", "all"),
                "ordering": run.get("ordering") or ordering_label(run["tasks"]),
                "seed": seed,
                "tasks": run["tasks"],
                "grid": run["grid"],
                "curves": run["curves"],
            }
        )
    return out
