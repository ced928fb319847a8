"""FastSAC-style learner: tanh-Gaussian chunk actor with a learned temperature α.

- Target of Eq. 2: a_{t+H} ~ π_θ(·|s_{t+H}, ã_{t+H}); the entropy term is folded into the reward before the
  projection, R^(H) − γ^H α log π(a_{t+H}) (FastSAC).
- Actor's Q in Eq. 1: the mean of the heads (FastSAC), plus α log π(a|s, ã).
- α is tuned toward a target entropy of `target_entropy_per_dim` × H × d.
- Eq. 4 distils the deterministic output π̄_θ = tanh(μ) (no sampling), as Eq. 3's teacher is evaluated.
"""

from __future__ import annotations

import math

import torch

from accrue.learner.agent import ChunkLearner
from accrue.learner.networks import GaussianActor, tanh_gaussian_sample


class FastSACLearner(ChunkLearner):
    algo = "fastsac"

    def _make_actor(self):
        c = self.cfg
        return GaussianActor(**self._actor_kwargs(), log_std_min=c.log_std_min, log_std_max=c.log_std_max)

    def reset_optimizers(self) -> None:
        super().reset_optimizers()
        self.log_alpha = torch.tensor(math.log(self.cfg.alpha_init), device=self.device, requires_grad=True)
        self.alpha_opt = torch.optim.Adam([self.log_alpha], lr=self.cfg.alpha_lr, fused=True)

    def optimizers(self):
        return {**super().optimizers(), "alpha": self.alpha_opt}

    @property
    def alpha(self) -> torch.Tensor:
        return self.log_alpha.exp()

    @property
    def target_entropy(self) -> float:
        return self.cfg.target_entropy_per_dim * self.horizon * self.action_dim

    def _gauss(self, shape):
        return torch.randn(shape, generator=self.gen, device=self.device)

    def _explore(self, s, ref, reset_mask):
        mean, log_std = self.actor.dist_params(s, ref)
        a = torch.tanh(mean + log_std.exp() * self._gauss(mean.shape))
        return a.view(-1, self.horizon, self.action_dim)

    def _target_noise(self, shape):  # ε for a_{t+H} ~ π(·|s_{t+H}), drawn outside the (compilable) loss
        return self._gauss((shape[0], self.horizon * self.action_dim))

    def _policy_eps(self, n):
        return self._gauss((n, self.horizon * self.action_dim))

    def _sample(self, mean, log_std, eps):
        a, log_prob = tanh_gaussian_sample(mean, log_std, eps)
        return a.view(-1, self.horizon, self.action_dim), log_prob

    def _next_action(self, s_next, ref_next, eps):
        mean, log_std = self.actor.dist_params(s_next, ref_next)
        a, log_prob = self._sample(mean, log_std, eps)
        return a, -self.alpha.detach() * log_prob

    def _policy_outputs(self, s, ref, n_cur, eps):
        mean, log_std = self.actor.dist_params(s, ref)
        a, log_prob = self._sample(mean[:n_cur], log_std[:n_cur], eps)
        a_det = torch.tanh(mean[n_cur:]).view(-1, self.horizon, self.action_dim)
        return a, log_prob, a_det

    def _actor_q(self, q_heads):
        return q_heads.mean(0)

    def _after_actor_step(self, log_prob):
        alpha_loss = -(self.log_alpha * (log_prob + self.target_entropy)).mean()
        self.alpha_opt.zero_grad(set_to_none=True)
        alpha_loss.backward()
        self.alpha_opt.step()
        return {"alpha": self.alpha.detach(), "entropy": -log_prob.mean()}
