"""A missing/broken checkpoint, an unknown or uninstalled policy type, or bad demos: one-line errors."""

from __future__ import annotations

import json

import pytest
from test_policy_helpers import write_synthetic_demos

from accrue.errors import AccrueError
from accrue.policy import BasePolicy, FinetuneSettings, finetune
from accrue.policy.lerobot_train_run import parse_step, run_lerobot_train


def _one_line(exc_info) -> str:
    message = str(exc_info.value)
    assert "\n" not in message
    return message


def _fake_checkpoint(path, config: dict | str):
    path.mkdir()
    (path / "config.json").write_text(config if isinstance(config, str) else json.dumps(config))
    for name in ("model.safetensors", "policy_preprocessor.json", "policy_postprocessor.json"):
        (path / name).write_text("{}")
    return path


def test_missing_checkpoint(tmp_path):
    with pytest.raises(AccrueError) as info:
        BasePolicy.load(tmp_path / "nope")
    assert "does not exist" in _one_line(info)


def test_checkpoint_without_weights(tmp_path):
    ckpt = _fake_checkpoint(tmp_path / "c", {"type": "act"})
    (ckpt / "model.safetensors").unlink()
    with pytest.raises(AccrueError) as info:
        BasePolicy.load(ckpt)
    assert "missing model.safetensors" in _one_line(info)


def test_broken_config_json(tmp_path):
    with pytest.raises(AccrueError) as info:
        BasePolicy.load(_fake_checkpoint(tmp_path / "c", "{not json"))
    assert "config.json is not valid JSON" in _one_line(info)


def test_unknown_policy_type(tmp_path):
    ckpt = _fake_checkpoint(tmp_path / "c", {"type": "telepathy", "input_features": {}})
    with pytest.raises(AccrueError) as info:
        BasePolicy.load(ckpt)
    assert "unknown policy type 'telepathy'" in _one_line(info)


def test_corrupt_weights_file(tmp_path):
    ckpt = _fake_checkpoint(
        tmp_path / "c",
        {
            "type": "act",
            "pretrained_backbone_weights": None,
            "input_features": {"observation.environment_state": {"type": "ENV", "shape": [4]}},
            "output_features": {"action": {"type": "ACTION", "shape": [6]}},
        },
    )
    with pytest.raises(AccrueError) as info:
        BasePolicy.load(ckpt)
    assert _one_line(info).startswith(f"cannot load policy checkpoint {ckpt}")


def test_uninstalled_vla_type_names_what_is_missing(tmp_path):
    ckpt = _fake_checkpoint(
        tmp_path / "c",
        {
            "type": "smolvla",
            "input_features": {"observation.state": {"type": "STATE", "shape": [4]}},
            "output_features": {"action": {"type": "ACTION", "shape": [6]}},
        },
    )
    with pytest.raises(AccrueError) as info:
        BasePolicy.load(ckpt)
    message = _one_line(info)
    assert "lerobot[smolvla]" in message and "local HF cache" in message


def test_dataset_without_state_feature(tmp_path):
    import numpy as np
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    ds = LeRobotDataset.create(
        repo_id="local/bad",
        root=tmp_path / "bad",
        fps=10,
        use_videos=False,
        features={
            "observation.joints": {"dtype": "float32", "shape": (3,), "names": None},
            "action": {"dtype": "float32", "shape": (6,), "names": None},
        },
    )
    for _ in range(3):
        ds.add_frame({"observation.joints": np.zeros(3, np.float32), "action": np.zeros(6, np.float32), "task": "t"})
    ds.save_episode()
    ds.finalize()
    with pytest.raises(AccrueError) as info:
        finetune("embedded-act", [tmp_path / "bad"], tmp_path / "out", FinetuneSettings(steps=1))
    assert "has no feature 'observation.state'" in _one_line(info)


def test_not_a_dataset_and_unknown_init(tmp_path):
    (tmp_path / "empty").mkdir()
    for _attempt in range(2):  # a failed attempt's leftovers do not block the next attempt
        with pytest.raises(AccrueError, match="not a LeRobotDataset"):
            finetune("embedded-act", [tmp_path / "empty"], tmp_path / "out", FinetuneSettings(steps=1))
    demos = write_synthetic_demos(tmp_path / "d", "t", 1.0, episodes=1, length=3)
    with pytest.raises(AccrueError, match="unknown policy init 'gpt-robot'"):
        finetune("gpt-robot", [demos], tmp_path / "out2", FinetuneSettings(steps=1))
    with pytest.raises(AccrueError, match="retention must be in"):
        finetune("embedded-act", [demos], tmp_path / "out3", FinetuneSettings(retention=0.0))


def test_datasets_with_different_action_sizes(tmp_path):
    import test_policy_helpers as helpers

    a = write_synthetic_demos(tmp_path / "a", "t", 1.0, episodes=1, length=3)
    old = helpers.STATE_DIM
    helpers.STATE_DIM = 5
    try:
        b = write_synthetic_demos(tmp_path / "b", "u", 1.0, episodes=1, length=3)
    finally:
        helpers.STATE_DIM = old
    with pytest.raises(AccrueError, match="observation.state size 5 differs"):
        finetune("embedded-act", [a, b], tmp_path / "out", FinetuneSettings(steps=1))


def test_failed_training_subprocess_names_its_log(tmp_path):
    log = tmp_path / "train.log"
    with pytest.raises(AccrueError) as info:
        # a quick module that rejects its arguments stands in for a failing lerobot-train
        run_lerobot_train(["--no_such_flag=1"], log, total_steps=1, module="json.tool")
    assert f"see the log at {log}" in _one_line(info)
    assert log.stat().st_size > 0


def test_parse_step_reads_lerobot_log_lines():
    assert parse_step("INFO ... step:200 smpl:1K ep:3 loss:0.1") == 200
    assert parse_step("INFO ... step:2K smpl:64K") == 2000
    assert parse_step("Training: 10%") is None
