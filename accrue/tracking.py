"""Scalars for people watching a run: TensorBoard event files, and W&B when a workflow asks for it.

    with open_tracker(wf.tracking, tracking_dir(store.root, name), name) as tracker:
        tracker.scalar("train/critic_loss", 0.37, step=120)
        tracker.scalars({"eval/success/task-a": 0.8, "eval/success/task-b": 0.6}, step=4000)

`spec` is a workflow's `tracking:` section (stages.workflow.TrackingSpec), a plain dict of the same
fields, or None for the defaults (TensorBoard on, W&B off). Event files hold wall times and host names,
so they are never artifacts: they go under the store's log directory (`<store>/log/tracking/<run>/`,
beside the audit log, outside the content-addressed objects) and nothing written here enters a cache key.
A tracker never raises once open: a sink that fails to open or to write says so in one warning line and
is dropped, so tracking cannot end a training step or a robot session. See docs/TRACKING.md.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any, Callable, Mapping

# the defaults and choices of a workflow's `tracking:` section; stages.workflow's TrackingSpec/WandbSpec
# take theirs from here, so a plain dict given to settings_of() and a validated workflow agree
DEFAULT_TENSORBOARD = True
DEFAULT_EVERY = 20  # learner updates between two loss/Q points (TrackingSpec.every)
WANDB_MODES = ("offline", "online")
WANDB_DEFAULTS = {"project": "accrue", "mode": "offline", "entity": None}


def run_name(workflow: str, stage: int, step: str) -> str:
    """The run a step's scalars belong to: one TensorBoard run per workflow stage step."""
    return f"{workflow}/stage-{stage}/{step}"


def tracking_dir(store_root: Path | str, name: str) -> Path:
    """Where the event files of run `name` go: under the store's log directory, never its objects."""
    return Path(store_root) / "log" / "tracking" / name


def _warn_stderr(line: str) -> None:
    print(f"warning: {line}", file=sys.stderr, flush=True)


def settings_of(spec: Any) -> dict:
    """The tracking section as a dict with every field (None, a dict, or a pydantic model)."""
    if spec is None:
        data: dict = {}
    elif hasattr(spec, "model_dump"):
        data = spec.model_dump()
    elif isinstance(spec, Mapping):
        data = dict(spec)
    else:
        raise TypeError(f"tracking spec must be a mapping or None (got {type(spec).__name__})")
    wandb = data.get("wandb")
    if wandb is not None:
        wandb = {**WANDB_DEFAULTS, **dict(wandb)}
        if wandb["mode"] not in WANDB_MODES:
            raise ValueError(f"tracking.wandb.mode must be one of {', '.join(WANDB_MODES)} (got {wandb['mode']!r})")
    return {
        "tensorboard": bool(data.get("tensorboard", DEFAULT_TENSORBOARD)),
        "wandb": wandb,
        "every": int(data.get("every", DEFAULT_EVERY)),
    }


class _TensorBoard:
    name = "tensorboard"

    def __init__(self, log_dir: Path) -> None:
        from torch.utils.tensorboard import SummaryWriter

        log_dir.mkdir(parents=True, exist_ok=True)
        self._writer = SummaryWriter(log_dir=str(log_dir))

    def write(self, values: Mapping[str, float], step: int) -> None:
        for tag, value in values.items():
            self._writer.add_scalar(tag, value, step)

    def flush(self) -> None:
        self._writer.flush()

    def close(self) -> None:
        self._writer.close()


class _Wandb:
    name = "wandb"

    def __init__(self, log_dir: Path, run: str, settings: dict) -> None:
        import wandb

        log_dir.mkdir(parents=True, exist_ok=True)
        self._run = wandb.init(
            project=settings["project"],
            entity=settings["entity"],
            mode=settings["mode"],
            dir=str(log_dir),
            name=run,
            group=run.split("/", 1)[0],
            reinit="create_new",  # one process may hold a train step's run and a bench cell's at once
            settings=wandb.Settings(silent=True, console="off"),
        )
        # every tag is drawn against the step it was logged with (env steps, updates, episodes)
        self._run.define_metric("step")
        self._run.define_metric("*", step_metric="step")
        self.run_dir = Path(self._run.dir).parent

    def write(self, values: Mapping[str, float], step: int) -> None:
        self._run.log({**values, "step": step})

    def flush(self) -> None:
        pass

    def close(self) -> None:
        self._run.finish()


def _wandb_logged_in() -> bool:
    """An API key from WANDB_API_KEY or wandb's netrc entry (read locally, no network)."""
    import wandb

    try:
        return bool(wandb.api.api_key)
    except Exception:  # noqa: BLE001 - an unreadable netrc: let wandb.init say what is wrong
        return True


class Tracker:
    """scalar/scalars/flush/close; a sink that fails is dropped with one warning line, never an exception."""

    def __init__(self, sinks: list, log_dir: Path, name: str, every: int, warn: Callable[[str], None]) -> None:
        self._sinks = sinks
        self.log_dir = log_dir
        self.name = name
        self.every = every  # callers thin per-update scalars to one point in `every` updates
        self._warn = warn
        self._closed = False

    @property
    def enabled(self) -> bool:
        return bool(self._sinks) and not self._closed

    @property
    def sinks(self) -> list[str]:
        return [s.name for s in self._sinks]

    def due(self, updates: int) -> bool:
        """True on the updates whose per-update scalars are written (one in `every`)."""
        return self.enabled and updates % self.every == 0

    def scalar(self, tag: str, value: float, step: int) -> None:
        self.scalars({tag: value}, step)

    def scalars(self, values: Mapping[str, Any], step: int) -> None:
        if not self.enabled:
            return
        try:
            clean = {str(k): float(v) for k, v in values.items() if v is not None}
            clean = {k: v for k, v in clean.items() if math.isfinite(v)}
            step = int(step)
        except (TypeError, ValueError) as exc:
            self._warn(f"tracking {self.name}: scalars {sorted(values)} not written ({exc})")
            return
        if clean:
            self._each("write", clean, step)

    def flush(self) -> None:
        if self.enabled:
            self._each("flush")

    def close(self) -> None:
        if self._closed:
            return
        self._each("close")
        self._closed = True
        self._sinks = []

    def _each(self, method: str, *args: Any) -> None:
        for sink in list(self._sinks):
            try:
                getattr(sink, method)(*args)
            except Exception as exc:  # noqa: BLE001 - tracking must never end the step
                self._sinks.remove(sink)
                self._warn(
                    f"tracking {self.name}: {sink.name} stopped after a failed {method} "
                    f"({type(exc).__name__}: {str(exc).strip()[:200]}); the run goes on without it"
                )
                if method != "close":
                    try:
                        sink.close()
                    except Exception:  # noqa: BLE001 - already reported
                        pass

    def __enter__(self) -> "Tracker":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_tracker(
    spec: Any, log_dir: Path | str, run_name: str, *, warn: Callable[[str], None] | None = None
) -> Tracker:
    """A tracker writing run `run_name`'s scalars under log_dir (see the module docstring).

    Never raises for a sink that cannot open (one warning line each, e.g. W&B asked for but not
    installed); a malformed spec is a programming error (the workflow schema refuses it at load)."""
    warn = warn or _warn_stderr
    s = settings_of(spec)
    log_dir = Path(log_dir)
    sinks: list = []
    if s["tensorboard"]:
        try:
            sinks.append(_TensorBoard(log_dir))
        except ImportError:
            warn(
                "tracking: TensorBoard needs the tensorboard package (pip install tensorboard); not writing event files"
            )
        except Exception as exc:  # noqa: BLE001 - e.g. an unwritable log directory
            warn(f"tracking: cannot write TensorBoard event files under {log_dir} ({type(exc).__name__}: {exc})")
    if s["wandb"] is not None:
        try:
            import wandb  # noqa: F401 - only to tell a missing package from a failed init
        except ImportError:
            warn("tracking.wandb: wandb is not installed (pip install wandb); not logging to W&B")
        else:
            if s["wandb"]["mode"] == "online" and not _wandb_logged_in():  # else wandb.init would prompt
                warn(
                    "tracking.wandb: mode online needs a W&B login (`wandb login` or WANDB_API_KEY); not logging to W&B"
                )
                return Tracker(sinks, log_dir, run_name, s["every"], warn)
            try:
                sinks.append(_Wandb(log_dir, run_name, s["wandb"]))
            except Exception as exc:  # noqa: BLE001 - e.g. online without a network or login
                text = str(exc).strip().splitlines()
                warn(
                    f"tracking.wandb: cannot start an {s['wandb']['mode']} W&B run ({type(exc).__name__}: "
                    f"{text[0][:200] if text else ''}); not logging to W&B"
                )
    return Tracker(sinks, log_dir, run_name, s["every"], warn)
