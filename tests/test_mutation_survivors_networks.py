"""Tests written to kill mutants of accrue/learner/networks.py, distributional.py and config.py that survived
(or that no test reached) in issue 23's mutmut sweep over accrue/learner (docs/MUTATION.md). Each test's
docstring names the mutmut ids it kills.

The expected values are the modules' formulas written out again by hand (or, for the tanh-Gaussian
log-probability, the textbook change-of-variables form) on tiny tensors; the networks are built here,
a few units wide, on the CPU.
"""

from __future__ import annotations

import math

import pytest
import torch

from accrue.errors import AccrueError
from accrue.learner.config import LearnerConfig
from accrue.learner.distributional import categorical_cross_entropy, project_target
from accrue.learner.networks import (
    Actor,
    Critic,
    EnsembleLayerNorm,
    EnsembleLinear,
    GaussianActor,
    RunningNorm,
    pre_tanh,
    tanh_gaussian_sample,
)

pytestmark = pytest.mark.usefixtures("one_torch_thread")

D, H, A = 5, 2, 3  # state dim, chunk horizon, action dim
CHUNK = H * A


def inputs(n: int, seed: int = 0, dtype=torch.float32):
    g = torch.Generator().manual_seed(seed)
    s = torch.randn(n, D, generator=g, dtype=torch.float64) * 2
    ref = torch.rand(n, H, A, generator=g, dtype=torch.float64) * 1.8 - 0.9
    return s.to(dtype), ref.to(dtype)


# ------------------------------------------------------------------------------------------- RunningNorm
def test_running_norm_clip_bounds_z_on_both_sides_below_one():
    """Kills networks `RunningNorm.forward` 6 (clip ignored), 8, 9, 10, 11 (one bound dropped or the clip
    used as the lower bound), 14 (a clip of 0.5 taken as `clip > 1`: no clipping)."""
    rn = RunningNorm(4, clip=0.5)
    rn.mean.copy_(torch.tensor([0.0, 1.0, 2.0, 3.0]))
    rn.var.copy_(torch.tensor([1.0, 4.0, 0.25, 1.0]))
    std = (rn.var + 1e-6).sqrt()
    z = torch.tensor([[-3.0, 0.2, 3.0, -0.1], [2.0, -0.4, -2.5, 0.3]])
    x = rn.mean + z * std
    out = rn(x)
    want = torch.tensor([[-0.5, 0.2, 0.5, -0.1], [0.5, -0.4, -0.5, 0.3]])
    torch.testing.assert_close(out, want)
    # no clip at all: z comes through whole
    plain = RunningNorm(4)
    plain.load_state_dict(rn.state_dict())
    torch.testing.assert_close(plain(x), z)


def test_running_norm_fixed_tail_of_one_column_passes_raw():
    """Kills networks `RunningNorm.forward` 16 (`fixed_tail > 1`: a one-column tail normalised), 17-21
    (the concatenation broken or along dim 0), 22, 23 (the wrong columns kept)."""
    rn = RunningNorm(4, fixed_tail=1)
    rn.mean.fill_(1.0)
    rn.var.fill_(3.0)
    x = torch.tensor([[0.0, 2.0, 4.0, 7.0], [1.0, -2.0, 0.5, -3.0], [3.0, 3.0, 3.0, 0.25]])
    want = torch.cat([(x[:, :3] - 1.0) / math.sqrt(3.0 + 1e-6), x[:, 3:]], dim=1)
    out = rn(x)
    assert out.shape == (3, 4)
    torch.testing.assert_close(out, want)


def test_running_norm_fixed_tail_passes_raw_for_any_leading_shape():
    """Kills networks `RunningNorm.forward` 24 (the tail concatenated along dim +1, not the feature axis −1).
    Like `update` (which reshapes to (-1, dim)), forward maps s over any leading shape: one state (dim,) or
    a (T, B, dim) stack. The learner itself only passes (B, dim) batches, where dims 1 and −1 coincide."""
    rn = RunningNorm(4, fixed_tail=1)
    rn.mean.fill_(1.0)
    rn.var.fill_(3.0)
    x = torch.arange(24.0).view(2, 3, 4) / 4 - 2
    want = torch.cat([(x[..., :3] - 1.0) / math.sqrt(3.0 + 1e-6), x[..., 3:]], dim=-1)
    torch.testing.assert_close(rn(x), want)
    torch.testing.assert_close(rn(x[1, 2]), want[1, 2])  # a single unbatched state


# ------------------------------------------------------------------------------------------- pre_tanh
def test_pre_tanh_clips_references_at_both_bounds():
    """Kills networks `pre_tanh` 2, 3, 5 (a bound of the clip dropped: atanh(±1) = ±inf)."""
    c = 1.0 - 1e-4
    got = pre_tanh(torch.tensor([-1.0, 1.0, 0.5, -2.0, 2.0]))
    want = torch.atanh(torch.tensor([-c, c, 0.5, -c, c]))
    assert torch.isfinite(got).all()
    torch.testing.assert_close(got, want)
    assert abs(float(got[1]) - 4.95) < 0.01


# ------------------------------------------------------------------------------------------- Actor
def test_actor_residual_adds_delta_in_pre_tanh_space_and_uses_given_out():
    """Kills networks `Actor.pre_tanh_mean` 13 (δ subtracted), 3 (a given `out` ignored and recomputed)."""
    torch.manual_seed(0)
    actor = Actor(D, H, A, [8, 8], 4, init_scale=1.0)
    s, ref = inputs(3)
    with torch.no_grad():
        delta = actor.features(s, ref)[:, :CHUNK]
        assert delta.abs().min() > 1e-4
        torch.testing.assert_close(actor.pre_tanh_mean(s, ref), pre_tanh(ref.flatten(1)) + delta)
        torch.testing.assert_close(actor(s, ref), torch.tanh(pre_tanh(ref.flatten(1)) + delta).view(3, H, A))
        zeros = torch.zeros(3, CHUNK)
        torch.testing.assert_close(actor.pre_tanh_mean(s, ref, zeros), pre_tanh(ref.flatten(1)))


def test_actor_without_residual_acts_from_delta_alone():
    """Kills networks `Actor.pre_tanh_mean` 12 (the residual always added)."""
    torch.manual_seed(1)
    actor = Actor(D, H, A, [8, 8], 4, residual=False, init_scale=1.0)
    s, ref = inputs(3)
    with torch.no_grad():
        delta = actor.features(s, ref)
        torch.testing.assert_close(actor.pre_tanh_mean(s, ref), delta)
        torch.testing.assert_close(actor(s, ref), torch.tanh(delta).view(3, H, A))


def test_gaussian_actor_log_std_squashed_into_default_bounds_by_hand():
    """Kills networks `GaussianActor.__init__` 1 (default log_std_max 1), 3 (positional arguments lost),
    `GaussianActor.dist_params` 18-24 (the squash of log σ into [log_std_min, log_std_max])."""
    torch.manual_seed(2)
    actor = GaussianActor(D, H, A, [8, 8], 4, init_scale=1.0)  # positional, as the learner builds it
    s, ref = inputs(4)
    with torch.no_grad():
        out = actor.features(s, ref)
        mean, log_std = actor.dist_params(s, ref)
        raw = torch.tanh(out[:, CHUNK:])
        assert raw.abs().max() > 0.05
        torch.testing.assert_close(log_std, -5.0 + (0.0 - -5.0) * (raw + 1) / 2)
        torch.testing.assert_close(mean, pre_tanh(ref.flatten(1)) + out[:, :CHUNK])
        assert (log_std >= -5.0).all() and (log_std <= 0.0).all()
        torch.testing.assert_close(actor(s, ref), torch.tanh(mean).view(4, H, A))
        # the bounds are the constructor's
        narrow = GaussianActor(D, H, A, [8, 8], 4, init_scale=1.0, log_std_min=-2.0, log_std_max=-1.0)
        narrow.load_state_dict(actor.state_dict())
        _, ls = narrow.dist_params(s, ref)
        torch.testing.assert_close(ls, -2.0 + (raw + 1) / 2)


def test_tanh_gaussian_sample_matches_change_of_variables_by_hand():
    """Kills networks `tanh_gaussian_sample` 2, 3 (u = μ + σ·ε), 5-16 (the Gaussian log-density, summed
    over the last (event) axis of a (2, 3, 4) batch), 19-31 (the tanh Jacobian term)."""
    g = torch.Generator().manual_seed(7)
    mean = torch.rand(2, 3, 4, generator=g, dtype=torch.float64) * 2 - 1
    log_std = torch.rand(2, 3, 4, generator=g, dtype=torch.float64) - 1.5
    eps = torch.randn(2, 3, 4, generator=g, dtype=torch.float64)
    a, log_prob = tanh_gaussian_sample(mean, log_std, eps)
    u = mean + log_std.exp() * eps
    normal = torch.distributions.Normal(mean, log_std.exp())
    want = normal.log_prob(u).sum(-1) - torch.log(1 - torch.tanh(u) ** 2).sum(-1)
    assert log_prob.shape == (2, 3)
    torch.testing.assert_close(a, torch.tanh(u))
    torch.testing.assert_close(log_prob, want)


# ------------------------------------------------------------------------------------------- critic
def test_ensemble_layer_norm_normalises_each_row_over_features_only():
    """Kills networks `EnsembleLayerNorm.forward` 11, 12 (normalised over batch and features together)."""
    g = torch.Generator().manual_seed(5)
    ln = EnsembleLayerNorm(2, 3)
    with torch.no_grad():
        ln.weight.copy_(torch.rand(2, 1, 3, generator=g) + 0.5)
        ln.bias.copy_(torch.randn(2, 1, 3, generator=g))
    x = torch.randn(2, 4, 3, generator=g) * 3 + torch.arange(4.0).view(1, 4, 1)
    mu = x.mean(-1, keepdim=True)
    var = x.var(-1, unbiased=False, keepdim=True)
    want = (x - mu) / (var + 1e-5).sqrt() * ln.weight + ln.bias
    with torch.no_grad():
        torch.testing.assert_close(ln(x), want)
        # same row in a different batch gives the same output: nothing is shared across the batch
        torch.testing.assert_close(ln(x[:, :1]), want[:, :1])


def test_ensemble_linear_init_is_nn_linear_default_per_head():
    """Kills networks `EnsembleLinear.__init__` 14 (one bias shared by every head), 19, 20 (bound √d_in or
    2/√d_in instead of 1/√d_in), 26, 27 (weight drawn from [bound, 1] or [−bound, 1]), 33, 34, 35 (bias
    drawn from [bound, 1], [−bound, 1] or the single point bound). nn.Linear's default init: weight and
    bias each uniform on [−1/√d_in, 1/√d_in], here per head, each head its own bias."""
    torch.manual_seed(0)
    n, d_in, d_out = 4, 16, 64
    layer = EnsembleLinear(n, d_in, d_out)
    bound = 0.25  # 1/√16
    assert layer.weight.shape == (n, d_in, d_out) and layer.bias.shape == (n, 1, d_out)
    for p, edge in ((layer.weight, 0.24), (layer.bias, 0.22)):
        p = p.detach()
        assert p.abs().max() <= bound
        assert p.max() > edge and p.min() < -edge  # both ends of the interval are reached
        assert abs(float(p.mean())) < 0.03
        assert abs(float(p.std()) - bound / math.sqrt(3.0)) < 0.015  # uniform's σ = bound/√3
    # heads differ in their biases too, and head i computes x_i W_i + b_i
    assert not torch.equal(layer.bias[0], layer.bias[1])
    x = torch.randn(n, 3, d_in, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        out = layer(x)
        for i in range(n):
            torch.testing.assert_close(out[i], x[i] @ layer.weight[i] + layer.bias[i])


def test_critic_defaults_are_two_heads_with_layer_norm():
    """Kills networks `Critic.__init__` 1 (layer_norm off by default), 2 (three heads by default). The
    learner builds its critic without num_heads: two heads, for the clipped double-Q minimum."""
    torch.manual_seed(3)
    critic = Critic(D, H, A, [8, 8], 4, 5)
    explicit = Critic(D, H, A, [8, 8], 4, 5, layer_norm=True, num_heads=2)
    explicit.load_state_dict(critic.state_dict())  # strict: same layers, same shapes
    assert sum(isinstance(m, EnsembleLayerNorm) for m in critic.net) == 2
    s, ref = inputs(3)
    action = torch.rand(3, H, A) * 2 - 1
    with torch.no_grad():
        logits = critic(s, action, ref)
        assert logits.shape == (2, 3, 5)
        torch.testing.assert_close(logits, explicit(s, action, ref))


# ------------------------------------------------------------------------------------------- distributional
def test_project_target_by_hand_on_a_four_atom_support():
    """The C51 projection of Eq. 2 written out: split by distance, clipped to the support at both ends."""
    support = torch.tensor([0.0, 1.0, 2.0, 3.0])
    probs = torch.tensor([[0.1, 0.2, 0.3, 0.4], [0.1, 0.2, 0.3, 0.4], [0.25, 0.25, 0.25, 0.25]])
    reward = torch.tensor([0.5, -5.0, 0.0])
    discount = torch.tensor([0.5, 0.9, 1.0])
    out = project_target(probs, reward, discount, support)
    # row 0: atoms move to 0.5, 1, 1.5, 2 → [0.05, 0.05 + 0.2 + 0.15, 0.15 + 0.4, 0]
    want = torch.tensor([[0.05, 0.4, 0.55, 0.0], [1.0, 0.0, 0.0, 0.0], [0.25, 0.25, 0.25, 0.25]])
    torch.testing.assert_close(out, want)


def test_project_target_keeps_a_return_above_v_max_on_the_top_atom_when_the_index_rounds_over():
    """Kills distributional `project_target` 28, 30, 34 (the fractional index not clamped to n − 1).
    On this support (v_max − v_min)/δ is 12.000001 in float32, so an atom clipped to v_max would have
    its upper neighbour at index 13, past the last atom."""
    support = torch.linspace(-0.69, 1.31, 13)
    g = torch.Generator().manual_seed(0)
    probs = torch.softmax(torch.randn(2, 13, generator=g), -1)
    out = project_target(probs, torch.tensor([5.0, 5.0]), torch.tensor([1.0, 0.0]), support)
    want = torch.zeros(2, 13)
    want[:, -1] = 1.0
    torch.testing.assert_close(out, want)


def test_project_target_clips_a_return_past_either_end_to_exactly_that_end():
    """Kills distributional `project_target` 15, 17 (the moved atoms not clipped at v_max). "Clipped to the
    support": a return past v_max is projected bit for bit as a return of v_max, and one below v_min as
    v_min. On −10..20 with 51 atoms float32 puts v_max's index at 49.999996, so a return at v_max leaves a
    sliver on atom 48; unclipped, a larger return would be indexed past the top and leave none."""
    support = torch.linspace(-10.0, 20.0, 51)
    g = torch.Generator().manual_seed(0)
    probs = torch.softmax(torch.randn(1, 51, generator=g), -1).expand(4, -1)
    reward = torch.tensor([20.0, 35.0, -10.0, -25.0])
    out = project_target(probs, reward, torch.zeros(4), support)
    assert torch.equal(out[1], out[0]) and torch.equal(out[3], out[2])
    torch.testing.assert_close(out[0, -1], torch.tensor(1.0))  # all of it on the top atom, up to rounding
    torch.testing.assert_close(out[2, 0], torch.tensor(1.0))
    assert out[2, 1:].sum() == 0


def test_categorical_cross_entropy_over_atoms_averaged_over_heads_and_batch():
    """Kills distributional `categorical_cross_entropy` 2 (summed over the batch), 8 (log-softmax over the
    batch axis), 10 (summed over the batch axis): logits (heads, B, atoms) as its docstring allows."""
    g = torch.Generator().manual_seed(3)
    logits = torch.randn(2, 3, 4, generator=g)
    target = torch.softmax(torch.randn(2, 3, 4, generator=g), -1)
    log_p = logits - torch.logsumexp(logits, -1, keepdim=True)
    want = -(target * log_p).sum(-1).mean()
    torch.testing.assert_close(categorical_cross_entropy(logits, target), want)
    # uniform logits, one-hot targets: log N per row, whatever the batch size
    onehot = torch.eye(4)[torch.tensor([0, 3, 1])]
    got = categorical_cross_entropy(torch.zeros(3, 4), onehot)
    torch.testing.assert_close(got, torch.tensor(math.log(4.0)))


# ------------------------------------------------------------------------------------------- config
PAPER = dict(  # FastSAC over chunks and γ = 0.997 are the paper's (Sec. V); the sizes are FastSAC's scale
    algo="fastsac",
    actor_hidden=[512, 256, 128],
    critic_hidden=[768, 384, 192],
    projector_dim=256,
    batch_size=8192,
    utd=8,
    policy_frequency=4,
    gamma=0.997,
    tau=0.125,
    weight_decay=0.001,
    alpha_init=0.001,
    actor_lr=3e-4,
    critic_lr=3e-4,
    device="cuda",
    amp=True,
    compile=True,
)


def test_paper_config_is_the_defaults_with_the_paper_scale_settings():
    """Kills config `LearnerConfig.paper` 1-71 (every paper-scale value, written out here)."""
    want = LearnerConfig().to_dict()
    want.update(PAPER)
    assert LearnerConfig.paper().to_dict() == want


def test_paper_config_takes_overrides():
    """Kills config `LearnerConfig.paper` 72 (overrides dropped)."""
    cfg = LearnerConfig.paper(batch_size=64, device="cpu", seed=3)
    want = LearnerConfig().to_dict()
    want.update(PAPER, batch_size=64, device="cpu", seed=3)
    assert cfg.to_dict() == want


def test_from_dict_names_the_type_of_a_non_mapping():
    """Kills config `LearnerConfig.from_dict` 2, 3 (the message, and the type it names)."""
    with pytest.raises(AccrueError) as err:
        LearnerConfig.from_dict([1, 2])
    assert str(err.value) == "learner: expected a mapping, got list"
    with pytest.raises(AccrueError) as err:
        LearnerConfig.from_dict(None)
    assert str(err.value) == "learner: expected a mapping, got NoneType"
