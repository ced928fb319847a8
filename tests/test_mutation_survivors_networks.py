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
import torch.nn.functional as F
from torch import nn

from accrue.errors import AccrueError
from accrue.learner.config import LearnerConfig
from accrue.learner.distributional import categorical_cross_entropy, make_support, project_target
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


def test_running_norm_counts_rows_exactly_past_float32s_integer_range():
    """Kills networks `RunningNorm.__init__` 30, 32 (the row count kept in float32, torch's default dtype).
    At the paper's 8192-row batches the count passes 2**24 within a few thousand updates; a float32 count
    stops there (2**24 + 1 rounds back down), so the mean's weight n / total would be wrong from then on."""
    rn = RunningNorm(2)
    assert rn.count.dtype == torch.float64
    rn.count.fill_(2.0**24)
    rn.update(torch.ones(1, 2))
    assert float(rn.count) == 2.0**24 + 1


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


def actor_features_by_hand(actor: Actor, s: torch.Tensor, ref: torch.Tensor, layer_norm: bool) -> torch.Tensor:
    """proj = SiLU(LN(Linear)); trunk = (Linear, [LN], SiLU)* then Linear; head(SiLU(trunk)): Sec. IV-A's actor."""
    p = dict(actor.named_parameters())
    x = F.linear(actor.obs_norm(s), p["proj.0.weight"], p["proj.0.bias"])
    x = F.silu(F.layer_norm(x, x.shape[-1:], p["proj.1.weight"], p["proj.1.bias"]))
    x = torch.cat([x, ref.flatten(1)], -1)
    linears = [m for m in actor.trunk if isinstance(m, nn.Linear)]
    norms = [m for m in actor.trunk if isinstance(m, nn.LayerNorm)]
    for i, lin in enumerate(linears):
        x = F.linear(x, lin.weight, lin.bias)
        if i < len(linears) - 1:
            if layer_norm:
                x = F.layer_norm(x, x.shape[-1:], norms[i].weight, norms[i].bias)
            x = F.silu(x)
    return F.linear(F.silu(x), actor.head.weight, actor.head.bias)


@pytest.mark.parametrize("layer_norm", [True, False])
def test_actor_layers_in_order_and_features_by_hand(layer_norm):
    """Kills networks `mlp` 12, 13 (LayerNorm and SiLU after the trunk's last layer too), 14 (none after the
    last hidden layer), 17, 18 (a LayerNorm sized for another layer: hidden widths 8, 6 differ), `projector`
    5 (no LayerNorm), 6 (no SiLU)."""
    torch.manual_seed(4)
    actor = Actor(D, H, A, [8, 6], 4, layer_norm=layer_norm, init_scale=1.0)
    described = [(type(m).__name__, tuple(p.shape for p in m.parameters())) for m in [*actor.proj, *actor.trunk]]
    ln8 = [("LayerNorm", ((8,), (8,)))] if layer_norm else []
    assert described == [
        ("Linear", ((4, D), (4,))),
        ("LayerNorm", ((4,), (4,))),
        ("SiLU", ()),
        ("Linear", ((8, 4 + CHUNK), (8,))),
        *ln8,
        ("SiLU", ()),
        ("Linear", ((6, 8), (6,))),
    ]
    s, ref = inputs(3)
    with torch.no_grad():
        torch.testing.assert_close(actor.features(s, ref), actor_features_by_hand(actor, s, ref, layer_norm))


def test_actor_defaults_layer_norm_small_head_and_an_identity_free_obs_norm():
    """Kills networks `Actor.__init__` 1 (layer_norm off by default), 30 (layer_norm not passed to the trunk),
    3 (init_scale 1.01 by default, not 0.01), 4 (obs normalisation off by default), 6 (a std floor of 1 by
    default), 7 (z clipped to ±1 by default), 8 (the last column passed raw by default)."""
    torch.manual_seed(5)
    actor = Actor(D, H, A, [8, 6], 4)  # as the learner builds it, every optional argument defaulted
    torch.manual_seed(5)
    unscaled = Actor(D, H, A, [8, 6], 4, layer_norm=True, init_scale=1.0)
    unscaled.load_state_dict(actor.state_dict() | {"head.weight": unscaled.head.weight}, strict=True)
    assert sum(isinstance(m, nn.LayerNorm) for m in actor.trunk) == 1
    torch.testing.assert_close(actor.head.weight, 0.01 * unscaled.head.weight)
    assert not actor.head.bias.any()
    # the observation normaliser is on, with no floor, no clip and no raw tail: plain z of every column
    mean = torch.tensor([0.0, 1.0, -1.0, 2.0, 0.5])
    var = torch.tensor([0.25, 0.01, 4.0, 1.0, 0.04])
    actor.obs_norm.mean.copy_(mean)
    actor.obs_norm.var.copy_(var)
    s, ref = inputs(3)
    torch.testing.assert_close(actor.obs_norm(s), (s - mean) / (var + 1e-6).sqrt())
    assert actor.obs_norm(s).abs().max() > 3


def test_actor_passes_its_obs_norm_settings_to_the_normaliser():
    """Kills networks `Actor.__init__` 19 (obs_normalization=False ignored), 21 (obs_norm_clip ignored), 22
    (obs_norm_fixed_tail ignored)."""
    s, _ = inputs(4)
    off = Actor(D, H, A, [8], 4, obs_normalization=False)
    off.obs_norm.update(s)
    torch.testing.assert_close(off.obs_norm(s), s)
    on = Actor(D, H, A, [8], 4, obs_norm_clip=0.5, obs_norm_fixed_tail=1)
    on.obs_norm.var.fill_(0.01)
    z = s / (0.01 + 1e-6) ** 0.5
    want = torch.cat([z[:, :-1].clamp(-0.5, 0.5), s[:, -1:]], -1)
    torch.testing.assert_close(on.obs_norm(s), want)


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


def test_critic_layers_in_order_and_logits_by_hand():
    """Kills networks `Critic.__init__` 27, 28 (LayerNorm and SiLU after the last, logit layer too), 29 (none
    after the last hidden layer)."""
    torch.manual_seed(6)
    critic = Critic(D, H, A, [8, 6], 4, 5)
    described = [(type(m).__name__, tuple(p.shape for p in m.parameters())) for m in critic.net]
    assert described == [
        ("EnsembleLinear", ((2, 4 + 2 * CHUNK, 8), (2, 1, 8))),
        ("EnsembleLayerNorm", ((2, 1, 8), (2, 1, 8))),
        ("SiLU", ()),
        ("EnsembleLinear", ((2, 8, 6), (2, 1, 6))),
        ("EnsembleLayerNorm", ((2, 1, 6), (2, 1, 6))),
        ("SiLU", ()),
        ("EnsembleLinear", ((2, 6, 5), (2, 1, 5))),
    ]
    s, ref = inputs(3)
    action = torch.rand(3, H, A, generator=torch.Generator().manual_seed(1)) * 2 - 1
    p = dict(critic.named_parameters())
    with torch.no_grad():
        x = F.linear(s, p["proj.0.weight"], p["proj.0.bias"])
        x = F.silu(F.layer_norm(x, (4,), p["proj.1.weight"], p["proj.1.bias"]))
        x = torch.cat([x, action.flatten(1), ref.flatten(1)], -1)
        heads = []
        for h in range(2):
            y = x
            for i, width in ((0, 8), (3, 6)):
                y = y @ p[f"net.{i}.weight"][h] + p[f"net.{i}.bias"][h]
                y = F.silu(F.layer_norm(y, (width,), p[f"net.{i + 1}.weight"][h, 0], p[f"net.{i + 1}.bias"][h, 0]))
            heads.append(y @ p["net.6.weight"][h] + p["net.6.bias"][h])
        torch.testing.assert_close(critic(s, action, ref), torch.stack(heads))


# ------------------------------------------------------------------------------------------- distributional
def test_make_support_is_made_on_the_device_asked_for():
    """Kills distributional `make_support` 4, 8 (device dropped: the support made on torch's default device).
    The learner makes its support on its own device, whatever torch's default is; on a CPU-only machine a
    meta default device shows the difference."""
    with torch.device("meta"):
        support = make_support(-1.0, 1.0, 5, device="cpu")
    assert support.device.type == "cpu"
    torch.testing.assert_close(support, torch.tensor([-1.0, -0.5, 0.0, 0.5, 1.0]))


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
