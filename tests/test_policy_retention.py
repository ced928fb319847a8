"""Demonstration retention (paper Table VI) and the instruction embedding that conditions ACT."""

from __future__ import annotations

import numpy as np
import pytest
from test_policy_helpers import write_synthetic_demos

from accrue.policy.instruction_embedding import embed_instruction, embed_instructions
from accrue.policy.retention import kept_episode_count, retained_episodes
from accrue.policy.training_set import build_training_set


@pytest.mark.parametrize(
    "fraction, n, kept", [(1.0, 10, 10), (0.5, 10, 5), (0.5, 7, 4), (0.1, 10, 1), (0.05, 10, 1), (0.05, 100, 5)]
)
def test_kept_count_is_ceil_of_fraction(fraction, n, kept):
    assert kept_episode_count(n, fraction) == kept
    assert len(retained_episodes(n, fraction, seed=0, task_position=0, is_current=False)) == kept


def test_retained_episodes_are_a_deterministic_seeded_sample():
    first = retained_episodes(20, 0.5, seed=7, task_position=1, is_current=False)
    assert first == retained_episodes(20, 0.5, seed=7, task_position=1, is_current=False)
    assert first == sorted(set(first)) and all(0 <= i < 20 for i in first)
    others = {tuple(retained_episodes(20, 0.5, seed=s, task_position=1, is_current=False)) for s in range(8)}
    assert len(others) > 1  # the seed chooses the subset
    assert retained_episodes(20, 0.5, seed=7, task_position=1, is_current=True) == list(range(20))


def test_training_set_keeps_half_of_earlier_task_and_all_of_current(tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    old = write_synthetic_demos(tmp_path / "old", "old task", 1.0, episodes=6, length=5, seed=0)
    cur = write_synthetic_demos(tmp_path / "cur", "new task", -1.0, episodes=3, length=5, seed=1)
    summary = build_training_set(
        [old, cur], tmp_path / "merged", retention=0.5, seed=3, embedding_dim=16, use_images=False
    )
    expected_old = retained_episodes(6, 0.5, seed=3, task_position=0, is_current=False)
    assert summary.episodes_per_dataset == [expected_old, [0, 1, 2]]
    assert summary.total_frames == (3 + 3) * 5

    merged = LeRobotDataset("local/merged", root=tmp_path / "merged")
    source = LeRobotDataset("local/old", root=old)
    assert merged.num_episodes == 6
    for out_ep, src_ep in enumerate(expected_old):  # the kept episodes are the chosen ones, in order
        got = merged[out_ep * 5]
        want = source[src_ep * 5]
        np.testing.assert_array_equal(got["observation.state"].numpy(), want["observation.state"].numpy())
        assert got["task"] == "old task"
        np.testing.assert_allclose(got["observation.environment_state"].numpy(), embed_instruction("old task", 16))
    assert merged[5 * 5]["task"] == "new task"


def test_images_are_carried_when_asked(tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    demos = write_synthetic_demos(tmp_path / "img", "look", 1.0, episodes=2, length=3, image_hw=(8, 8))
    summary = build_training_set([demos], tmp_path / "merged", 1.0, 0, 8, use_images=True)
    assert summary.image_keys == ["observation.images.wrist"]
    merged = LeRobotDataset("local/merged", root=tmp_path / "merged")
    source = LeRobotDataset("local/img", root=demos)
    np.testing.assert_allclose(
        merged[4]["observation.images.wrist"].numpy(), source[4]["observation.images.wrist"].numpy(), atol=1 / 255
    )


def test_instruction_embedding_is_fixed_size_deterministic_and_distinct():
    a = embed_instruction("Insert the round peg.", 32)
    assert a.shape == (32,) and a.dtype == np.float32
    assert np.isclose(np.linalg.norm(a), 1.0)
    np.testing.assert_array_equal(a, embed_instruction("insert the round peg", 32))  # case/punctuation-insensitive
    b = embed_instruction("insert the square peg", 32)
    assert not np.allclose(a, b)
    assert embed_instructions(["x y", "y x", "z"], 32).shape == (3, 32)
    assert not np.allclose(embed_instruction("x y"), embed_instruction("y x"))  # word order matters via bigrams
