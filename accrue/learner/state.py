"""The learner's whole training state as safetensors (every tensor) + JSON (everything else). No pickle.

Saved: actor (with its observation normaliser), critic, target critic, optimiser moments and steps, the
SAC temperature, the learner's generator, the global torch and numpy RNG states, per-env noise stds,
counters, stage index and the continual-rule tensors (EWC Fisher/anchor, RETAIN's θ_prev). Loading
then continuing gives bit-identical updates to never having stopped (on CPU).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import torch

from accrue.errors import AccrueError
from accrue.learner.agent import ChunkLearner
from accrue.learner.config import LearnerConfig
from accrue.learner.continual import make_learner

TENSORS_FILE = "learner.safetensors"
META_FILE = "learner.json"
FORMAT_VERSION = 1


def _flatten_optimizer(prefix: str, opt: torch.optim.Optimizer, tensors: dict) -> dict:
    sd = opt.state_dict()
    scalars = {}
    for pid, st in sd["state"].items():
        for key, value in st.items():
            if torch.is_tensor(value):
                tensors[f"{prefix}/state/{pid}/{key}"] = value
            else:
                scalars[f"{pid}/{key}"] = value
    return {"param_groups": sd["param_groups"], "scalars": scalars}


def _unflatten_optimizer(prefix: str, meta: dict, tensors: dict) -> dict:
    state: dict[int, dict] = {}
    for name, value in tensors.items():
        if name.startswith(prefix + "/state/"):
            pid, key = name[len(prefix) + 7 :].split("/", 1)
            state.setdefault(int(pid), {})[key] = value
    for name, value in meta["scalars"].items():
        pid, key = name.split("/", 1)
        state.setdefault(int(pid), {})[key] = value
    groups = [{**g, "betas": tuple(g["betas"])} if "betas" in g else g for g in meta["param_groups"]]
    return {"state": state, "param_groups": groups}


def training_state(learner: ChunkLearner) -> tuple[dict[str, torch.Tensor], dict]:
    tensors: dict[str, torch.Tensor] = {}
    for name, module in (
        ("actor", learner.actor),
        ("critic", learner.critic),
        ("critic_target", learner.critic_target),
    ):
        for k, v in module.state_dict().items():
            tensors[f"{name}/{k}"] = v
    optim = {name: _flatten_optimizer(f"optim/{name}", opt, tensors) for name, opt in learner.optimizers().items()}
    if hasattr(learner, "log_alpha"):
        tensors["log_alpha"] = learner.log_alpha.detach()
    tensors["noise_std"] = learner.noise_std
    if learner.cfg.exploration == "ou":  # only then: the saved bytes of every other learner stay as they were
        tensors["noise_state"] = learner.noise_state
    tensors["rng/learner"] = learner.gen.get_state()
    tensors["rng/torch"] = torch.get_rng_state()
    for group, values in (
        ("ewc_fisher", learner.ewc_fisher),
        ("ewc_anchor", learner.ewc_anchor),
        ("retain_prev", learner.retain_prev),
    ):
        for k, v in values.items():
            tensors[f"{group}/{k}"] = v
    kind, keys, pos, has_gauss, cached = np.random.get_state()
    meta = {
        "format": FORMAT_VERSION,
        "algo": learner.algo,
        "config": learner.cfg.to_dict(),
        "state_dim": learner.state_dim,
        "horizon": learner.horizon,
        "action_dim": learner.action_dim,
        "stage": learner.stage,
        "counters": dict(learner.counters),
        "optim": optim,
        "numpy_rng": {
            "kind": kind,
            "keys": keys.tolist(),
            "pos": int(pos),
            "has_gauss": int(has_gauss),
            "cached_gaussian": float(cached),
        },
    }
    if learner.layout:  # only a robot's learner: every other learner's meta stays byte for byte as it was
        meta["layout"] = learner.layout
    return tensors, meta


def load_training_state_into(learner: ChunkLearner, tensors: dict[str, torch.Tensor], meta: dict) -> None:
    dev = learner.device
    for name, module in (
        ("actor", learner.actor),
        ("critic", learner.critic),
        ("critic_target", learner.critic_target),
    ):
        sd = {k[len(name) + 1 :]: v for k, v in tensors.items() if k.startswith(name + "/")}
        if name == "actor":  # checkpoints written before the normaliser could be frozen
            sd.setdefault("obs_norm.frozen", torch.zeros((), dtype=torch.bool))
        module.load_state_dict(sd)
    if "log_alpha" in tensors:
        with torch.no_grad():
            learner.log_alpha.copy_(tensors["log_alpha"])
    for name, opt in learner.optimizers().items():
        opt.load_state_dict(_unflatten_optimizer(f"optim/{name}", meta["optim"][name], tensors))
    learner.noise_std = tensors["noise_std"].to(dev)
    if "noise_state" in tensors:
        learner.noise_state = tensors["noise_state"].to(dev)
    learner.gen.set_state(tensors["rng/learner"].cpu())
    torch.set_rng_state(tensors["rng/torch"].cpu())
    for group in ("ewc_fisher", "ewc_anchor", "retain_prev"):
        setattr(
            learner, group, {k[len(group) + 1 :]: v.to(dev) for k, v in tensors.items() if k.startswith(group + "/")}
        )
    r = meta["numpy_rng"]
    np.random.set_state(
        (r["kind"], np.array(r["keys"], dtype=np.uint32), r["pos"], r["has_gauss"], r["cached_gaussian"])
    )
    learner.stage = int(meta["stage"])
    learner.counters = dict(meta["counters"])
    learner.layout = dict(meta.get("layout") or {})


def save_learner(learner: ChunkLearner, directory: str | Path) -> None:
    from safetensors.torch import save_file

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    tensors, meta = training_state(learner)
    # safetensors refuses shared/non-contiguous storage: store independent contiguous CPU copies
    tensors = {k: v.detach().to("cpu").contiguous().clone() for k, v in tensors.items()}
    tmp = directory / (TENSORS_FILE + ".tmp")
    save_file(tensors, str(tmp))
    os.replace(tmp, directory / TENSORS_FILE)
    tmp = directory / (META_FILE + ".tmp")
    tmp.write_text(json.dumps(meta, indent=1, sort_keys=True) + "\n")
    os.replace(tmp, directory / META_FILE)


def load_learner(directory: str | Path, device: str | None = None) -> ChunkLearner:
    from safetensors.torch import load_file

    directory = Path(directory)
    try:
        meta = json.loads((directory / META_FILE).read_text())
        tensors = load_file(str(directory / TENSORS_FILE))
    except FileNotFoundError as exc:
        raise AccrueError(f"{directory}: not a learner checkpoint ({Path(exc.filename).name} missing)") from None
    except ValueError as exc:
        raise AccrueError(f"{directory}: corrupt learner checkpoint ({exc})") from None
    if meta.get("format") != FORMAT_VERSION:
        raise AccrueError(f"{directory / META_FILE}: unsupported learner format {meta.get('format')!r}")
    cfg_dict = dict(meta["config"])
    if device is not None:
        cfg_dict["device"] = device
    cfg = LearnerConfig.from_dict(cfg_dict)
    learner = make_learner(cfg, meta["state_dim"], meta["horizon"], meta["action_dim"])
    load_training_state_into(learner, {k: v.to(learner.device) for k, v in tensors.items()}, meta)
    return learner
