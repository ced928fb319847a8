"""How far the actor's residual δ moves in its first updates when the critic has learned nothing yet: the
mechanism behind β = 0 collapsing to 0.00 success by the first evaluation on the contact family.

The real learner (FastTD3, the contact-learner spec's sizes and optimiser) is updated on random minibatches
whose rewards are noise, so its critic's action slope carries no information, for each actor learning rate
and β asked. After n actor updates it prints, on 512 held-out states:

    mean|δ|        the mean absolute residual in pre-tanh space (0 at the start; tanh(1) ≈ 0.76)
    shared         |mean over states of δ| / mean|δ|: 1 when δ is one offset for every state

Adam moves every weight by about lr per update whatever the size of its gradient; δ's head sums 256 SiLU
features of mostly one sign, so a slope that points the same way in most states adds up to one offset.

    .venv/bin/python benchmarks/actor_step_offset.py [--lrs 3e-4,1e-4,3e-5] [--betas 0,0.1] [--json]

--json writes benchmarks/results/actor_step_offset.json (the command, settings and every figure).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
OUT = ROOT / "benchmarks" / "results" / "actor_step_offset.json"
STATE_DIM, H, D = 93, 4, 6  # the contact quickstart's s (29 + 4 x 15 history + 4 geometry), H, d
CHECKPOINTS = (10, 50, 100, 200, 400)


def random_buffer(n: int, seed: int):
    import torch

    from accrue.learner.replay import ReplayBuffer

    g = torch.Generator().manual_seed(seed)
    buf = ReplayBuffer(STATE_DIM, H, D)
    ref = torch.rand(n, H, D, generator=g) * 1.6 - 0.8
    action = (ref + 0.2 * torch.randn(n, H, D, generator=g)).clamp(-1, 1)  # ã plus exploration noise
    buf.add(
        torch.randn(n, STATE_DIM, generator=g),
        action,
        ref,
        (torch.rand(n, generator=g) > 0.9).float(),  # sparse rewards unrelated to the action
        torch.randn(n, STATE_DIM, generator=g),
        torch.rand(n, H, D, generator=g) * 1.6 - 0.8,
        torch.rand(n, generator=g) > 0.95,
        0,
        torch.arange(n) // 20,
    )
    return buf


def offsets(lr: float, beta: float, seed: int, last: int = CHECKPOINTS[-1]) -> list[dict]:
    import torch

    from accrue.learner import LearnerConfig, make_learner
    from accrue.learner.networks import pre_tanh

    cfg = LearnerConfig(beta=beta, actor_lr=lr, critic_lr=3e-4, max_grad_norm=1.0, utd=4, seed=seed)
    learner = make_learner(cfg, STATE_DIM, H)
    buf = random_buffer(8192, seed)
    held = random_buffer(512, seed + 1000)
    s, ref = held.column("state"), held.column("ref")
    rows = []
    marks = [c for c in CHECKPOINTS if c < last] + [last]
    while learner.counters["actor_updates"] < last:
        learner.train_step(buf)
        done = learner.counters["actor_updates"]
        if rows and done <= rows[-1]["actor_updates"]:
            continue
        if done in marks:
            with torch.no_grad():
                delta = learner.actor.pre_tanh_mean(s, ref) - pre_tanh(ref.flatten(1))
            mean_abs = float(delta.abs().mean())
            rows.append(
                {
                    "actor_updates": done,
                    "mean_abs_delta": round(mean_abs, 4),
                    "shared": round(float(delta.mean(0).abs().mean()) / max(mean_abs, 1e-12), 3),
                }
            )
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lrs", default="3e-4,1e-4,3e-5")
    ap.add_argument("--betas", default="0,0.1")
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--updates", type=int, default=CHECKPOINTS[-1], help="actor updates per run")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    import torch

    torch.set_num_threads(1)
    runs = []
    for beta in (float(b) for b in args.betas.split(",")):
        for lr in (float(x) for x in args.lrs.split(",")):
            for seed in (int(x) for x in args.seeds.split(",")):
                rows = offsets(lr, beta, seed, args.updates)
                runs.append({"beta": beta, "actor_lr": lr, "seed": seed, "rows": rows})
                line = ", ".join(f"{r['actor_updates']}: {r['mean_abs_delta']:.2f} ({r['shared']:.2f})" for r in rows)
                print(f"β {beta:g}  actor_lr {lr:g}  seed {seed}  mean|δ| (shared) after n actor updates  {line}")
    if args.json:
        cmd = "python benchmarks/actor_step_offset.py " + " ".join(argv if argv is not None else sys.argv[1:])
        OUT.write_text(json.dumps({"command": cmd.strip(), "state_dim": STATE_DIM, "runs": runs}, indent=1) + "\n")
        print(f"wrote {OUT.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
