"""`handoff`: Algorithm 1 line 11, (θ^k, ψ^k, B^{<k+1} = B^{<k} ∪ last N complete episodes of B^k), stage
k+1's input.

Layout: learner/ (the whole learner state), memory/ (replay shards of B^{<k+1}), per_task/<i>/ (Isolated
only: the learner kept for task i), handoff.json (what was kept, and whether the stage had fewer than N
complete episodes to keep).
"""

from __future__ import annotations

from pathlib import Path

from stages.runner_context import StepContext
from stages.runner_types import StepDef
from stages.steps import checkpoint_layout
from stages.steps.common import copy_tree, deterministic, read_json, write_json

LEARNER_DIR, MEMORY_DIR, PER_TASK_DIR, INFO_FILE = "learner", "memory", "per_task", "handoff.json"


def per_task_learners(handoff: Path | None) -> dict[int, Path]:
    """Isolated: stage index i -> the learner kept for task i (handoff/per_task/<i>/)."""
    if handoff is None or not (handoff / PER_TASK_DIR).is_dir():
        return {}
    return {int(p.name): p for p in sorted((handoff / PER_TASK_DIR).iterdir())}


def run(ctx: StepContext) -> None:
    from accrue.learner import ReplayBuffer
    from accrue.methods import rules
    from accrue.stage_rl import hand_over

    c = ctx.config
    deterministic(c["seed"])
    checkpoint = ctx.input_path("checkpoint")
    current = ReplayBuffer.load(ctx.input_path("replay"))  # B^k
    previous = ReplayBuffer.load(ctx.input_path("handoff") / MEMORY_DIR) if ctx.has_input("handoff") else None
    memory, kept = hand_over(previous, current, c["retained_episodes"])
    out = ctx.new_output("handoff", "handoff")
    copy_tree(checkpoint / checkpoint_layout.LEARNER_DIR, out / LEARNER_DIR)
    memory.save_new_shards(out / MEMORY_DIR)
    per_task = []
    if rules(c["method"], c["ablation"]).checkpoint_per_task:
        if (checkpoint / checkpoint_layout.PER_TASK_DIR).is_dir():
            copy_tree(checkpoint / checkpoint_layout.PER_TASK_DIR, out / PER_TASK_DIR)
        copy_tree(checkpoint / checkpoint_layout.LEARNER_DIR, out / PER_TASK_DIR / str(c["stage"]))
        per_task = sorted(int(p.name) for p in (out / PER_TASK_DIR).iterdir())
    info = read_json(checkpoint / checkpoint_layout.CHECKPOINT_FILE)
    tasks = sorted({int(t) for t in memory.column("task").tolist()})
    write_json(
        out / INFO_FILE,
        {
            "stage": c["stage"],
            "task_ids": info["task_ids"],
            "method": c["method"],
            "retained_episodes": c["retained_episodes"],
            "memory_rows": len(memory),
            "memory_tasks": tasks,
            "per_task": per_task,
            "memory": kept,
        },
    )
    if kept["short"]:
        ctx.console.print(
            f"handoff: stage {c['stage']} ended fewer than N = {c['retained_episodes']} complete episodes "
            f"({episodes_text(kept['current_complete_episodes'])}); the memory keeps what there is"
        )
        ctx.log_event(
            "short-memory",
            stage=c["stage"],
            retained_episodes=c["retained_episodes"],
            complete_episodes=kept["current_complete_episodes"],
        )
    ctx.console.print(
        f"handoff: θ^{c['stage']}, ψ^{c['stage']} and {len(memory)} retained transitions ({kept_text(kept['kept'])})"
    )


def episodes_text(counts: dict) -> str:
    """{task index: complete episodes} in words: `16 of task 1`, `20 of task 1, 5 of task 2` (tasks 1-based)."""
    parts = sorted((int(t), n) for t, n in counts.items())
    return ", ".join(f"{n} of task {t + 1}" for t, n in parts) or "none"


def kept_text(kept: dict) -> str:
    """{task index: complete episodes kept} in words: `20 of task 1, 5 of task 2 kept`."""
    if not kept:
        return "no complete episode kept"
    if len(kept) == 1:
        [(t, n)] = kept.items()
        return f"{n} complete episodes of task {int(t) + 1} kept"
    return f"complete episodes: {episodes_text(kept)} kept"


STEP = StepDef(
    name="handoff",
    code_version="handoff-2",
    run=run,
    inputs=("checkpoint", "replay"),
    optional_inputs=("handoff",),
    outputs={"handoff": "handoff"},
    description="actor, critic and last N complete episodes for the next stage",
)
