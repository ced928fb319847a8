"""Bench specs: a base workflow and a grid of methods x task orderings x seeds, each cell an ordinary
workflow run under its own derived name.

    spec = load_spec(Path("workflows/bench/nist-small.yaml"))   # StageError, one line, on any mistake
    for cell in spec.cells: cell.name, cell.workflow (a validated stages.workflow.Workflow)

Spec fields (YAML):
    name         optional (default: the file stem); prefixes every cell's workflow name
    description  optional
    base         the base workflow file, relative to the spec file
    overrides    workflow overrides for every cell: nested mappings and/or dotted paths
                 ("budgets.env_steps: 6000"); mappings merge, other values replace, null removes
                 the key (back to the workflow default). Generic: any workflow or learner field.
    methods      name -> overrides of that method (same rules). `method:` defaults to the name when
                 the name is a workflow method (accrue, sequential, ...); the Table IV ablations are
                 methods here, e.g. `accrue-no-ref: {method: accrue, learner.ablation: no-reference}`.
                 A method may also give `resources:` (below) for its cells.
    orderings    name -> task list, or a list of task lists (named S1, S2, ...)
    seeds        list of seeds
    resources    per cell: {num_cpus: 1, num_gpus: 0 (fractions allowed), custom: {name: amount}}
    retries      extra tries of a failed cell (default 1)
    remote       optional: the store's remote (a name of `accrue remote list`) that cells on nodes without
                 the store use: each node runs on its own store, pulls lazily and pushes its results
                 (`accrue bench run --remote NAME` gives or overrides it)
    reference    optional method name the report compares the others against (default: accrue if present)
    claims       optional: the paper's claims about the reference, [{claim, metric, reference_is, than}]
    predictions  optional: what the spec predicts, declared (committed) before any of its cells ran:
                 [{prediction, metric, reference_is, than, reference (optional, default the spec's)}];
                 judged like claims (holds / contradicted / not resolved), each shown whichever way it goes
    success_threshold  optional: the success rate T_thr counts env steps to (default 0.5)

A cell's workflow = base + overrides + method overrides, then tasks = the ordering, seed = the seed,
name = "<spec>.<method>.<ordering>.s<seed>.<hash>" where <hash> is the first 8 hex digits of the
BLAKE3 of the cell's validated workflow (all fields but name and description): changing anything a
cell runs gives it a new name, so a finished cell is never confused with a changed one. Steps are
cached by content (the workflow name is not in any cache key), so cells that share a base policy's
fine-tune (same demos, settings, seed) share it through the store.
"""

from __future__ import annotations

import copy
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from accrue.metrics import THRESHOLD
from stages.bench.claims import DIRECTIONS, Claim
from stages.errors import StageError

_LABEL = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]{0,39}$")
GRID_FIELDS = ("name", "tasks", "seed")  # set by the grid, never by overrides
SPEC_FIELDS = (
    "name",
    "description",
    "base",
    "overrides",
    "methods",
    "orderings",
    "seeds",
    "resources",
    "retries",
    "remote",
    "reference",
    "claims",
    "predictions",
    "success_threshold",
)
CLAIM_FIELDS = ("claim", "metric", "reference_is", "than")
PREDICTION_FIELDS = ("prediction", "metric", "reference_is", "than")  # and optionally "reference"
RESOURCE_FIELDS = ("num_cpus", "num_gpus", "custom")
MAX_NAME = 64


@dataclass(frozen=True)
class Resources:
    num_cpus: float = 1.0
    num_gpus: float = 0.0
    custom: dict[str, float] = field(default_factory=dict)

    def ray_options(self) -> dict:
        opts: dict[str, Any] = {"num_cpus": self.num_cpus, "num_gpus": self.num_gpus}
        if self.custom:
            opts["resources"] = dict(self.custom)
        return opts


@dataclass(frozen=True)
class Cell:
    method: str
    ordering: str
    seed: int
    name: str  # the cell's workflow name (refs workflow/<name>/...)
    workflow: Any  # stages.workflow.Workflow
    resources: Resources

    @property
    def tasks(self) -> list[str]:
        return list(self.workflow.tasks)

    @property
    def label(self) -> str:
        return f"{self.method} · {self.ordering} · seed {self.seed}"


@dataclass(frozen=True)
class BenchSpec:
    path: Path
    name: str
    description: str
    base: Path
    methods: list[str]
    orderings: dict[str, list[str]]
    seeds: list[int]
    retries: int
    reference: str | None
    cells: list[Cell]
    claims: list[Claim] = field(default_factory=list)
    predictions: list[Claim] = field(default_factory=list)
    success_threshold: float = THRESHOLD
    remote: str | None = None

    def cell(self, method: str, ordering: str, seed: int) -> Cell:
        for c in self.cells:
            if (c.method, c.ordering, c.seed) == (method, ordering, seed):
                return c
        raise StageError(f"{self.path}: no cell {method}/{ordering}/seed {seed}")


def select_cells(
    spec: BenchSpec,
    methods: list[str] | None = None,
    orderings: list[str] | None = None,
    seeds: list[int] | None = None,
) -> list[Cell]:
    """The spec's cells restricted to these methods / orderings / seeds (None: all), in the spec's order.
    A part of the grid first (say seeds 0-1 of every method) and the rest later: the cells are the
    spec's own, so the later full run skips what the first one finished."""
    chosen = {"--methods": methods, "--orderings": orderings, "--seeds": seeds}
    grid = {"--methods": spec.methods, "--orderings": list(spec.orderings), "--seeds": spec.seeds}
    for flag, values in chosen.items():
        unknown = [v for v in values or [] if v not in grid[flag]]
        if unknown:
            raise StageError(
                f"{flag}: {', '.join(map(str, unknown))} not in {spec.path.name} "
                f"(it has {', '.join(map(str, grid[flag]))})"
            )
    return [
        c
        for c in spec.cells
        if (methods is None or c.method in methods)
        and (orderings is None or c.ordering in orderings)
        and (seeds is None or c.seed in seeds)
    ]


# ------------------------------------------------------------------------- overrides
def expand_dotted(mapping: dict, where: str) -> dict:
    """{"a.b": 1, "c": {"d.e": 2}} -> {"a": {"b": 1}, "c": {"d": {"e": 2}}} (merging shared prefixes)."""
    out: dict = {}
    for key, value in mapping.items():
        if not isinstance(key, str) or not key:
            raise StageError(f"{where}: override keys must be field names (got {key!r})")
        value = expand_dotted(value, f"{where}.{key}") if isinstance(value, dict) else value
        parts = key.split(".")
        if any(not p for p in parts):
            raise StageError(f"{where}: bad dotted path {key!r}")
        node = out
        for p in parts[:-1]:
            nxt = node.setdefault(p, {})
            if not isinstance(nxt, dict):
                raise StageError(f"{where}: {key} conflicts with another override of {p}")
            node = nxt
        last = parts[-1]
        if isinstance(node.get(last), dict) and isinstance(value, dict):
            node[last] = merge(node[last], value, where)
        else:
            node[last] = value
    return out


def merge(base: dict, overrides: dict, where: str, path: str = "") -> dict:
    """A copy of base with overrides applied: mappings merge, other values replace, None removes."""
    out = copy.deepcopy(base)
    for key, value in overrides.items():
        at = f"{path}.{key}" if path else key
        if value is None:
            out.pop(key, None)
        elif isinstance(value, dict) and key in out and out[key] is not None:
            if not isinstance(out[key], dict):
                raise StageError(
                    f"{where}: {at}: the base workflow's value is not a mapping (got {out[key]!r}); override it whole"
                )
            out[key] = merge(out[key], value, where, at)
        else:
            out[key] = copy.deepcopy(value)
    return out


# ------------------------------------------------------------------------- loading
def _read_yaml(path: Path, what: str) -> Any:
    import yaml

    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise StageError(f"{path}: no such {what}") from None
    except IsADirectoryError:
        raise StageError(f"{path}: is a directory, not a {what}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise StageError(f"{path}: cannot read ({exc.__class__.__name__})") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise StageError(f"{path}: YAML syntax error at {where}{problem}") from None


def _mapping(value: Any, where: str, allow_none: bool = True) -> dict:
    if value is None and allow_none:
        return {}
    if not isinstance(value, dict):
        raise StageError(f"{where}: expected a mapping (got {value!r})")
    return value


def _label(value: Any, where: str) -> str:
    if not isinstance(value, str) or not _LABEL.match(value):
        raise StageError(f"{where}: names must be letters, digits, '_' or '-', at most 40 (got {value!r})")
    return value


def _resources(value: Any, where: str, default: Resources | None = None) -> Resources:
    d = _mapping(value, where)
    unknown = sorted(set(d) - set(RESOURCE_FIELDS))
    if unknown:
        raise StageError(f"{where}.{unknown[0]}: unknown field (use {', '.join(RESOURCE_FIELDS)})")
    base = default or Resources()

    def number(key: str, positive: bool) -> float:
        v = d.get(key, getattr(base, key))
        if isinstance(v, bool) or not isinstance(v, (int, float)) or v < 0 or (positive and v == 0):
            raise StageError(
                f"{where}.{key}: must be a {'positive' if positive else 'non-negative'} number (got {v!r})"
            )
        return float(v)

    custom = _mapping(d.get("custom", base.custom), f"{where}.custom")
    for k, v in custom.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or v <= 0:
            raise StageError(f"{where}.custom.{k}: must be a positive number (got {v!r})")
    return Resources(number("num_cpus", True), number("num_gpus", False), {str(k): float(v) for k, v in custom.items()})


def _orderings(value: Any, where: str) -> dict[str, list[str]]:
    if isinstance(value, list):
        value = {f"S{i}": tasks for i, tasks in enumerate(value, 1)}
    d = _mapping(value, where, allow_none=False)
    out = {}
    for name, tasks in d.items():
        _label(name, f"{where}")
        if not isinstance(tasks, list) or not tasks or not all(isinstance(t, str) for t in tasks):
            raise StageError(f"{where}.{name}: expected a non-empty list of task ids (got {tasks!r})")
        out[name] = list(tasks)
    return out


def _check_tasks(orderings: dict[str, list[str]], where: str) -> None:
    from accrue.sim import list_tasks

    known = list_tasks()
    for name, tasks in orderings.items():
        for i, t in enumerate(tasks):
            if t not in known:
                raise StageError(f"{where}.{name}[{i}]: unknown task {t!r} (known: {', '.join(known)})")


def cell_name(spec_name: str, method: str, ordering: str, seed: int, wf_data: dict) -> str:
    from artifacts.hashing import hash_json

    # tracking (where scalars are written) changes no result: cells keep their names with it on or off
    digest = hash_json({k: v for k, v in wf_data.items() if k not in ("name", "description", "tracking")})[:8]
    label = f"{spec_name}.{method}.{ordering}.s{seed}"
    return f"{label[: MAX_NAME - 9]}.{digest}"


def load_spec(path: Path | str) -> BenchSpec:
    from stages.plan import check_workflow
    from stages.workflow import METHODS, parse_workflow

    path = Path(path)
    data = _read_yaml(path, "bench spec")
    src = str(path)
    if not isinstance(data, dict):
        raise StageError(f"{src}: expected a mapping of bench spec fields (got {type(data).__name__})")
    unknown = sorted(set(data) - set(SPEC_FIELDS))
    if unknown:
        raise StageError(f"{src}: {unknown[0]}: unknown field (a spec has {', '.join(SPEC_FIELDS)})")
    name = _label(data.get("name", path.stem), f"{src}: name")
    if "base" not in data or not isinstance(data["base"], str):
        raise StageError(f"{src}: base: required, the base workflow file relative to the spec")
    base = (path.parent / data["base"]).resolve() if not Path(data["base"]).is_absolute() else Path(data["base"])
    base_data = _read_yaml(base, "base workflow file")
    if not isinstance(base_data, dict):
        raise StageError(f"{base}: expected a mapping of workflow fields")
    overrides = expand_dotted(_mapping(data.get("overrides"), f"{src}: overrides"), f"{src}: overrides")
    for f in GRID_FIELDS:
        if f in overrides:
            raise StageError(f"{src}: overrides.{f}: set by the grid (orderings, seeds, cell names), not by overrides")
    methods_in = _mapping(data.get("methods"), f"{src}: methods")
    orderings = _orderings(data.get("orderings"), f"{src}: orderings")
    seeds = data.get("seeds")
    if not isinstance(seeds, list) or any(isinstance(s, bool) or not isinstance(s, int) or s < 0 for s in seeds):
        raise StageError(f"{src}: seeds: expected a list of non-negative integers (got {seeds!r})")
    if len(set(seeds)) != len(seeds):
        raise StageError(f"{src}: seeds: a seed appears twice (got {seeds!r})")
    empty = [k for k, v in (("methods", methods_in), ("orderings", orderings), ("seeds", seeds)) if not v]
    if empty:
        raise StageError(f"{src}: empty grid: {', '.join(empty)} has no entries")
    retries = data.get("retries", 1)
    if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
        raise StageError(f"{src}: retries: must be a non-negative integer (got {retries!r})")
    resources = _resources(data.get("resources"), f"{src}: resources")
    remote = data.get("remote")
    if remote is not None and (not isinstance(remote, str) or not remote.strip()):
        raise StageError(f"{src}: remote: expected the name of one of the store's remotes (got {remote!r})")
    _check_tasks(orderings, f"{src}: orderings")

    cells: list[Cell] = []
    method_names = []
    for method, raw in methods_in.items():
        where = f"{src}: methods.{_label(method, f'{src}: methods')}"
        m = expand_dotted(_mapping(raw, where), where)
        cell_resources = _resources(m.pop("resources", None), f"{where}.resources", resources)
        for f in GRID_FIELDS:
            if f in m:
                raise StageError(f"{where}.{f}: set by the grid (orderings, seeds, cell names), not by a method")
        if "method" not in m:
            if method not in METHODS:
                raise StageError(
                    f"{where}: unknown method {method!r}: name one of {', '.join(METHODS)}, or give "
                    f"`method:` for a variant (e.g. {{method: accrue, learner.ablation: no-reference}})"
                )
            m["method"] = method
        merged = merge(merge(base_data, overrides, f"{src}: overrides"), m, where)
        method_names.append(method)
        for ordering, tasks in orderings.items():
            for seed in seeds:
                cell_data = {**merged, "tasks": tasks, "seed": seed}
                source = f"{src} (method {method}, ordering {ordering}, seed {seed})"
                wf = parse_workflow({**cell_data, "name": "cell"}, source)
                dumped = wf.model_dump(mode="json")
                cname = cell_name(name, method, ordering, seed, dumped)
                wf = wf.model_copy(update={"name": cname})
                try:
                    check_workflow(wf)
                except StageError as exc:
                    raise StageError(f"{source}: {exc}") from None
                cells.append(Cell(method, ordering, seed, cname, wf, cell_resources))
    reference = data.get("reference", "accrue" if "accrue" in method_names else None)
    if reference is not None and reference not in method_names:
        raise StageError(
            f"{src}: reference: {reference!r} is not one of the spec's methods ({', '.join(method_names)})"
        )
    claims = _claims(data.get("claims"), f"{src}: claims", method_names, reference)
    predictions = _claims(data.get("predictions"), f"{src}: predictions", method_names, reference, "prediction")
    threshold = data.get("success_threshold", THRESHOLD)
    if isinstance(threshold, bool) or not isinstance(threshold, (int, float)) or not 0 < threshold <= 1:
        raise StageError(f"{src}: success_threshold: must be a success rate in (0, 1] (got {threshold!r})")
    return BenchSpec(
        path=path,
        name=name,
        description=str(data.get("description", "")),
        base=base,
        methods=method_names,
        orderings=orderings,
        seeds=list(seeds),
        retries=retries,
        reference=reference,
        cells=cells,
        claims=claims,
        predictions=predictions,
        success_threshold=float(threshold),
        remote=remote,
    )


def _claims(value: Any, where: str, methods: list[str], reference: str | None, kind: str = "claim") -> list[Claim]:
    """claims: [{claim: words, metric: NBT, reference_is: lower, than: [sequential, er]}, ...];
    predictions: the same with `prediction:` for the words and an optional `reference:` of their own."""
    from accrue.metrics import METRICS

    if value is None:
        return []
    if not isinstance(value, list):
        raise StageError(f"{where}: expected a list of {kind}s (got {type(value).__name__})")
    fields = CLAIM_FIELDS if kind == "claim" else PREDICTION_FIELDS
    out = []
    for i, raw in enumerate(value):
        at = f"{where}[{i}]"
        optional = {"reference"} if kind == "prediction" else set()
        if not isinstance(raw, dict) or not set(fields) <= set(raw) <= set(fields) | optional:
            extra = f" (and optionally {', '.join(sorted(optional))})" if optional else ""
            raise StageError(f"{at}: expected exactly the fields {', '.join(fields)}{extra}")
        ref = raw.get("reference", reference)
        if ref is None:
            raise StageError(f"{at}: a {kind} is about a reference method, and this spec has none")
        if ref not in methods:
            raise StageError(f"{at}.reference: {ref!r} is not one of the spec's methods ({', '.join(methods)})")
        if raw["metric"] not in METRICS:
            raise StageError(f"{at}.metric: {raw['metric']!r} is not one of {', '.join(METRICS)}")
        if raw["reference_is"] not in DIRECTIONS:
            raise StageError(f"{at}.reference_is: {raw['reference_is']!r} is not one of {', '.join(DIRECTIONS)}")
        than = raw["than"] if isinstance(raw["than"], list) else [raw["than"]]
        bad = [m for m in than if m not in methods or m == ref]
        if not than or bad:
            raise StageError(f"{at}.than: {bad or than!r}: name the spec's methods other than {ref}")
        out.append(Claim(str(raw[kind]), raw["metric"], raw["reference_is"], tuple(than), ref))
    return out


def workflow_data(cell: Cell) -> dict:
    """The cell's workflow as plain JSON (what a worker re-validates with parse_workflow)."""
    return cell.workflow.model_dump(mode="json")
