"""`finetune-base`: π_base^k = π_base^{k-1} (or the workflow's starting policy) fine-tuned on D^1..D^k.

Inputs: `init` (the previous stage's base policy, or a given checkpoint; absent when starting from a
named from-scratch policy such as embedded-act) and `demos-1` .. `demos-k`. Earlier tasks keep the
workflow's demo-retention fraction of their episodes (paper Table VI); the current task keeps all.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

from artifacts.errors import StoreError
from artifacts.manifests import materialize, publish_artifact
from artifacts.refs import read_ref, set_ref
from stages.errors import StageError
from stages.runner_context import StepContext
from stages.runner_types import StepDef
from stages.steps.common import Progress, copy_tree, write_json

SCRIPTED_FILE = "scripted_reference.json"
TRAINING_SET_REFS = "cache/training-set"


class StoreTrainingSets:
    """Merged training sets as `training-set` artifacts, found by a ref named after what decides their
    bytes: the demonstrations' content ids (in order) and the fine-tune's key (retention, seed, ...)."""

    def __init__(self, ctx: StepContext, roles: tuple[str, ...]) -> None:
        self.ctx = ctx
        self.roles = roles

    def _ref(self, key: dict) -> str:
        demos = [self.ctx.input_manifest(role)["content"] for role in self.roles]
        text = json.dumps({"demos": demos, **key}, sort_keys=True)
        return f"{TRAINING_SET_REFS}/{hashlib.sha256(text.encode()).hexdigest()}"

    def find(self, key: dict) -> Path | None:
        oid = read_ref(self.ctx.store, self._ref(key))
        if oid is None:
            return None
        try:
            return materialize(self.ctx.store, oid, self.ctx.work_dir / "training-set", quarantine=True)
        except StoreError as exc:  # damaged: build it again (and move the ref to the new copy)
            self.ctx.console.print(f"[yellow]finetune-base: cached training set {oid[:12]} is damaged ({exc})[/]")
            return None

    def keep(self, key: dict, root: Path) -> None:
        oid = publish_artifact(
            self.ctx.store,
            root,
            "training-set",
            producer={"step": self.ctx.step},
            inputs={role: self.ctx.inputs[role] for role in self.roles},
            config=key,
            code_version=f"training-set-{key['format']}",
        )
        set_ref(self.ctx.store, self._ref(key), oid)


def demo_roles(stage: int) -> tuple[str, ...]:
    return tuple(f"demos-{i}" for i in range(1, stage + 1))


def run(ctx: StepContext) -> None:
    from accrue.policy import FinetuneSettings, finetune
    from accrue.scripted_reference import parse_spec

    c = ctx.config
    out = ctx.new_output("base-policy", "base-policy")
    init = ctx.input_path("init") if ctx.has_input("init") else c["init"]
    if not ctx.has_input("init") and parse_spec(c["init"]) is not None:  # stand-in: nothing to train
        write_json(out / SCRIPTED_FILE, {"known_bias": parse_spec(c["init"])})
        write_json(out / "accrue_base.json", {"stage": c["stage"], "finetuned": False, "scripted": True})
        return
    if ctx.has_input("init") and (init / SCRIPTED_FILE).is_file():
        copy_tree(init, out)
        write_json(out / "accrue_base.json", {"stage": c["stage"], "finetuned": False, "scripted": True})
        return
    if not c["finetune"]:
        if not ctx.has_input("init"):
            raise StageError(
                f"base_policy.finetune is false, so base_policy.init must name a checkpoint (got {c['init']!r})"
            )
        copy_tree(ctx.input_path("init"), out)
        write_json(out / "accrue_base.json", {"stage": c["stage"], "finetuned": False})
        return
    import torch

    roles = demo_roles(c["stage"])
    datasets = [ctx.input_path(role) for role in roles]
    settings = FinetuneSettings(
        steps=c["steps"],
        batch_size=c["batch_size"],
        lr=c["lr"],
        seed=c["seed"],
        retention=c["retention"],
        chunk_size=c["chunk_size"],
        device="cuda" if torch.cuda.is_available() else "cpu",
    )
    progress = Progress(ctx.console.print, "finetune-base")  # a line per fifth, with its rate and time left

    # the record names inputs by role, not by this attempt's paths: the step record maps roles to
    # artifact ids, and the bytes stay the same on every machine (content ids would not: recorded demos
    # differ between runs in the key order of lerobot's meta/stats.json alone)
    labels = ("input:init" if ctx.has_input("init") else str(init), [f"input:{role}" for role in roles])
    os.environ.setdefault("OMP_NUM_THREADS", "1")  # DataLoader workers, for training sets with cameras
    finetune(init, datasets, out, settings, progress, StoreTrainingSets(ctx, roles), labels)
    write_json(out / "accrue_base.json", {"stage": c["stage"], "finetuned": True, "tasks": c["tasks"]})


STEP = StepDef(
    name="finetune-base",
    code_version="finetune-base-2",
    run=run,
    optional_inputs=("init",),
    outputs={"base-policy": "base-policy"},
    description="base policy fine-tuned on the demos of tasks 1..k",
)
