"""The train step hands train_stage what the method needs (issue 23, item 1 one level up): a tiny
two-stage ACCRUE workflow with λ and β set in its YAML, run in-process with train_stage wrapped; stage 2
must get θ^1, B^{<2} from the handoff and the cached Eq. 3 targets of exactly those rows, and the
config's λ and β (mutations train-step-drops-teacher; accrue-becomes-sequential and lambda/beta-hardcoded
one level up)."""

from __future__ import annotations

import pytest
import torch

pytestmark = pytest.mark.slow

WORKFLOW = """
name: wiring
tasks: [nist/rect_peg, nist/gear]
method: accrue
seed: 3
horizon: 4
task_features: 8
base_policy: {init: "scripted-reference:0.5"}
learner: {actor_hidden: [32, 32], critic_hidden: [32, 32], projector_dim: 16, batch_size: 32, num_atoms: 11, utd: 1,
          lam: 0.37, beta: 0.23}
budgets: {env_steps: 40, eval_every: 40, eval_episodes: 2, num_envs: 2, warmup_episodes: 2,
          retained_episodes: 2, checkpoint_every: 0, log_episodes: 1}
"""


def test_stage_two_train_step_passes_handoff_memory_teacher_and_config(tmp_path, monkeypatch):
    from rich.console import Console

    from accrue import stage_rl
    from accrue.learner import compute_teacher_targets
    from artifacts.store import Store
    from stages.plan import plan_stage
    from stages.runner import Runner
    from stages.workflow import load_workflow

    calls = []
    real = stage_rl.train_stage

    def spy(cfg, previous, memory, teacher, *args, **kwargs):
        calls.append(dict(cfg=cfg, previous=previous, memory=memory, teacher=teacher))
        return real(cfg, previous, memory, teacher, *args, **kwargs)

    monkeypatch.setattr(stage_rl, "train_stage", spy)
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    (tmp_path / "wf.yaml").write_text(WORKFLOW)
    store = Store.init(tmp_path / "store")[0]
    wf = load_workflow(tmp_path / "wf.yaml")
    runner = Runner(store, console=Console(stderr=True, width=200))
    for stage in (1, 2):
        runner.run_plan(plan_stage(wf, stage, store))
    assert len(calls) == 2
    first, second = calls
    assert first["previous"] is None and first["memory"] is None and first["teacher"] is None
    for c in calls:
        assert (c["cfg"].method, c["cfg"].lam, c["cfg"].beta) == ("accrue", 0.37, 0.23)
    memory, teacher, previous = second["memory"], second["teacher"], second["previous"]
    assert previous is not None and memory is not None and teacher is not None
    assert len(memory) > 0 and set(memory.column("task").tolist()) == {0}
    assert teacher.targets.shape == memory.column("ref").shape
    # Eq. 3 at the stored inputs, by the handed-over θ^1
    want = compute_teacher_targets(previous, memory.column("state"), memory.column("ref"))
    torch.testing.assert_close(teacher.targets, want)
