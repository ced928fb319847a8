"""Save → load → continue gives bit-identical updates to uninterrupted training (CPU)."""

import numpy as np
import pytest
import torch

from accrue.learner import (
    LearnerConfig,
    ReplayBuffer,
    compute_teacher_targets,
    load_learner,
    make_learner,
    retain_last_episodes,
    save_learner,
)

D, H, A = 6, 2, 3

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def buffers():
    g = torch.Generator().manual_seed(1)
    buf = ReplayBuffer(D, H, A)
    n = 200
    buf.add(
        torch.randn(n, D, generator=g),
        torch.rand(n, H, A, generator=g) * 2 - 1,
        torch.rand(n, H, A, generator=g) * 2 - 1,
        (torch.rand(n, generator=g) > 0.8).float(),
        torch.randn(n, D, generator=g),
        torch.rand(n, H, A, generator=g) * 2 - 1,
        torch.rand(n, generator=g) > 0.9,
        0,
        torch.arange(n) // 10,
    )
    return buf, retain_last_episodes(buf, 4)


def run(learner, buf, prior, teacher, steps):
    out = []
    for _ in range(steps):
        learner.act(torch.randn(4, D), torch.zeros(4, H, A))  # exploration touches the RNGs and the normaliser
        out.append(learner.train_step(buf, prior, teacher))
        np.random.rand()  # the caller's numpy RNG is also restored
    return out


@pytest.mark.parametrize("algo", ["fasttd3", "fastsac"])
def test_resume_is_bit_identical(tmp_path, algo):
    cfg = LearnerConfig(
        algo=algo,
        actor_hidden=[32],
        critic_hidden=[32],
        projector_dim=8,
        batch_size=16,
        num_atoms=11,
        utd=2,
        policy_frequency=2,
        n_step=2,
    )
    buf, prior = buffers()
    torch.manual_seed(5), np.random.seed(5)
    a = make_learner(cfg, D, H, A)
    teacher = compute_teacher_targets(a, prior.column("state"), prior.column("ref"), 32)
    run(a, buf, prior, teacher, 3)
    save_learner(a, tmp_path / "ckpt")
    uninterrupted = run(a, buf, prior, teacher, 4)

    torch.manual_seed(99), np.random.seed(99)  # scramble the globals: the load must restore them
    b = load_learner(tmp_path / "ckpt")
    resumed = run(b, buf, prior, teacher, 4)
    assert resumed == uninterrupted
    for name in ("actor", "critic", "critic_target"):
        sa, sb = getattr(a, name).state_dict(), getattr(b, name).state_dict()
        assert all(torch.equal(sa[k], sb[k]) for k in sa), name
    assert a.counters == b.counters
    assert torch.equal(a.gen.get_state(), b.gen.get_state())


def test_load_reports_missing_checkpoint(tmp_path):
    from accrue.errors import AccrueError

    with pytest.raises(AccrueError, match="not a learner checkpoint"):
        load_learner(tmp_path)
