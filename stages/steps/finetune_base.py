"""`finetune-base`: π_base^k = π_base^{k-1} (or the workflow's starting policy) fine-tuned on D^1..D^k.

Inputs: `init` (the previous stage's base policy, or a given checkpoint; absent when starting from a
named from-scratch policy such as embedded-act) and `demos-1` .. `demos-k`. Earlier tasks keep the
workflow's demo-retention fraction of their episodes (paper Table VI); the current task keeps all.
"""

from __future__ import annotations

import os

from stages.errors import StageError
from stages.runner_context import StepContext
from stages.runner_types import StepDef
from stages.steps.common import copy_tree, write_json

SCRIPTED_FILE = "scripted_reference.json"


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

    datasets = [ctx.input_path(role) for role in demo_roles(c["stage"])]
    settings = FinetuneSettings(
        steps=c["steps"],
        batch_size=c["batch_size"],
        lr=c["lr"],
        seed=c["seed"],
        retention=c["retention"],
        chunk_size=c["chunk_size"],
        device="cuda" if torch.cuda.is_available() else "cpu",
    )
    last = [0]

    def progress(step: int, total: int) -> None:
        if step - last[0] >= max(1, total // 5) or step == total:
            last[0] = step
            ctx.console.print(f"finetune-base: step {step}/{total}")

    # lerobot-train runs in a subprocess: one BLAS thread there unless the user chose otherwise (on two
    # busy cores, oversubscribed threads made each step ~10x slower in our measurements)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    finetune(init, datasets, out, settings, progress=progress)
    write_json(out / "accrue_base.json", {"stage": c["stage"], "finetuned": True, "tasks": c["tasks"]})


STEP = StepDef(
    name="finetune-base",
    code_version="finetune-base-1",
    run=run,
    optional_inputs=("init",),
    outputs={"base-policy": "base-policy"},
    description="base policy fine-tuned on the demos of tasks 1..k",
)
