"""Fine-tune the embedded ACT from scratch and from a checkpoint on two synthetic tasks, then query it."""

from __future__ import annotations

import json
import socket

import numpy as np
import pytest
from test_policy_helpers import STATE_DIM, write_synthetic_demos

from accrue.errors import AccrueError
from accrue.policy import BasePolicy, FinetuneSettings, finetune

TASK_A = "insert the round peg"
TASK_B = "insert the square peg"
TINY = FinetuneSettings(steps=6, batch_size=8, lr=1e-3, seed=0, chunk_size=8)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    root = tmp_path_factory.mktemp("ft")
    demos_a = write_synthetic_demos(root / "a", TASK_A, 1.0, episodes=3, length=10, seed=0)
    demos_b = write_synthetic_demos(root / "b", TASK_B, -1.0, episodes=3, length=10, seed=1)
    steps = []
    scratch = finetune("embedded-act", [demos_a], root / "stage1", TINY, progress=lambda s, n: steps.append((s, n)))
    stage2 = finetune(scratch, [demos_a, demos_b], root / "stage2", TINY)
    return {"a": demos_a, "b": demos_b, "scratch": scratch, "stage2": stage2, "progress": steps, "root": root}


@pytest.fixture
def no_network(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("tried to open a network connection")

    monkeypatch.setattr(socket.socket, "connect", refuse)


def _obs(batch=3, seed=0):
    return {"state": np.random.default_rng(seed).uniform(-1, 1, (batch, STATE_DIM)).astype(np.float32)}


def test_finetune_writes_a_lerobot_checkpoint_and_reports_progress(trained):
    for name in ("config.json", "model.safetensors", "policy_preprocessor.json", "policy_postprocessor.json"):
        assert (trained["scratch"] / name).is_file()
    assert trained["progress"][-1] == (6, 6)
    assert [s for s, _ in trained["progress"]] == sorted(s for s, _ in trained["progress"])
    record = json.loads((trained["stage2"] / "accrue_finetune.json").read_text())
    assert record["init"] == str(trained["scratch"])
    assert record["training_set"]["instructions"] == [TASK_A, TASK_B]
    assert not (trained["stage2"] / "_work").exists()


def test_stage2_continues_from_stage1_weights(trained):
    from safetensors.numpy import load_file

    before = load_file(trained["scratch"] / "model.safetensors")
    after = load_file(trained["stage2"] / "model.safetensors")
    assert before.keys() == after.keys()
    assert any(not np.array_equal(before[k], after[k]) for k in before)


def test_reloaded_chunk_matches_lerobot_policy_with_dataset_normalisation(trained, no_network):
    """The chunk is the lerobot model's output, unnormalised with the training demos' statistics."""
    import torch
    from lerobot.policies.act.modeling_act import ACTPolicy

    from accrue.policy.demo_sources import open_demo_source
    from accrue.policy.instruction_embedding import embed_instructions

    pol = BasePolicy.load(trained["stage2"])
    obs = _obs()
    chunk = pol.reference_chunk(obs, TASK_B, horizon=5)
    assert chunk.shape == (3, 5, 6) and chunk.dtype == np.float32

    sources = [open_demo_source(trained["a"]), open_demo_source(trained["b"])]
    states = np.concatenate([s for src in sources for s in src.states])
    actions = np.concatenate([a for src in sources for a in src.actions])
    model = ACTPolicy.from_pretrained(trained["stage2"]).eval()
    batch = {
        "observation.state": torch.from_numpy((obs["state"] - states.mean(0)) / (states.std(0) + 1e-8)).float(),
        "observation.environment_state": torch.from_numpy(embed_instructions([TASK_B] * 3, 32)),
    }
    with torch.no_grad():
        normalised = model.predict_action_chunk(batch)[:, :5].numpy()
    expected = np.clip(normalised * (actions.std(0) + 1e-8) + actions.mean(0), -1, 1)
    np.testing.assert_allclose(chunk, expected, atol=1e-4)

    again = BasePolicy.load(trained["stage2"]).reference_chunk(obs, [TASK_B] * 3, horizon=5)
    np.testing.assert_array_equal(chunk, again)


def test_chunk_is_deterministic_and_task_conditioned(trained):
    pol = BasePolicy.load(trained["stage2"], seed=3)
    obs = _obs(batch=2, seed=5)
    first = pol.reference_chunk(obs, TASK_A, horizon=8)
    assert np.array_equal(first, pol.reference_chunk(obs, TASK_A, horizon=8))
    other_task = pol.reference_chunk(obs, TASK_B, horizon=8)
    assert np.abs(first - other_task).max() > 1e-4
    mixed = pol.reference_chunk(obs, [TASK_A, TASK_B], horizon=8)
    np.testing.assert_allclose(mixed[0], first[0], atol=1e-5)
    np.testing.assert_allclose(mixed[1], other_task[1], atol=1e-5)
    assert np.all(np.abs(first) <= 1.0)


def test_bad_queries_are_one_line_errors(trained):
    pol = BasePolicy.load(trained["scratch"])
    with pytest.raises(AccrueError, match="horizon 9 is outside 1..8"):
        pol.reference_chunk(_obs(), TASK_A, horizon=9)
    with pytest.raises(AccrueError, match="expects \\(B, 4\\)"):
        pol.reference_chunk({"state": np.zeros((2, 7), np.float32)}, TASK_A, horizon=4)
    with pytest.raises(AccrueError, match="2 instructions for a batch of 3"):
        pol.reference_chunk(_obs(), [TASK_A, TASK_B], horizon=4)


def test_checkpoint_and_dataset_shapes_must_agree(trained, tmp_path):
    wide = write_synthetic_demos(
        tmp_path / "wide",
        TASK_A,
        1.0,
        episodes=1,
        length=4,
        extra_features={"observation.extra": {"dtype": "float32", "shape": (2,), "names": None}},
    )
    # same state size but an extra feature is fine; a different state size is not
    import test_policy_helpers as helpers
    from test_policy_helpers import write_synthetic_demos as write

    old = helpers.STATE_DIM
    helpers.STATE_DIM = 5
    try:
        five = write(tmp_path / "five", TASK_A, 1.0, episodes=1, length=4)
    finally:
        helpers.STATE_DIM = old
    with pytest.raises(AccrueError, match="'observation.state' has shape \\[5\\] but checkpoint"):
        finetune(trained["scratch"], [five], tmp_path / "out", TINY)
    with pytest.raises(AccrueError, match="already exists and is not empty"):
        finetune(trained["scratch"], [wide], trained["stage2"], TINY)
