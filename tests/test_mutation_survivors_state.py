"""Tests written to kill mutants of accrue/learner/state.py that survived mutmut's round-1 sweep over the rest
of accrue/learner (docs/MUTATION.md). Each test's docstring names the mutmut ids it kills.

What they check: optimiser state survives the flatten → JSON → unflatten → load path exactly (non-tensor
entries, keys holding "/", parameters with only non-tensor state, `betas` back as a tuple, groups without
betas untouched); the continual-rule tensors and the stage index survive save/load; learner.json's header and
canonical form; a checkpoint written before the normaliser could be frozen still loads; the exact refusals
of load_learner; the device override of load_learner. Tiny networks, CPU only.
"""

from __future__ import annotations

import json
import re

import pytest
import torch

from accrue.errors import AccrueError
from accrue.learner import LearnerConfig, load_learner, make_learner, save_learner
from accrue.learner.state import META_FILE, TENSORS_FILE, _flatten_optimizer, _unflatten_optimizer

pytestmark = pytest.mark.usefixtures("one_torch_thread")

D, H, A = 3, 2, 2


def config(algo: str = "fasttd3", **kw) -> LearnerConfig:
    return LearnerConfig(
        algo=algo, actor_hidden=[8], critic_hidden=[8], projector_dim=4, num_atoms=5, batch_size=4, **kw
    )


def raises_exactly(message: str):
    return pytest.raises(AccrueError, match="^" + re.escape(message) + "$")


def assert_same(got, want, where: str = "") -> None:
    """Equal nested dicts/lists/tuples: tensors bit-equal, everything else equal and of the same type."""
    assert type(got) is type(want), (where, type(got), type(want))
    if isinstance(want, dict):
        assert list(got) == list(want) or set(got) == set(want), (where, set(got) ^ set(want))
        for k in want:
            assert_same(got[k], want[k], f"{where}/{k}")
    elif isinstance(want, list | tuple):
        assert len(got) == len(want), where
        for i, (g, w) in enumerate(zip(got, want)):
            assert_same(g, w, f"{where}[{i}]")
    elif torch.is_tensor(want):
        assert got.dtype == want.dtype and torch.equal(got, want), where
    else:
        assert got == want, where


def through_json(prefix: str, opt: torch.optim.Optimizer) -> tuple[dict, dict]:
    """What save_learner + load_learner do to one optimiser: tensors kept aside, the rest through JSON."""
    tensors: dict = {}
    meta = json.loads(json.dumps(_flatten_optimizer(prefix, opt, tensors)))
    return _unflatten_optimizer(prefix, meta, tensors), tensors


# ------------------------------------------------------------------------------------------- optimiser state
def sparse_adam_with_extra_state():
    """SparseAdam keeps `step` as a plain int (non-tensor state) next to its moment tensors; entries may be
    named freely, so keys holding "/" are added, and a parameter whose only state is non-tensor."""
    emb = torch.nn.Embedding(4, 2, sparse=True)
    other = torch.nn.Parameter(torch.zeros(3))
    opt = torch.optim.SparseAdam([{"params": [emb.weight]}, {"params": [other], "lr": 0.5}], lr=0.1)
    emb(torch.tensor([1, 3])).sum().backward()
    opt.step()
    opt.state[emb.weight]["trace/last"] = torch.tensor([5.0, -6.0])  # a tensor entry named with "/"
    opt.state[emb.weight]["phase/count"] = 7  # a non-tensor entry named with "/"
    opt.state[other]["visits"] = 3  # a parameter that has non-tensor state only
    return emb, other, opt


def test_optimizer_state_round_trips_non_tensor_entries_and_slashed_keys():
    """Kills state `_flatten_optimizer` 7 (non-tensor value kept), `_unflatten_optimizer` 10, 11, 15 (a tensor
    entry's key split once, from the left), 24-31 (a non-tensor entry's key split once at the first "/"),
    32 (its value), 33, 37 (its parameter id), 34, 35, 36 (a parameter that has non-tensor state only)."""
    emb, other, opt = sparse_adam_with_extra_state()
    want = opt.state_dict()
    assert want["state"][0]["step"] == 1 and not torch.is_tensor(want["state"][0]["step"])
    got, tensors = through_json("optim/x", opt)
    assert "optim/x/state/0/trace/last" in tensors and "optim/x/state/0/step" not in tensors
    assert_same(got, want)
    # and an optimiser loaded from it holds exactly the same state
    emb2, other2 = torch.nn.Embedding(4, 2, sparse=True), torch.nn.Parameter(torch.zeros(3))
    fresh = torch.optim.SparseAdam([{"params": [emb2.weight]}, {"params": [other2], "lr": 0.5}], lr=0.1)
    fresh.load_state_dict(got)
    assert_same(fresh.state_dict(), want)
    assert fresh.state[other2] == {"visits": 3}


def test_optimizer_betas_come_back_a_tuple_and_groups_without_betas_untouched():
    """Kills state `_unflatten_optimizer` 39, 41, 42, 46, 47, 48 (AdamW's betas, a list after JSON, turned back
    into a tuple under the same key, nothing added) and 40, 48 (SGD's groups have no betas: left as they are)."""
    p = torch.nn.Parameter(torch.ones(2))
    adamw = torch.optim.AdamW([p], lr=0.1, betas=(0.8, 0.95))
    p.grad = torch.tensor([1.0, -2.0])
    adamw.step()
    got, _ = through_json("optim/actor", adamw)
    assert_same(got, adamw.state_dict())
    assert got["param_groups"][0]["betas"] == (0.8, 0.95)

    q = torch.nn.Parameter(torch.ones(2))
    sgd = torch.optim.SGD([q], lr=0.1, momentum=0.9)
    q.grad = torch.tensor([1.0, -2.0])
    sgd.step()
    got, _ = through_json("optim/sgd", sgd)
    assert "betas" not in got["param_groups"][0]
    assert_same(got, sgd.state_dict())


# ------------------------------------------------------------------------------------------- save / load
def with_rule_tensors(learner, stage: int):
    """EWC's Fisher and anchor and RETAIN's θ_prev, each with its own values, as begin_stage fills them."""
    g = torch.Generator().manual_seed(stage)
    params = dict(learner.actor.named_parameters())
    learner.ewc_fisher = {k: torch.rand(v.shape, generator=g) for k, v in params.items()}
    learner.ewc_anchor = {k: torch.randn(v.shape, generator=g) for k, v in params.items()}
    learner.retain_prev = {k: torch.randn(v.shape, generator=g) for k, v in params.items()}
    learner.stage = stage
    return learner


def test_rule_tensors_and_stage_survive_save_and_load_into_a_nested_directory_saved_twice(tmp_path):
    """Kills state `training_state` 34-39 (the groups' names), 40 (their tensors), `load_training_state_into`
    53-58 (the groups read back), 61, 65, 66, 70 (each under its own key, prefix and "/" stripped), 89 (the stage
    index), `save_learner` 3, 5, 7 (missing parents created), 4, 6, 8 (an existing checkpoint overwritten)."""
    directory = tmp_path / "a" / "b" / "c"
    save_learner(with_rule_tensors(make_learner(config(method="ewc"), D, H, A), 1), directory)
    learner = with_rule_tensors(make_learner(config(method="ewc"), D, H, A), 2)
    save_learner(learner, directory)
    loaded = load_learner(directory)
    assert loaded.stage == 2 and type(loaded.stage) is int
    for group in ("ewc_fisher", "ewc_anchor", "retain_prev"):
        want, got = getattr(learner, group), getattr(loaded, group)
        assert set(got) == set(want) == set(dict(learner.actor.named_parameters())), group
        for k in want:
            assert torch.equal(got[k], want[k]), (group, k)
    assert sorted(p.name for p in directory.iterdir()) == [META_FILE, TENSORS_FILE]


@pytest.mark.parametrize("algo", ["fasttd3", "fastsac"])
def test_learner_json_header_and_canonical_form(tmp_path, algo):
    """Kills state `training_state` 45, 46 (learner.json's `algo`), `save_learner` 38, 39, 41, 42, 43, 44
    (written sorted, indented by one space, newline-terminated: the same state gives the same bytes)."""
    save_learner(make_learner(config(algo), D, H, A), tmp_path)
    text = (tmp_path / META_FILE).read_text()
    meta = json.loads(text)
    assert meta["algo"] == algo == meta["config"]["algo"]
    assert meta["format"] == 1 and (meta["state_dim"], meta["horizon"], meta["action_dim"]) == (D, H, A)
    assert text == json.dumps(meta, indent=1, sort_keys=True) + "\n"
    assert text.splitlines()[:3] == ["{", ' "action_dim": 2,', f' "algo": "{algo}",']


def test_checkpoint_without_normaliser_freeze_flag_loads_unfrozen(tmp_path):
    """Kills state `load_training_state_into` 15, 16 (the flag defaulted for the actor), 18, 20 (to a tensor):
    a checkpoint written before the observation normaliser could be frozen has no `actor/obs_norm.frozen`."""
    from safetensors.torch import load_file, save_file

    learner = make_learner(config(), D, H, A)
    save_learner(learner, tmp_path)
    tensors = load_file(str(tmp_path / TENSORS_FILE))
    del tensors["actor/obs_norm.frozen"]
    save_file(tensors, str(tmp_path / TENSORS_FILE))
    loaded = load_learner(tmp_path)
    assert loaded.actor.obs_norm.frozen.dtype == torch.bool and not bool(loaded.actor.obs_norm.frozen)
    sa, sb = learner.actor.state_dict(), loaded.actor.state_dict()
    assert set(sa) == set(sb) and all(torch.equal(sa[k], sb[k]) for k in sa)


def test_corrupt_checkpoint_message(tmp_path):
    """Kills state `load_learner` 12 (the exact message)."""
    save_learner(make_learner(config(), D, H, A), tmp_path)
    (tmp_path / META_FILE).write_text("{not json")
    with raises_exactly(
        f"{tmp_path}: corrupt learner checkpoint (Expecting property name enclosed in double quotes: "
        "line 1 column 2 (char 1))"
    ):
        load_learner(tmp_path)


def test_unsupported_format_message(tmp_path):
    """Kills state `load_learner` 17-21 (the exact message: the file, the format found)."""
    save_learner(make_learner(config(), D, H, A), tmp_path)
    meta = json.loads((tmp_path / META_FILE).read_text())
    meta["format"] = 99
    (tmp_path / META_FILE).write_text(json.dumps(meta))
    with raises_exactly(f"{tmp_path / META_FILE}: unsupported learner format 99"):
        load_learner(tmp_path)


def test_device_argument_overrides_the_saved_device(tmp_path):
    """Kills state `load_learner` 27, 28, 29: a checkpoint written by a CUDA learner (its config says cuda)
    loads onto the CPU when asked to; without the override it asks for the GPU it was saved from."""
    learner = make_learner(config(), D, H, A)
    save_learner(learner, tmp_path)
    meta = json.loads((tmp_path / META_FILE).read_text())
    meta["config"]["device"] = "cuda"
    (tmp_path / META_FILE).write_text(json.dumps(meta))
    loaded = load_learner(tmp_path, device="cpu")
    assert loaded.cfg.device == "cpu" and loaded.device == torch.device("cpu")
    assert next(loaded.actor.parameters()).device == torch.device("cpu")
    sa, sb = learner.actor.state_dict(), loaded.actor.state_dict()
    assert all(torch.equal(sa[k], sb[k]) for k in sa)
    if not torch.cuda.is_available():
        with raises_exactly("learner.device: CUDA requested but no GPU is available"):
            load_learner(tmp_path)
