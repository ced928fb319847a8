"""Gradient updates per second: one full ACCRUE update (critic + actor + distillation) next to a plain
FastTD3-style update at the same sizes, in the same run.

    .venv/bin/python benchmarks/bench_learner.py                         # CPU defaults
    .venv/bin/python benchmarks/bench_learner.py --device cuda --amp --compile --cudagraphs --batch 8192

"reference" is written here the way FastTD3 writes it: two separate critic MLPs, the actor loss
backpropagating into the critic weights, critic + actor on the current batch only. "accrue" is
accrue.learner's update: both critic heads in one batched matmul, the critic frozen during the actor
step, and the student's prior-batch forward stacked with the current one (one actor pass for Eqs. 1 and 4).
By default every update includes an actor step (--policy-frequency 1), the heaviest case for ACCRUE;
--policy-frequency 2 is the learner's default schedule (both sides then step the actor every 2nd update).
"""

from __future__ import annotations

import argparse
import time

import torch
from torch import nn


def reference_fasttd3(state_dim, chunk, hidden, proj, atoms, v_min, v_max, lr, wd, device, policy_frequency=1):
    """A plain FastTD3-style C51 TD3 update over chunks (the baseline being compared against)."""

    def mlp(sizes):
        layers = []
        for i in range(len(sizes) - 1):
            layers.append(nn.Linear(sizes[i], sizes[i + 1]))
            if i < len(sizes) - 2:
                layers += [nn.LayerNorm(sizes[i + 1]), nn.SiLU()]
        return nn.Sequential(*layers)

    class Q(nn.Module):
        def __init__(self):
            super().__init__()
            self.proj = nn.Sequential(nn.Linear(state_dim, proj), nn.LayerNorm(proj), nn.SiLU())
            self.q1 = mlp([proj + 2 * chunk, *hidden, atoms])
            self.q2 = mlp([proj + 2 * chunk, *hidden, atoms])

        def forward(self, s, a, r):
            x = torch.cat([self.proj(s), a, r], -1)
            return self.q1(x), self.q2(x)

    actor_net = nn.Sequential(
        nn.Linear(state_dim, proj), nn.LayerNorm(proj), nn.SiLU(), mlp([proj, *hidden, chunk])
    ).to(device)
    actor = lambda s, r: torch.tanh(actor_net(s) + torch.atanh(r.clamp(-0.999, 0.999)))  # noqa: E731
    qnet, qtarget = Q().to(device), Q().to(device)
    qtarget.load_state_dict(qnet.state_dict())
    q_opt = torch.optim.AdamW(qnet.parameters(), lr=lr, weight_decay=wd)
    a_opt = torch.optim.AdamW(actor_net.parameters(), lr=lr, weight_decay=wd)
    support = torch.linspace(v_min, v_max, atoms, device=device)
    dz = (v_max - v_min) / (atoms - 1)

    def projection(probs, reward, discount):
        tz = (reward[:, None] + discount[:, None] * support).clamp(v_min, v_max)
        b = (tz - v_min) / dz
        lo, up = b.floor().long(), b.ceil().long()
        out = torch.zeros_like(probs)
        out.scatter_add_(1, lo, probs * (up.float() - b + (lo == up).float()))
        out.scatter_add_(1, up, probs * (b - lo.float()))
        return out

    calls = [0]

    def update(b):
        s, a, r, rew, s2, r2, disc = b
        calls[0] += 1
        with torch.no_grad():
            a2 = (actor(s2, r2) + (torch.randn_like(a) * 0.001).clamp(-0.5, 0.5)).clamp(-1, 1)
            l1, l2 = qtarget(s2, a2, r2)
            p1, p2 = l1.softmax(-1), l2.softmax(-1)
            pick = ((p1 * support).sum(-1) < (p2 * support).sum(-1))[:, None]
            target = projection(torch.where(pick, p1, p2), rew, disc)
        q1, q2 = qnet(s, a, r)
        q_loss = -(target * q1.log_softmax(-1)).sum(-1).mean() - (target * q2.log_softmax(-1)).sum(-1).mean()
        q_opt.zero_grad(set_to_none=True)
        q_loss.backward()
        q_opt.step()
        if calls[0] % policy_frequency == 0:
            act = actor(s, r)
            l1, l2 = qnet(s, act, r)
            q = torch.minimum((l1.softmax(-1) * support).sum(-1), (l2.softmax(-1) * support).sum(-1))
            a_loss = (-q + 0.1 * (act - r).square().sum(-1)).mean()
            a_opt.zero_grad(set_to_none=True)
            a_loss.backward()
            a_opt.step()
        with torch.no_grad():
            torch._foreach_lerp_(list(qtarget.parameters()), list(qnet.parameters()), 0.1)

    return update


def timed_interleaved(fns: dict, iters: int, warmup: int, rounds: int, device: str) -> dict:
    """Updates/s of each function, measured in alternating rounds (so a busy machine slows all alike);
    the median round is reported."""

    def sync():
        if device.startswith("cuda"):
            torch.cuda.synchronize()

    for fn in fns.values():
        for _ in range(warmup):
            fn()
    sync()
    rates: dict[str, list[float]] = {name: [] for name in fns}
    per_round = max(1, iters // rounds)
    for _ in range(rounds):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            for _ in range(per_round):
                fn()
            sync()
            rates[name].append(per_round / (time.perf_counter() - t0))
    return {name: sorted(r)[len(r) // 2] for name, r in rates.items()}


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--device", default="cpu")
    p.add_argument("--state-dim", type=int, default=64)
    p.add_argument("--horizon", type=int, default=8)
    p.add_argument("--action-dim", type=int, default=6)
    p.add_argument("--batch", type=int, default=256)
    p.add_argument("--hidden", type=int, nargs="+", default=[256, 256])
    p.add_argument("--projector", type=int, default=64)
    p.add_argument("--atoms", type=int, default=101)
    p.add_argument("--iters", type=int, default=60)
    p.add_argument("--warmup", type=int, default=10)
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--policy-frequency", type=int, default=1)
    p.add_argument("--threads", type=int, default=0, help="torch CPU threads (0 = torch default)")
    p.add_argument("--amp", action="store_true", help="bf16 autocast (CUDA)")
    p.add_argument("--compile", action="store_true", help="torch.compile the loss functions")
    p.add_argument("--cudagraphs", action="store_true", help="compile mode reduce-overhead (CUDA graphs)")
    return p


REFERENCE = "reference FastTD3 update (critic+actor, B^k)"
SEQUENTIAL = "accrue.learner sequential update (critic+actor, B^k)"
ACCRUE = "accrue.learner ACCRUE update (critic+actor+distill, B^k + B^<k)"


def measure(args: argparse.Namespace) -> dict[str, float]:
    """Updates/s of the reference, Sequential and ACCRUE updates at args' sizes, in interleaved rounds."""
    if args.threads:
        torch.set_num_threads(args.threads)

    from accrue.learner import LearnerConfig, compute_teacher_targets, make_learner
    from accrue.learner.replay import Batch

    d, h, a_dim, n = args.state_dim, args.horizon, args.action_dim, args.batch
    cfg = LearnerConfig(
        algo="fasttd3",
        method="accrue",
        actor_hidden=args.hidden,
        critic_hidden=args.hidden,
        projector_dim=args.projector,
        num_atoms=args.atoms,
        batch_size=n,
        policy_frequency=args.policy_frequency,
        device=args.device,
        amp=args.amp,
        compile=args.compile or args.cudagraphs,
        compile_mode="reduce-overhead" if args.cudagraphs else "default",
    )
    learner = make_learner(cfg, d, h, a_dim)
    g = torch.Generator().manual_seed(0)

    def batch():
        rows = lambda *shape: torch.rand(n, *shape, generator=g).to(args.device) * 2 - 1  # noqa: E731
        return Batch(
            state=rows(d),
            action=rows(h, a_dim),
            ref=rows(h, a_dim),
            reward=(rows() > 0.8).float(),
            next_state=rows(d),
            next_ref=rows(h, a_dim),
            done=(rows() > 0.9).float(),
            index=torch.arange(n, device=args.device),
        )

    cur, prior = batch(), batch()
    prior = prior.with_teacher(compute_teacher_targets(learner, prior.state, prior.ref, n))
    ref_update = reference_fasttd3(
        d,
        h * a_dim,
        args.hidden,
        args.projector,
        args.atoms,
        cfg.v_min,
        cfg.v_max,
        cfg.critic_lr,
        cfg.weight_decay,
        args.device,
        args.policy_frequency,
    )
    disc = (cfg.gamma**h) * (1 - cur.done)
    ref_batch = (
        cur.state,
        cur.action.flatten(1),
        cur.ref.flatten(1),
        cur.reward,
        cur.next_state,
        cur.next_ref.flatten(1),
        disc,
    )

    return timed_interleaved(
        {
            REFERENCE: lambda: ref_update(ref_batch),
            SEQUENTIAL: lambda: learner._update(cur, None),
            ACCRUE: lambda: learner._update(cur, prior),
        },
        args.iters,
        args.warmup,
        args.rounds,
        args.device,
    )


def main() -> None:
    args = parser().parse_args()
    results = measure(args)
    d, h, a_dim, n = args.state_dim, args.horizon, args.action_dim, args.batch
    print(
        f"device={args.device} threads={torch.get_num_threads()} state_dim={d} H={h} d={a_dim} batch={n} "
        f"(+{n} prior rows for ACCRUE) hidden={args.hidden} atoms={args.atoms} amp={args.amp} "
        f"compile={args.compile} cudagraphs={args.cudagraphs} policy_frequency={args.policy_frequency}; median of {args.rounds} interleaved rounds"
    )
    base = results[REFERENCE]
    for name, ups in results.items():
        print(f"  {name:<66s} {ups:8.1f} updates/s   ({ups / base:4.2f}x reference)")


if __name__ == "__main__":
    main()
