"""Issue 18 item 5: the optimiser settings β = 0 is re-examined with (learning starts, gradient clipping,
learning rates) reach every method's updates."""

import pytest
import torch

from accrue.errors import AccrueError
from accrue.learner import LearnerConfig, ReplayBuffer, make_learner

D, H, A = 6, 2, 3
SMALL = dict(
    actor_hidden=[32, 32], critic_hidden=[32], projector_dim=16, batch_size=32, num_atoms=21, utd=2, policy_frequency=1
)

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def make_buffer(n: int, seed: int = 0) -> ReplayBuffer:
    g = torch.Generator().manual_seed(seed)
    buf = ReplayBuffer(D, H, A)
    buf.add(
        torch.randn(n, D, generator=g),
        torch.rand(n, H, A, generator=g) * 2 - 1,
        torch.rand(n, H, A, generator=g) * 1.6 - 0.8,
        (torch.rand(n, generator=g) > 0.7).float() * 3,
        torch.randn(n, D, generator=g),
        torch.rand(n, H, A, generator=g) * 1.6 - 0.8,
        torch.rand(n, generator=g) > 0.9,
        0,
        torch.arange(n) // 8,
    )
    return buf


def params(module) -> list[torch.Tensor]:
    return [p.detach().clone() for p in module.parameters()]


@pytest.mark.parametrize("algo", ["fasttd3", "fastsac"])
@pytest.mark.parametrize("method", ["accrue", "sequential", "single-task"])
def test_no_update_before_learning_starts(algo, method):
    learner = make_learner(LearnerConfig(algo=algo, method=method, learning_starts=100, **SMALL), D, H, A)
    actor, critic = params(learner.actor), params(learner.critic)
    assert learner.train_step(make_buffer(99)) == {}  # 99 < 100 transitions: nothing moves
    assert learner.counters["updates"] == 0
    assert all(torch.equal(a, b) for a, b in zip(actor, params(learner.actor)))
    assert all(torch.equal(a, b) for a, b in zip(critic, params(learner.critic)))
    info = learner.train_step(make_buffer(100))  # 100 transitions: learning starts
    assert "critic_loss" in info and learner.counters["updates"] == 2
    assert any(not torch.equal(a, b) for a, b in zip(critic, params(learner.critic)))


def grad_norm(module) -> float:
    return float(
        torch.linalg.vector_norm(torch.stack([p.grad.norm() for p in module.parameters() if p.grad is not None]))
    )


@pytest.mark.parametrize("algo", ["fasttd3", "fastsac"])
def test_gradients_are_clipped_to_max_grad_norm(algo):
    buf = make_buffer(256)
    clipped = make_learner(LearnerConfig(algo=algo, max_grad_norm=1e-3, **SMALL), D, H, A)
    clipped.update(clipped.sample(buf, 32))
    # the grads stay on the parameters after the step: the ones each optimizer applied
    assert grad_norm(clipped.critic) <= 1e-3 * (1 + 1e-4)
    assert grad_norm(clipped.actor) <= 1e-3 * (1 + 1e-4)
    free = make_learner(LearnerConfig(algo=algo, max_grad_norm=0.0, **SMALL), D, H, A)
    free.update(free.sample(buf, 32))
    assert grad_norm(free.critic) > 1e-2  # unclipped the same update is far larger: the clip did bind


def test_learning_rates_reach_the_optimizers():
    learner = make_learner(LearnerConfig(actor_lr=3e-4, critic_lr=2e-4, **SMALL), D, H, A)
    assert [g["lr"] for g in learner.actor_opt.param_groups] == [3e-4]
    assert [g["lr"] for g in learner.critic_opt.param_groups] == [2e-4]


@pytest.mark.parametrize("bad", [-1, 1.5, True])
def test_learning_starts_must_be_a_non_negative_integer(bad):
    with pytest.raises(AccrueError, match="learner.learning_starts"):
        LearnerConfig(learning_starts=bad)
