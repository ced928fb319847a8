"""finetune-base in-process: two fresh stores give byte-identical outputs with the same artifact ids
(stage 1 from scratch and stage 2 from stage 1's checkpoint), the merged training set is a cached
artifact, and the result stays a lerobot checkpoint that lerobot's own factory loads."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest
from rich.console import Console

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_policy_helpers import write_synthetic_demos  # noqa: E402

from artifacts.ingest import add_path
from artifacts.manifests import materialize, read_artifact, read_tree
from artifacts.refs import list_refs
from artifacts.store import Store
from stages.runner import Runner
from stages.runner_types import StepInvocation
from stages.steps import finetune_base

TASKS = ("insert the round peg", "insert the square peg")
ROOT = Path(__file__).resolve().parents[1]


def _config(stage: int, init: str) -> dict:
    return {
        "stage": stage,
        "tasks": list(TASKS[:stage]),
        "init": init,
        "finetune": True,
        "steps": 5,
        "batch_size": 8,
        "lr": 1e-3,
        "seed": 0,
        "retention": 1.0,
        "chunk_size": 4,
    }


def _step(stage: int):
    return dataclasses.replace(finetune_base.STEP, inputs=finetune_base.demo_roles(stage))


def _two_stages(root: Path, demos: list[Path]) -> dict:
    """Run stage 1 (embedded-mlp from scratch) and stage 2 (from stage 1) in a fresh store at root."""
    store = Store.init(root)[0]
    runner = Runner(store, console=Console(file=open(os.devnull, "w")))
    ids = [add_path(store, d, "demos")[0] for d in demos]
    one = runner.run(StepInvocation(step=_step(1), config=_config(1, "embedded-mlp"), inputs={"demos-1": ids[0]}))
    policy = one.outputs["base-policy"]
    two = runner.run(
        StepInvocation(
            step=_step(2),
            config=_config(2, "previous-stage"),
            inputs={"demos-1": ids[0], "demos-2": ids[1], "init": policy},
        )
    )
    return {"store": store, "runner": runner, "ids": ids, "one": one, "two": two}


def _content(store: Store, artifact_id: str) -> tuple[str, dict]:
    manifest = read_artifact(store, artifact_id)
    return manifest["content"], {e["path"]: e["id"] for e in read_tree(store, manifest["content"])}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("inproc")
    demos = [
        write_synthetic_demos(root / "demos-a", TASKS[0], 1.0, episodes=3, length=10, seed=0),
        write_synthetic_demos(root / "demos-b", TASKS[1], -1.0, episodes=3, length=10, seed=1),
    ]
    first = _two_stages(root / "store-1", demos)
    # the second store in another process with another hash seed: what varies between processes
    # (set and dict orders lerobot writes in) must not reach the bytes either
    code = (
        "import json, sys; sys.path.insert(0, 'tests'); from pathlib import Path; "
        "from test_finetune_inprocess import _two_stages; "
        f"r = _two_stages(Path({str(root / 'store-2')!r}), [Path({str(demos[0])!r}), Path({str(demos[1])!r})]); "
        "print(json.dumps({k: r[k].outputs for k in ('one', 'two')}))"
    )
    env = {**os.environ, "PYTHONHASHSEED": "12345"}
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True, check=True)
    outputs = json.loads(out.stdout.strip().splitlines()[-1])
    second = {"store": Store.open(root / "store-2"), **{k: SimpleNamespace(outputs=v) for k, v in outputs.items()}}
    return [first, second], root


def test_two_fresh_stores_produce_the_same_bytes_for_both_stages(runs):
    (a, b), _ = runs
    for stage in ("one", "two"):
        tree_a, files_a = _content(a["store"], a[stage].outputs["base-policy"])
        tree_b, files_b = _content(b["store"], b[stage].outputs["base-policy"])
        assert files_a == files_b, f"stage {stage}: files differ"
        assert tree_a == tree_b
        # and the same artifact ids: the id is a function of kind, content, inputs, config and code
        # version, never of the store's path, the attempt or the time (issue 23, item 3)
        assert a[stage].outputs == b[stage].outputs, f"stage {stage}: artifact ids differ"
    record = json.loads(
        (
            materialize(a["store"], a["two"].outputs["base-policy"], runs[1] / "two-a") / "accrue_finetune.json"
        ).read_text()
    )
    # the record names inputs by role (the step record maps them to ids), never by temporary paths
    assert record["init"] == "input:init" and record["datasets"] == ["input:demos-1", "input:demos-2"]
    assert "root" not in record["training_set"]
    # the cached training sets too: the same names and the same bytes in both stores
    sets_a = list_refs(a["store"], finetune_base.TRAINING_SET_REFS + "/")
    sets_b = list_refs(b["store"], finetune_base.TRAINING_SET_REFS + "/")
    assert sets_a.keys() == sets_b.keys()
    assert [_content(a["store"], sets_a[k]) for k in sets_a] == [_content(b["store"], sets_b[k]) for k in sets_a]
    assert sets_a == sets_b  # the same artifact ids too


def test_the_checkpoint_keeps_no_machine_path(runs):
    (a, _), root = runs
    out = materialize(a["store"], a["two"].outputs["base-policy"], root / "paths-a")
    for name in ("config.json", "train_config.json", "accrue_finetune.json", "finetune.log"):
        text = (out / name).read_text()
        assert str(a["store"].root) not in text and "/tmp" not in text, name
    train_config = json.loads((out / "train_config.json").read_text())
    assert train_config["dataset"]["root"] is None and train_config["output_dir"] is None


def test_training_sets_are_cached_artifacts_reused_by_a_rerun(runs):
    (a, _), _ = runs
    refs = list_refs(a["store"], finetune_base.TRAINING_SET_REFS + "/")
    assert len(refs) == 2  # stage 1 (task A) and stage 2 (tasks A + B)
    for oid in refs.values():
        manifest = read_artifact(a["store"], oid)
        assert manifest["kind"] == "training-set"
        paths = {e["path"] for e in read_tree(a["store"], manifest["content"])}
        assert {"meta/info.json", "accrue_frames.safetensors", finetune_base_summary()} <= paths
    again = a["runner"].run(
        StepInvocation(step=_step(1), config=_config(1, "embedded-mlp"), inputs={"demos-1": a["ids"][0]}),
        mode="rerun",
    )
    assert list_refs(a["store"], finetune_base.TRAINING_SET_REFS + "/") == refs  # found, not rebuilt
    files_again = _content(a["store"], again.outputs["base-policy"])[1]
    files_first = _content(a["store"], a["one"].outputs["base-policy"])[1]
    assert [p for p in files_first if files_again.get(p) != files_first[p]] == []


def finetune_base_summary() -> str:
    from accrue.policy.finetune import SUMMARY_FILE

    return SUMMARY_FILE


def test_lerobot_loads_the_checkpoint_with_its_own_factory(runs):
    import torch
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    (a, _), root = runs
    out = materialize(a["store"], a["two"].outputs["base-policy"], root / "load-a")
    config = PreTrainedConfig.from_pretrained(out)
    policy = get_policy_class(config.type).from_pretrained(out).eval()
    pre, post = make_pre_post_processors(config, pretrained_path=str(out))
    state_dim = config.input_features["observation.state"].shape[0]
    env_dim = config.input_features["observation.environment_state"].shape[0]
    batch = pre(
        {"observation.state": torch.zeros(1, state_dim), "observation.environment_state": torch.zeros(1, env_dim)}
    )
    with torch.no_grad():
        action = post(policy.select_action(batch))
    assert action.shape[-1] == config.output_features["action"].shape[0]
    assert torch.isfinite(action).all()
