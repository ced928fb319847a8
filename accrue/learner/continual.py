"""Stage boundaries of the continual methods: what a stage inherits (Algorithm 1 line 1), ACCRUE's cached
teacher targets (Eq. 3), EWC's Fisher, and what a stage hands over (RETAIN's merge, the normaliser freeze).

Each method's rules are one row of `accrue.methods.METHOD_RULES`; this module only applies them:
    accrue, sequential, er, ewc, retain, isolated — actor, critic, target critic and the observation
        normaliser come from the previous stage; optimiser moments, the SAC temperature and the update
        counters start afresh (a new task's gradients have a new scale); the learner's RNG continues.
    single-task — everything fresh (seed cfg.seed + stage), prior memory unused.
    ablation reset-critic — like accrue, but the critic (and its target) is re-initialised.
    isolated — like sequential; the caller keeps each stage's learner for its own task.
EWC — Fisher of the previous actor estimated on the previous stage's data (`fisher_batch`) at handoff,
    summed over finished stages; anchor θ* = previous stage's actor.
RETAIN — θ ← (1 − α)·θ_prev + α·θ with θ_prev the actor at stage start (the merged θ^{k-1}, so stage i's
    weights are discounted by (1 − α)^{k−i}): what is deployed and evaluated at every grid point
    (`ChunkLearner.deployed_actor`), merged in place at `end_stage`, and every `retain_interval` actor
    updates when that is > 0.
"""

from __future__ import annotations

import copy

import torch

from accrue.errors import AccrueError
from accrue.learner.agent import ChunkLearner
from accrue.learner.config import LearnerConfig
from accrue.learner.networks import Actor
from accrue.learner.replay import Batch
from accrue.learner.sac import FastSACLearner
from accrue.learner.td3 import FastTD3Learner
from accrue.torch_rng import seeded_torch_rng


def make_learner(cfg: LearnerConfig, state_dim: int, horizon: int, action_dim: int = 6) -> ChunkLearner:
    cls = {"fasttd3": FastTD3Learner, "fastsac": FastSACLearner}[cfg.algo]
    return cls(cfg, state_dim, horizon, action_dim)


def begin_stage(
    prev: ChunkLearner | None,
    cfg: LearnerConfig,
    state_dim: int,
    horizon: int,
    action_dim: int = 6,
    fisher_batch: Batch | None = None,
) -> ChunkLearner:
    """Algorithm 1 line 1: the stage's learner, initialised per the method (module docstring)."""
    if prev is None:
        return make_learner(cfg, state_dim, horizon, action_dim)
    if (prev.state_dim, prev.horizon, prev.action_dim) != (state_dim, horizon, action_dim):
        raise AccrueError(
            f"begin_stage: previous learner has state/chunk dims "
            f"{(prev.state_dim, prev.horizon, prev.action_dim)}, this stage needs "
            f"{(state_dim, horizon, action_dim)}"
        )
    plan = cfg.rules
    stage = prev.stage + 1
    if not plan.inherit_actor:
        learner = make_learner(cfg.replace(seed=cfg.seed + stage), state_dim, horizon, action_dim)
        learner.stage = stage
        return learner
    learner = make_learner(cfg, state_dim, horizon, action_dim)
    learner.stage = stage
    learner.gen.set_state(prev.gen.get_state())
    learner.actor.load_state_dict(prev.actor.state_dict())
    if plan.inherit_critic:
        learner.critic.load_state_dict(prev.critic.state_dict())
        learner.critic_target.load_state_dict(prev.critic_target.state_dict())
    else:  # reset-critic: fresh critic from a stage-dependent seed
        with seeded_torch_rng(cfg.seed + stage):
            learner.critic = learner._make_critic().to(learner.device)
        learner.critic_target.load_state_dict(learner.critic.state_dict())
    learner.reset_optimizers()  # optimisers must point at the (possibly new) parameters
    if plan.ewc_penalty:
        if fisher_batch is None:
            raise AccrueError("method ewc: begin_stage needs fisher_batch (previous stage's transitions)")
        fisher = estimate_fisher(prev.actor, fisher_batch, generator=learner.gen)
        learner.ewc_fisher = {k: fisher[k] + prev.ewc_fisher.get(k, 0.0) for k in fisher}
        learner.ewc_anchor = {k: v.detach().clone() for k, v in prev.actor.named_parameters()}
    if plan.merge:
        learner.retain_prev = {k: v.detach().clone() for k, v in learner.actor.named_parameters()}
    return learner


def end_stage(learner: ChunkLearner) -> ChunkLearner:
    """The stage's handoff (θ^k, ψ^k): RETAIN merges its actor; with obs_norm_update "first-stage" the
    normaliser's statistics are frozen from here on (the learner's later stages read s through one map)."""
    if learner.rules.merge:
        learner.merge_actor()
    if learner.cfg.obs_norm_update == "first-stage":
        learner.actor.obs_norm.freeze()
    return learner


def _as_actor(actor) -> tuple[Actor, callable]:
    if isinstance(actor, ChunkLearner):
        return actor.actor, actor._ref_in
    return actor, (lambda ref: ref)


@torch.no_grad()
def compute_teacher_targets(actor, states: torch.Tensor, refs: torch.Tensor, batch_size: int = 1024) -> torch.Tensor:
    """Eq. 3: â_j = π̄_{θ^{k−1}}(s_j, ã_j) for every retained transition j — the frozen previous actor's
    deterministic output (no sampling, no exploration noise), computed once at stage start and cached.

    `actor` is the previous stage's learner (its no-reference setting is honoured) or an Actor module.
    Returns (N, H, d) float32 on the states' device.
    """
    net, ref_in = _as_actor(actor)
    was_training = net.training
    net.eval()
    device = next(net.parameters()).device
    out = []
    for i in range(0, states.shape[0], batch_size):
        s = states[i : i + batch_size].to(device, torch.float32)
        r = refs[i : i + batch_size].to(device, torch.float32)
        out.append(net.deterministic(s, ref_in(r)).float().to(states.device))
    net.train(was_training)
    if not out:
        return torch.zeros((0, net.horizon, net.action_dim), device=states.device)
    return torch.cat(out, 0)


def estimate_fisher(
    actor, batch: Batch, generator: torch.Generator | None = None, chunk: int = 128
) -> dict[str, torch.Tensor]:
    """Diagonal Fisher of the actor on a batch of the previous stage's transitions (EWC).

    The actor is read as a Gaussian policy N(π̄_θ(s, ã), I) (σ is absorbed in ewc_lambda, as Continual World
    does for the mean term). With a sampled action a = π̄ + v, v ~ N(0, I), the score is v·∂π̄/∂θ, so
    F = E_{s, v}[(v·∂π̄/∂θ)²] = E_s[Σ_o (∂π̄_o/∂θ)²]. Per-sample gradients come from torch.func.vmap.
    """
    from torch.func import functional_call, grad, vmap

    net, ref_in = _as_actor(actor)
    params = {k: v.detach() for k, v in net.named_parameters()}
    buffers = {k: v.detach() for k, v in net.named_buffers()}
    device = next(net.parameters()).device

    def projected_output(p, s, r, v):
        out = functional_call(net, (p, buffers), (s.unsqueeze(0), r.unsqueeze(0)))
        return (out.flatten() * v).sum()

    per_sample_grad = vmap(grad(projected_output), in_dims=(None, 0, 0, 0))
    fisher = {k: torch.zeros_like(v) for k, v in params.items()}
    n = len(batch)
    for i in range(0, n, chunk):
        s = batch.state[i : i + chunk].to(device)
        r = ref_in(batch.ref[i : i + chunk].to(device))
        v = torch.randn((s.shape[0], net.horizon * net.action_dim), generator=generator, device=device)
        grads = per_sample_grad(params, s, r, v)
        for k in fisher:
            fisher[k] += grads[k].square().sum(0)
    return {k: f / max(n, 1) for k, f in fisher.items()}


def copy_learner(learner: ChunkLearner) -> ChunkLearner:
    """A deep copy (e.g. the Isolated method's per-task checkpoint kept in memory)."""
    return copy.deepcopy(learner)
