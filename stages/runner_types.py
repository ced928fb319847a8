"""The runner's data types: step definitions, invocations, stage plans, results, cache keys.

The step-bodies package (stages/steps/, stages/plan.py) builds these; the runner executes them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib.metadata import PackageNotFoundError, version
from typing import TYPE_CHECKING, Any, Callable, Mapping, Union

from stages.errors import StageError

if TYPE_CHECKING:
    from stages.runner_context import StepContext

# The runner's vocabulary, in the order a stage runs them (DESIGN.md §1, paper Algorithm 1).
STEP_NAMES = ("finetune-base", "cache-teacher", "warmup", "train", "evaluate-all", "handoff")


def accrue_version() -> str:
    try:
        return version("accrue")
    except PackageNotFoundError:
        return "0+unknown"


@dataclass(frozen=True)
class StepDef:
    """What a step is. `run(ctx)` reads inputs and config from ctx and fills ctx.new_output(...).

    name          one of STEP_NAMES (tests may use other names)
    code_version  bump it when the body's behaviour changes: it is part of the cache key
    run           the body; it returns nothing, outputs are what it wrote via ctx.new_output
    inputs        the roles it requires (checked before the body runs); optional roles may be absent
    outputs       role -> artifact kind it must produce (checked when the body returns)
    """

    name: str
    code_version: str
    run: Callable[["StepContext"], None]
    inputs: tuple[str, ...] = ()
    optional_inputs: tuple[str, ...] = ()
    outputs: Mapping[str, str] = field(default_factory=dict)
    description: str = ""


@dataclass(frozen=True)
class FromStep:
    """Input wired to output `role` of an earlier step of the same plan."""

    step: str
    role: str


@dataclass(frozen=True)
class FromRef:
    """Input read from a ref when the step starts (then pinned by id), e.g. the previous stage's
    handoff `workflow/quick/stage/1/handoff:handoff`. Any `accrue show` spelling is accepted."""

    ref: str


InputSource = Union[str, FromStep, FromRef]  # a str is an artifact id (or unambiguous prefix)


@dataclass(frozen=True)
class StepInvocation:
    """One step to run: its definition, resolved JSON-able config and inputs by role."""

    step: StepDef
    config: Mapping[str, Any]
    inputs: Mapping[str, InputSource] = field(default_factory=dict)
    workflow: str | None = None  # labels: where the result's ref goes and what status shows
    stage: int | None = None


@dataclass(frozen=True)
class StagePlan:
    """The ordered steps of stage `stage` of a workflow (built by stages.plan.plan_stage)."""

    workflow: str
    stage: int
    steps: tuple[StepInvocation, ...]

    def names(self) -> list[str]:
        return [inv.step.name for inv in self.steps]


@dataclass(frozen=True)
class StepResult:
    step: str
    outputs: dict[str, str]  # role -> artifact id
    cached: bool
    record_id: str  # the committed step-record object
    cache_key: str
    attempt: int


def code_version_of(step: StepDef) -> str:
    """The step's own version plus accrue's package version — not the git commit, so unrelated
    commits do not invalidate caches."""
    return f"{step.code_version}+accrue-{accrue_version()}"


def cache_key(step: StepDef, config: Mapping[str, Any], inputs: Mapping[str, str]) -> str:
    from artifacts.hashing import hash_json
    from artifacts.store import STORE_FORMAT

    try:
        return hash_json(
            {
                "step": step.name,
                "config": dict(config),
                "inputs": dict(inputs),
                "code_version": code_version_of(step),
                "store_format": STORE_FORMAT,
            }
        )
    except (TypeError, ValueError) as exc:
        raise StageError(f"step {step.name}: config is not plain JSON ({exc})") from None
