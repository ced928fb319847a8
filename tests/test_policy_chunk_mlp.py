"""The embedded base policy `accrue_chunk_mlp`: a lerobot policy type accrue registers, trained by
lerobot-train, reloaded through lerobot's loaders, and its chunk equal to the network's own output."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_policy_helpers import STATE_DIM, expert_action, write_synthetic_demos

from accrue.policy import EMBEDDED_DEFAULT, BasePolicy, FinetuneSettings, finetune

TASK_A = "insert the round peg"
TASK_B = "insert the square peg"


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    root = tmp_path_factory.mktemp("mlp")
    demos_a = write_synthetic_demos(root / "a", TASK_A, 1.0, episodes=4, length=10, seed=0)
    demos_b = write_synthetic_demos(root / "b", TASK_B, -1.0, episodes=4, length=10, seed=1)
    settings = FinetuneSettings(steps=300, batch_size=32, lr=3e-3, seed=0, chunk_size=4)
    stage1 = finetune(EMBEDDED_DEFAULT, [demos_a], root / "stage1", settings)
    stage2 = finetune(stage1, [demos_a, demos_b], root / "stage2", settings)
    return {"a": demos_a, "b": demos_b, "stage1": stage1, "stage2": stage2}


def test_embedded_default_is_the_chunk_mlp(trained):
    config = json.loads((trained["stage1"] / "config.json").read_text())
    assert EMBEDDED_DEFAULT == "embedded-mlp"
    assert config["type"] == "accrue_chunk_mlp" and config["chunk_size"] == 4
    assert set(config["input_features"]) == {"observation.state", "observation.environment_state"}


def test_reloaded_chunk_is_the_network_output_on_normalised_inputs(trained):
    import torch
    from safetensors.numpy import load_file

    from accrue.policy.chunk_mlp import ChunkMLPPolicy
    from accrue.policy.demo_sources import open_demo_source
    from accrue.policy.instruction_embedding import embed_instructions

    policy = BasePolicy.load(trained["stage2"])
    obs = {"state": np.random.default_rng(4).uniform(-1, 1, (3, STATE_DIM)).astype(np.float32)}
    chunk = policy.reference_chunk(obs, TASK_B, horizon=3)
    assert chunk.shape == (3, 3, 6)

    # the saved normaliser carries the training demos' statistics
    stats = load_file(next(trained["stage2"].glob("policy_preprocessor_step_*_normalizer_processor.safetensors")))
    sources = [open_demo_source(trained["a"]), open_demo_source(trained["b"])]
    states = np.concatenate([s for src in sources for s in src.states])
    np.testing.assert_allclose(stats["observation.state.mean"], states.mean(0), atol=1e-5)
    np.testing.assert_allclose(stats["observation.state.std"], states.std(0), atol=1e-5)

    def standardise(x, key):
        return torch.from_numpy((x - stats[f"{key}.mean"]) / (stats[f"{key}.std"] + 1e-8)).float()

    model = ChunkMLPPolicy.from_pretrained(trained["stage2"]).eval()
    batch = {
        "observation.state": standardise(obs["state"], "observation.state"),
        "observation.environment_state": standardise(
            embed_instructions([TASK_B] * 3, 32), "observation.environment_state"
        ),
    }
    expected = np.clip(model.predict_action_chunk(batch)[:, :3].numpy(), -1, 1)  # actions are not normalised
    np.testing.assert_allclose(chunk, expected, atol=1e-4)


def test_it_learns_each_task_from_its_instruction(trained):
    # the two synthetic tasks act with opposite signs on the same states: the instruction decides
    policy = BasePolicy.load(trained["stage2"])
    rng = np.random.default_rng(0)
    errors, swapped = [], []
    for instruction, sign, other in ((TASK_A, 1.0, -1.0), (TASK_B, -1.0, 1.0)):
        states = rng.uniform(-1, 1, (32, STATE_DIM)).astype(np.float32)
        first = policy.reference_chunk({"state": states}, instruction, horizon=1)[:, 0]
        want = np.stack([expert_action(s, sign) for s in states])
        wrong = np.stack([expert_action(s, other) for s in states])
        errors.append(np.abs(first - want).mean())
        swapped.append(np.abs(first - wrong).mean())
    assert max(errors) < 0.5 * min(swapped)


def test_stage2_continues_from_stage1(trained):
    record = json.loads((trained["stage2"] / "accrue_finetune.json").read_text())
    assert record["init"] == str(trained["stage1"])
    assert record["training_set"]["instructions"] == [TASK_A, TASK_B]
