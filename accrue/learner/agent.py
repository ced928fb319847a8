"""ChunkLearner: the off-policy actor-critic over action chunks that FastTD3 and FastSAC variants share.

One call to `update(current, prior)` is one gradient update (Algorithm 1, lines 8–9):
  - critic ψ on B^k by cross-entropy to the projected Eq. 2 target (B^k ∪ B^{<k} only for `er` and the
    `critic-all-replay` ablation — ACCRUE's critic never reads the prior batch);
  - every `policy_frequency`-th update, actor θ on Eq. 5 = Eq. 1 on B^k + λ · Eq. 4 on a separate, equally
    sized minibatch of B^{<k} carrying the cached Eq. 3 targets (ACCRUE), or the baseline's rule;
  - Polyak averaging of the target critic.
`train_step(buffer, prior, teacher)` samples `utd` such minibatch pairs from the learner's own generator
and runs that many updates, so a resumed learner samples exactly what an uninterrupted one would.
All randomness of the learner (sampling, reference dropout, exploration and policy noise) comes from
`self.gen`, which is part of the saved state.
"""

from __future__ import annotations

import contextlib
import copy

import numpy as np
import torch

from accrue.errors import AccrueError
from accrue.learner import losses
from accrue.learner.config import LearnerConfig
from accrue.learner.distributional import expected_value, make_support
from accrue.learner.networks import Actor, Critic
from accrue.learner.replay import Batch, ReplayBuffer
from accrue.torch_rng import seeded_torch_rng


class ChunkLearner:
    algo = "base"

    def __init__(self, cfg: LearnerConfig, state_dim: int, horizon: int, action_dim: int = 6):
        self.cfg, self.state_dim, self.horizon, self.action_dim = cfg, state_dim, horizon, action_dim
        self.rules = cfg.rules  # the continual method's rules (accrue.methods)
        self.device = torch.device(cfg.device)
        if self.device.type == "cuda" and not torch.cuda.is_available():
            raise AccrueError("learner.device: CUDA requested but no GPU is available")
        # networks are initialised from cfg.seed without touching the global torch RNG
        with seeded_torch_rng(cfg.seed):  # built on the CPU, then moved: only the CPU's generator draws
            self.actor = self._make_actor().to(self.device)
            self.critic = self._make_critic().to(self.device)
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        self.support = make_support(cfg.v_min, cfg.v_max, cfg.num_atoms, self.device)
        self.gen = torch.Generator(device=self.device)
        self.gen.manual_seed(cfg.seed)
        self.noise_std = torch.zeros(0, device=self.device)  # per-env exploration std (FastTD3)
        self.noise_state = torch.zeros(0, device=self.device)  # per-env OU state (exploration "ou")
        self.counters = {"updates": 0, "actor_updates": 0, "merges": 0}
        self.stage = 0
        # what s and a are made of on a robot ({"action_keys": [...], "cameras": [...]}; empty in the simulator):
        # saved with the learner, so a later stage on other keys or cameras is refused (stages.steps.robot_env)
        self.layout: dict = {}
        # continual-rule state (continual.py fills these at stage start)
        self.ewc_anchor: dict[str, torch.Tensor] = {}
        self.ewc_fisher: dict[str, torch.Tensor] = {}
        self.retain_prev: dict[str, torch.Tensor] = {}
        self.reset_optimizers()
        self._critic_loss_fn = self._critic_loss
        self._actor_loss_fn = self._actor_loss
        if cfg.compile:
            self._critic_loss_fn = torch.compile(self._critic_loss, mode=cfg.compile_mode)
            self._actor_loss_fn = torch.compile(self._actor_loss, mode=cfg.compile_mode)

    # ---- construction ---------------------------------------------------------------------
    def _actor_kwargs(self) -> dict:
        c = self.cfg
        return dict(
            state_dim=self.state_dim,
            horizon=self.horizon,
            action_dim=self.action_dim,
            hidden=c.actor_hidden,
            projector_dim=c.projector_dim,
            layer_norm=c.layer_norm,
            residual=c.actor_residual,
            init_scale=c.actor_init_scale,
            obs_normalization=c.obs_normalization,
            obs_norm_min_std=c.obs_norm_min_std,
            obs_norm_clip=c.obs_norm_clip,
            obs_norm_fixed_tail=c.obs_norm_fixed_tail,
            delta_bound=c.delta_bound,
        )

    def _make_actor(self) -> Actor:
        return Actor(**self._actor_kwargs())

    def _make_critic(self) -> Critic:
        c = self.cfg
        return Critic(
            self.state_dim, self.horizon, self.action_dim, c.critic_hidden, c.projector_dim, c.num_atoms, c.layer_norm
        )

    def _adamw(self, params, lr):
        # fused AdamW: one kernel for all parameters (≈4x faster step than the default on CPU)
        return torch.optim.AdamW(params, lr=lr, weight_decay=self.cfg.weight_decay, fused=True)

    def reset_optimizers(self) -> None:
        self.actor_opt = self._adamw(self.actor.parameters(), self.cfg.actor_lr)
        self.critic_opt = self._adamw(self.critic.parameters(), self.cfg.critic_lr)

    def optimizers(self) -> dict[str, torch.optim.Optimizer]:
        return {"actor": self.actor_opt, "critic": self.critic_opt}

    def _autocast(self):
        if self.cfg.amp and self.device.type == "cuda":
            return torch.autocast("cuda", dtype=torch.bfloat16)
        return contextlib.nullcontext()

    # ---- acting -------------------------------------------------------------------------------
    def _ref_in(self, ref: torch.Tensor) -> torch.Tensor:
        """ã as actor and critic see it: zeros in the no-reference ablation (π_θ(s), Q_ψ(s, a) instead of
        π_θ(s, ã), Q_ψ(s, a, ã))."""
        return ref if self.rules.use_reference else torch.zeros_like(ref)

    def deployed_actor(self) -> Actor:
        """The actor the method would deploy if the stage ended now: RETAIN's discounted interpolation
        (1−α)·θ_prev + α·θ (a copy; the training actor is untouched), the actor itself otherwise."""
        if not (self.rules.merge and self.retain_prev):
            return self.actor
        merged = copy.deepcopy(self.actor)
        interpolate_into(merged, self.retain_prev, self.cfg.retain_alpha)
        return merged

    @torch.no_grad()
    def act(self, state, ref, explore: bool = True, reset_mask=None):
        """Action chunk (B, H, d) in [-1, 1] for states (B, D) and references (B, H, d).

        explore=True adds the algorithm's exploration noise; explore=False gives π̄_θ (deterministic, for
        evaluation and the Eq. 3 teacher).
        reset_mask (B,) marks envs that just reset: FastTD3 redraws their noise std there.
        """
        as_numpy = isinstance(state, np.ndarray)
        s = torch.as_tensor(state, dtype=torch.float32, device=self.device)
        r = torch.as_tensor(ref, dtype=torch.float32, device=self.device).view(-1, self.horizon, self.action_dim)
        with self._autocast():
            a = (
                self._explore(s, self._ref_in(r), reset_mask)
                if explore
                else self.actor.deterministic(s, self._ref_in(r))
            )
        a = a.float()
        return a.cpu().numpy() if as_numpy else a

    @torch.no_grad()
    def act_with(self, actor: Actor, state: np.ndarray, ref: np.ndarray) -> np.ndarray:
        """π̄ of a given actor module (e.g. deployed_actor()) under this learner's input rules."""
        s = torch.as_tensor(state, dtype=torch.float32, device=self.device)
        r = torch.as_tensor(ref, dtype=torch.float32, device=self.device).view(-1, self.horizon, self.action_dim)
        with self._autocast():
            return actor.deterministic(s, self._ref_in(r)).float().cpu().numpy()

    def _explore(self, s, ref, reset_mask):
        raise NotImplementedError

    # ---- one gradient update ----------------------------------------------------------------
    def _dropout_keep(self, n: int) -> torch.Tensor:
        """(n, 1, 1) mask: 0 for the fraction p of rows whose ã is replaced by zeros (both networks)."""
        keep = torch.rand(n, generator=self.gen, device=self.device) >= self.cfg.ref_dropout
        return keep.float().view(n, 1, 1)

    def _discount(self, batch: Batch) -> torch.Tensor:
        if batch.discount is not None:
            return batch.discount
        return (self.cfg.gamma**self.horizon) * (1.0 - batch.done)

    def update(self, current: Batch, prior: Batch | None = None) -> dict[str, float]:
        """One gradient update (critic; actor every policy_frequency-th call; target Polyak). Unlike
        train_step it does not feed the observation normaliser."""
        return {k: float(v) for k, v in self._update(current, prior).items()}

    def _update(self, current: Batch, prior: Batch | None, actor_on: bool = True) -> dict[str, torch.Tensor]:
        cfg = self.cfg
        if prior is not None and len(prior) == 0:
            prior = None
        critic_batch = Batch.cat(current, prior) if (prior is not None and self.rules.critic_on_prior) else current
        info = self._critic_update(critic_batch)
        self.counters["updates"] += 1
        if actor_on and self.counters["updates"] % cfg.policy_frequency == 0:
            info.update(self._actor_update(current, prior))
            self.counters["actor_updates"] += 1
            if self.rules.merge and cfg.retain_interval and self.counters["actor_updates"] % cfg.retain_interval == 0:
                self.merge_actor()
        # Polyak averaging of the target critic ψ' ← (1 − τ)ψ' + τψ
        torch._foreach_lerp_(list(self.critic_target.parameters()), list(self.critic.parameters()), cfg.tau)
        return info

    def _critic_update(self, b: Batch) -> dict[str, float]:
        keep = self._dropout_keep(len(b))
        noise = self._target_noise(b.action.shape)
        with self._autocast():
            loss, q_mean = self._critic_loss_fn(
                b.state, b.action, b.ref, b.reward, b.next_state, b.next_ref, self._discount(b), keep, noise
            )
        self.critic_opt.zero_grad(set_to_none=True)
        loss.backward()
        if self.cfg.max_grad_norm > 0:
            torch.nn.utils.clip_grad_norm_(self.critic.parameters(), self.cfg.max_grad_norm)
        self.critic_opt.step()
        return {"critic_loss": loss.detach(), "q_mean": q_mean}

    def _critic_loss(self, s, a, ref, reward, s_next, ref_next, discount, keep, noise):
        """Cross-entropy of Q_ψ(s, a, ã) to the projected Eq. 2 target. Reference dropout zeroes ã (and ã')
        for the same rows in both networks."""
        norm = self.actor.obs_norm
        ref_next_in, ref_in = self._ref_in(ref_next * keep), self._ref_in(ref * keep)
        with torch.no_grad():
            a_next, bonus = self._next_action(s_next, ref_next_in, noise)
            next_logits = self.critic_target(norm(s_next), a_next, ref_next_in)
            target = losses.td_target(next_logits.float(), reward, discount, self.support, self.cfg.use_cdq, bonus)
        logits = self.critic(norm(s), a, ref_in).float()
        q_mean = expected_value(torch.softmax(logits.detach(), -1), self.support).mean()
        return losses.critic_loss(logits, target), q_mean

    def _actor_update(self, cur: Batch, prior: Batch | None) -> dict[str, float]:
        cfg = self.cfg
        rl = Batch.cat(cur, prior) if (prior is not None and self.rules.actor_rl_on_prior) else cur
        distill = self.rules.distill and prior is not None
        if distill and prior.teacher is None:
            raise AccrueError("ACCRUE needs cached teacher targets on the prior batch (Batch.with_teacher)")
        student_s, student_ref, targets = self._distill_inputs(prior) if distill else (None, None, None)
        keep = self._dropout_keep(len(rl))
        eps = self._policy_eps(len(rl))
        self.critic.requires_grad_(False)  # the actor loss only moves θ
        with self._autocast():
            out = self._actor_loss_fn(rl.state, rl.ref, keep, eps, student_s, student_ref, targets, self.anchor_beta())
        self.critic.requires_grad_(True)
        loss = out["actor_loss"]
        if self.rules.ewc_penalty and self.ewc_fisher:
            params = dict(self.actor.named_parameters())
            out["ewc_penalty"] = losses.ewc_penalty(params, self.ewc_anchor, self.ewc_fisher)
            loss = loss + cfg.ewc_lambda * out["ewc_penalty"]
        self.actor_opt.zero_grad(set_to_none=True)
        loss.backward()
        if cfg.max_grad_norm > 0:
            torch.nn.utils.clip_grad_norm_(self.actor.parameters(), cfg.max_grad_norm)
        self.actor_opt.step()
        info = {k: v.detach() for k, v in out.items() if k != "_log_prob"}
        info.update(self._after_actor_step(out.get("_log_prob")))
        return info

    def _distill_inputs(self, prior: Batch):
        """Eq. 4's student inputs and targets. `stored` (the paper): π_θ(s_j, ã_j) → â_j. `fresh`: the current
        base policy's chunk ã'_j at s_j replaces ã_j (reference shift after re-fine-tuning), same target
        â_j = π̄_{θ^{k-1}}(s_j, ã_j). `both`: the two sets of rows together."""
        mode = self.cfg.distill_inputs
        if mode == "stored":
            return prior.state, prior.ref, prior.teacher
        if prior.fresh_ref is None:
            raise AccrueError(f"learner.distill_inputs {mode}: the prior batch has no fresh reference chunks")
        if mode == "fresh":
            return prior.state, prior.fresh_ref, prior.teacher
        return (
            torch.cat([prior.state, prior.state], 0),
            torch.cat([prior.ref, prior.fresh_ref], 0),
            torch.cat([prior.teacher, prior.teacher], 0),
        )

    def anchor_beta(self) -> torch.Tensor | float:
        """Eq. 1's β for the next actor update: cfg.beta, or, with beta_anneal_updates, a linear ramp from
        beta_start to beta over the stage's first actor updates (a tensor then, so a compiled loss is not
        re-traced for every value). The no-anchor ablation has β = 0 throughout."""
        cfg, done = self.cfg, self.counters["actor_updates"]
        if self.rules.zero_beta or not cfg.beta_anneal_updates:
            return cfg.effective_beta
        left = max(0.0, 1.0 - done / cfg.beta_anneal_updates)
        return torch.tensor(cfg.beta + (cfg.beta_start - cfg.beta) * left, device=self.device)

    def _actor_loss(self, s, ref, keep, eps, prior_s, prior_ref, prior_teacher, beta):
        """Eq. 5 = Eq. 1 on the current batch + λ · Eq. 4 on the prior batch (one actor forward for both)."""
        n = s.shape[0]
        ref_in = self._ref_in(ref * keep)
        if prior_s is not None:  # batch the student's prior inputs with the current ones
            s_all = torch.cat([s, prior_s], 0)
            ref_all = torch.cat([ref_in, self._ref_in(prior_ref)], 0)
        else:
            s_all, ref_all = s, ref_in
        a, log_prob, a_det = self._policy_outputs(s_all, ref_all, n, eps)
        logits = self.critic(self.actor.obs_norm(s), a, ref_in).float()
        q = self._actor_q(expected_value(torch.softmax(logits, -1), self.support))
        alpha = self.alpha.detach() if log_prob is not None else 0.0
        loss_cur = losses.actor_loss_current(q, a.float(), ref, beta, log_prob, alpha)
        out = {"loss_cur": loss_cur}
        loss_prior = None
        if prior_s is not None:
            loss_prior = losses.distill_loss_prior(a_det.float(), prior_teacher)
            out["loss_prior"] = loss_prior
        out["actor_loss"] = losses.actor_loss_total(loss_cur, loss_prior, self.cfg.lam)
        if log_prob is not None:
            out["_log_prob"] = log_prob.detach()
        return out

    # ---- algorithm-specific pieces (td3.py / sac.py) ---------------------------------------
    def _target_noise(self, shape) -> torch.Tensor | None:
        return None

    def _policy_eps(self, n: int) -> torch.Tensor | None:
        return None

    def _next_action(self, s_next, ref_next, noise):
        raise NotImplementedError

    def _policy_outputs(self, s, ref, n_cur, eps):
        """(a for the first n_cur rows, log π or None, deterministic output of the remaining rows)."""
        raise NotImplementedError

    def _actor_q(self, q_heads: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def _after_actor_step(self, log_prob) -> dict[str, torch.Tensor]:
        return {}

    @property
    def alpha(self) -> torch.Tensor:
        raise AttributeError("this learner has no temperature")

    # ---- UTD loop over buffers ----------------------------------------------------------------
    def sample(self, buffer: ReplayBuffer, n: int) -> Batch:
        return buffer.sample(n, self.gen, self.cfg.n_step, self.cfg.gamma)

    def train_step(
        self,
        buffer: ReplayBuffer,
        prior: ReplayBuffer | None = None,
        teacher: torch.Tensor | None = None,
        fresh_ref: torch.Tensor | None = None,
    ) -> dict[str, float]:
        """`utd` updates, each on a fresh current minibatch and (1:1) a prior minibatch when a prior memory
        is in use by the method. `teacher` (and `fresh_ref` for distill_inputs fresh/both) are indexed like
        the prior memory's rows. Returns the mean of each reported figure; {} (and no update at all)
        while the current buffer holds fewer than `learning_starts` transitions."""
        if len(buffer) < self.cfg.learning_starts:  # critic warm-up: wait for N transitions of B^k
            return {}
        use_prior = prior is not None and len(prior) > 0 and self.uses_prior_memory
        actor_on = len(buffer) >= self.cfg.actor_learning_starts  # the critic's own warm-up on B^k
        sums: dict[str, torch.Tensor] = {}  # tensors until the end: one device sync per train_step
        counts: dict[str, int] = {}
        for _ in range(self.cfg.utd):
            cur = self.sample(buffer, self.cfg.batch_size).to_device(self.device)
            # running mean/std of s from uniform samples of the current task's buffer (warmup included,
            # whoever collected it); prior-task memory never moves the statistics
            self.actor.obs_norm.update(cur.state)
            pri = None
            if use_prior:
                pri = self.sample(prior, self.cfg.batch_size).to_device(self.device)
                if self.rules.distill:
                    if teacher is None:
                        raise AccrueError(
                            "ACCRUE needs teacher targets for the prior memory (compute_teacher_targets at stage start)"
                        )
                    pri = pri.with_teacher(teacher, fresh_ref)
            for k, v in self._update(cur, pri, actor_on).items():
                sums[k] = sums.get(k, 0.0) + v
                counts[k] = counts.get(k, 0) + 1
        return {k: float(sums[k]) / counts[k] for k in sums}

    @property
    def uses_prior_memory(self) -> bool:
        return self.rules.uses_prior_memory

    @torch.no_grad()
    def merge_actor(self) -> None:
        """RETAIN: θ ← (1 − α)·θ_prev + α·θ in place (nothing to merge before a previous actor exists)."""
        if not self.retain_prev:
            return
        interpolate_into(self.actor, self.retain_prev, self.cfg.retain_alpha)
        self.counters["merges"] += 1


@torch.no_grad()
def interpolate_into(actor: Actor, previous: dict[str, torch.Tensor], alpha: float) -> None:
    """θ ← (1 − α)·θ_prev + α·θ for every parameter of `actor` (RETAIN's weight interpolation)."""
    for name, p in actor.named_parameters():
        p.copy_((1 - alpha) * previous[name] + alpha * p)
