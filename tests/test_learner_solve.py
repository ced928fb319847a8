"""Both learners solve a small continuous-control problem made for the test, clearly beating the reference.

The problem: one chunk per episode. A state s ~ N(0, I) hides a target chunk T(s) = 0.6·tanh(W s); the base
policy proposes ã = T(s) + b(s) + noise, with a systematic state-dependent error b(s) = 0.25·tanh(V s) (so
imitating the reference cannot solve it) and noise σ = 0.1 per entry. Executing a chunk pays reward 1 and
terminates when ‖a − T(s)‖ < ε = 0.3, else 0 — sparse, like the assembly tasks. The actor must learn the
state-dependent correction from the sparse reward through the critic.
"""

import pytest
import torch

from accrue.learner import LearnerConfig, ReplayBuffer, make_learner

D, H, A, EPS = 4, 2, 2, 0.3


pytestmark = pytest.mark.usefixtures("one_torch_thread")


class RefineTask:
    def __init__(self, seed):
        self.g = torch.Generator().manual_seed(seed)
        self.w = torch.randn(D, H * A, generator=self.g)
        self.v = torch.randn(D, H * A, generator=self.g)

    def target(self, s):
        return 0.6 * torch.tanh(s @ self.w).view(-1, H, A)

    def observe(self, n):
        s = torch.randn(n, D, generator=self.g)
        bias = 0.25 * torch.tanh(s @ self.v).view(-1, H, A)
        ref = (self.target(s) + bias + 0.1 * torch.randn(n, H, A, generator=self.g)).clamp(-1, 1)
        return s, ref

    def reward(self, s, a):
        return ((a - self.target(s)).flatten(1).norm(dim=1) < EPS).float()


def train_and_evaluate(algo):
    task = RefineTask(0)
    cfg = LearnerConfig(
        algo=algo,
        actor_hidden=[128, 128],
        critic_hidden=[128, 128],
        projector_dim=32,
        batch_size=128,
        num_atoms=21,
        v_min=-0.5,
        v_max=1.5,
        utd=2,
        policy_frequency=2,
        std_max=0.2,
        ref_dropout=0.1,
        actor_lr=1e-3,
        critic_lr=1e-3,
        seed=0,
    )
    learner = make_learner(cfg, D, H, A)
    buf = ReplayBuffer(D, H, A)
    n_env, episode = 32, 0
    for step in range(450):
        s, ref = task.observe(n_env)
        a = learner.act(s, ref, explore=True, reset_mask=torch.ones(n_env, dtype=torch.bool))
        r = task.reward(s, a)
        s_next, ref_next = task.observe(n_env)  # unused: every episode terminates after one chunk
        buf.add(
            s,
            a,
            ref,
            r,
            s_next,
            ref_next,
            torch.ones(n_env, dtype=torch.bool),
            0,
            torch.arange(episode, episode + n_env),
        )
        episode += n_env
        if step >= 10:  # warmup collection first
            learner.train_step(buf)
    s, ref = task.observe(2000)
    actor_success = task.reward(s, learner.act(s, ref, explore=False)).mean().item()
    reference_success = task.reward(s, ref).mean().item()
    return actor_success, reference_success


@pytest.mark.parametrize("algo", ["fasttd3", "fastsac"])
def test_learner_refines_reference_toward_hidden_target(algo):
    actor, reference = train_and_evaluate(algo)
    assert reference < 0.2
    assert actor > reference + 0.3, (actor, reference)
