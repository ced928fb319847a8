"""FastTD3-style learner: deterministic chunk actor, per-env exploration noise, target-policy smoothing.

- Exploration: each env draws its own noise std uniformly in [std_min, std_max], redrawn when it resets;
  the noise is white (a fresh draw every control step, FastTD3) or, with exploration "ou", an
  Ornstein-Uhlenbeck process per env and action dimension carried across chunks, so a deviation is held
  for about noise_steps control steps (temporally correlated exploration, Eberhard et al. ICLR 2023).
- Target action a_{t+H} of Eq. 2: π_θ(s_{t+H}, ã_{t+H}) plus clipped Gaussian smoothing noise (FastTD3 uses
  the online actor here, no target actor).
- Actor's Q in Eq. 1: the smaller of the two heads' expectations with clipped double-Q, else their mean.
"""

from __future__ import annotations

import math

import torch

from accrue.learner.agent import ChunkLearner


class FastTD3Learner(ChunkLearner):
    algo = "fasttd3"

    def _draw_std(self, n: int) -> torch.Tensor:
        c = self.cfg
        return c.std_min + (c.std_max - c.std_min) * torch.rand(n, generator=self.gen, device=self.device)

    def _explore(self, s, ref, reset_mask):
        n = s.shape[0]
        if self.noise_std.shape[0] != n:
            self.noise_std = self._draw_std(n)
        elif reset_mask is not None:
            mask = torch.as_tensor(reset_mask, dtype=torch.bool, device=self.device)
            self.noise_std = torch.where(mask, self._draw_std(n), self.noise_std)
        a = self.actor(s, ref)
        unit = self._ou_noise(a.shape, reset_mask) if self.cfg.exploration == "ou" else self._white(a.shape)
        return (a + unit * self.noise_std.view(-1, 1, 1)).clamp(-1.0, 1.0)

    def _white(self, shape):
        return torch.randn(shape, generator=self.gen, device=self.device)

    def _ou_noise(self, shape, reset_mask):
        """Unit-variance OU noise for H control steps: x ← ρ·x + √(1−ρ²)·ε with ρ = exp(−1/noise_steps);
        envs that just reset start from a stationary draw x ~ N(0, 1)."""
        n, horizon, d = shape
        fresh = self._white((n, d))
        if self.noise_state.shape != (n, d):
            self.noise_state = fresh
        elif reset_mask is not None:
            mask = torch.as_tensor(reset_mask, dtype=torch.bool, device=self.device).view(-1, 1)
            self.noise_state = torch.where(mask, fresh, self.noise_state)
        rho = math.exp(-1.0 / self.cfg.noise_steps)
        steps = self._white(shape)
        out = torch.empty(shape, device=self.device)
        for h in range(horizon):
            out[:, h] = self.noise_state
            self.noise_state = rho * self.noise_state + math.sqrt(1 - rho * rho) * steps[:, h]
        return out

    def _target_noise(self, shape):
        c = self.cfg
        noise = torch.randn(shape, generator=self.gen, device=self.device) * c.policy_noise
        return noise.clamp(-c.noise_clip, c.noise_clip)

    def _next_action(self, s_next, ref_next, noise):
        return (self.actor(s_next, ref_next) + noise).clamp(-1.0, 1.0), None

    def _policy_outputs(self, s, ref, n_cur, eps):
        a = self.actor(s, ref)
        return a[:n_cur], None, a[n_cur:]

    def _actor_q(self, q_heads):
        return q_heads.min(0).values if self.cfg.use_cdq else q_heads.mean(0)
