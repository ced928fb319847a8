"""`handoff`: Algorithm 1 line 11, (θ^k, ψ^k, B^{<k+1} = B^{<k} ∪ last N episodes of B^k), stage k+1's input.

Layout: learner/ (the whole learner state), memory/ (replay shards of B^{<k+1}), per_task/<i>/ (Isolated
only: the learner kept for task i), handoff.json.
"""
from __future__ import annotations

from stages.runner_context import StepContext
from stages.runner_types import StepDef
from stages.steps.common import copy_tree, deterministic, read_json, write_json


def run(ctx: StepContext) -> None:
    from accrue.learner import ReplayBuffer, retain_last_episodes
    from accrue.learner.continual import stage_plan

    c = ctx.config
    deterministic(c["seed"])
    checkpoint = ctx.input_path("checkpoint")
    current = ReplayBuffer.load(ctx.input_path("replay"))                       # B^k
    parts = [current]
    if ctx.has_input("handoff"):
        parts.insert(0, ReplayBuffer.load(ctx.input_path("handoff") / "memory"))   # B^{<k}
    memory = retain_last_episodes(ReplayBuffer.concat(parts), c["retained_episodes"])
    out = ctx.new_output("handoff", "handoff")
    copy_tree(checkpoint / "learner", out / "learner")
    memory.save_new_shards(out / "memory")
    per_task = []
    if stage_plan(c["method"], c["ablation"]).checkpoint_per_task:
        if (checkpoint / "per_task").is_dir():
            copy_tree(checkpoint / "per_task", out / "per_task")
        copy_tree(checkpoint / "learner", out / "per_task" / str(c["stage"]))
        per_task = sorted(int(p.name) for p in (out / "per_task").iterdir())
    info = read_json(checkpoint / "checkpoint.json")
    tasks = sorted({int(t) for t in memory.column("task").tolist()})
    write_json(out / "handoff.json", {"stage": c["stage"], "task_ids": info["task_ids"], "method": c["method"],
                                      "retained_episodes": c["retained_episodes"], "memory_rows": len(memory),
                                      "memory_tasks": tasks, "per_task": per_task})
    ctx.console.print(f"handoff: θ^{c['stage']}, ψ^{c['stage']} and {len(memory)} retained transitions "
                      f"of tasks {[t + 1 for t in tasks]}")


STEP = StepDef(name="handoff", code_version="handoff-1", run=run, inputs=("checkpoint", "replay"),
               optional_inputs=("handoff",), outputs={"handoff": "handoff"},
               description="actor, critic and retained memory for the next stage")
