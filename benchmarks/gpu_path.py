"""The GPU path, measured in one run: the learner update at paper sizes with and without torch.compile /
CUDA graphs against the plain FastTD3 reference, and env physics steps/s on CPU MuJoCo against MuJoCo
Warp for one task of each family (what Warp cannot run is reported, not skipped silently).

    .venv/bin/python benchmarks/gpu_path.py --out benchmarks/results/gpu_path.json        # CUDA: batch 4096
    .venv/bin/python benchmarks/gpu_path.py --small --no-compile                          # CPU, seconds (CI)

On a CUDA machine the defaults take a few minutes (well under 10). Without CUDA the same rows run on CPU
at --small sizes; CUDA graphs and MuJoCo Warp rows then say why they did not run.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
import traceback
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

FAMILY_TASKS = ("nist/rect_peg", "plugs/cross", "contact/keyed_peg")


def _why(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}".strip()


def learner_rows(device: str, small: bool, compile_: bool) -> list[dict]:
    import bench_learner

    base = ["--device", device, "--threads", "0"]
    if small:
        base += [
            "--batch",
            "64",
            "--hidden",
            "64",
            "64",
            "--atoms",
            "11",
            "--iters",
            "6",
            "--warmup",
            "2",
            "--rounds",
            "2",
        ]
    else:
        base += ["--batch", "4096", "--hidden", "1024", "512", "256", "--iters", "200", "--warmup", "20"]
        base += ["--rounds", "5"] + (["--amp"] if device == "cuda" else [])
    variants = {"eager": []}
    if compile_:
        variants["torch.compile"] = ["--compile"]
        variants["torch.compile + CUDA graphs"] = ["--cudagraphs"]
    rows = []
    for name, extra in variants.items():
        row = {"variant": name, "args": base + extra}
        if "CUDA graphs" in name and device != "cuda":
            rows.append({**row, "skipped": "CUDA graphs need a CUDA device"})
            continue
        try:
            rates = bench_learner.measure(bench_learner.parser().parse_args(base + extra))
        except Exception as exc:  # noqa: BLE001 - a variant that fails is a finding, reported as such
            rows.append({**row, "failed": _why(exc)})
            continue
        ref = rates[bench_learner.REFERENCE]
        rows.append(
            {
                **row,
                "updates_per_s": {k: round(v, 2) for k, v in rates.items()},
                "accrue_vs_reference": round(rates[bench_learner.ACCRUE] / ref, 3),
                "sequential_vs_reference": round(rates[bench_learner.SEQUENTIAL] / ref, 3),
            }
        )
    return rows


def cpu_physics_rate(task_id: str, num_envs: int, control_steps: int) -> dict:
    import bench_sim

    env, env_rate, _expert, episodes = bench_sim.run_env(task_id, num_envs, control_steps, threads=os.cpu_count() or 1)
    raw_ctrl, raw_phys = bench_sim.raw_rate(env, episodes)
    model = env.batch.get_model(0)
    env.close()
    return {
        "env_control_steps_per_s": round(env_rate, 1),
        "raw_physics_steps_per_s_one_core": round(raw_phys, 1),
        "substeps": env.task.substeps,
        "_model": model,
    }


def warp_physics_rate(model, nworld: int, nstep: int) -> dict:
    """MuJoCo Warp physics steps/s over nworld copies of one task model; the reason when it cannot run."""
    try:
        import mujoco
        import mujoco_warp as mjw
        import warp as wp
    except ImportError as exc:
        return {"not_run": f"mujoco_warp is not importable here ({_why(exc)})"}
    try:
        m = mjw.put_model(model)
        d = mjw.put_data(model, mujoco.MjData(model), nworld=nworld)
        mjw.step(m, d)  # compile the kernels before timing
        wp.synchronize()
        t = time.perf_counter()
        for _ in range(nstep):
            mjw.step(m, d)
        wp.synchronize()
        dt = time.perf_counter() - t
    except Exception as exc:  # noqa: BLE001 - unsupported scene features surface here
        return {"not_run": f"MuJoCo Warp cannot run this scene: {_why(exc)}"}
    return {"physics_steps_per_s": round(nworld * nstep / dt, 1), "nworld": nworld, "nstep": nstep}


def env_rows(small: bool, cuda: bool) -> list[dict]:
    rows = []
    for task_id in FAMILY_TASKS:
        row: dict = {"task": task_id}
        try:
            cpu = cpu_physics_rate(task_id, 4 if small else 64, 40 if small else 4000)
        except Exception as exc:  # noqa: BLE001
            rows.append({**row, "cpu": {"failed": _why(exc)}})
            continue
        model = cpu.pop("_model")
        row["cpu"] = cpu
        if cuda:
            row["warp"] = warp_physics_rate(model, 4096, 200)
        else:
            row["warp"] = {"not_run": "no CUDA device (MuJoCo Warp runs these scenes on the GPU)"}
            if not small:  # still say whether the scene would load
                row["warp"]["import"] = warp_physics_rate(model, 1, 0).get("not_run", "importable")
        rows.append(row)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--small", action="store_true", help="CPU-sized rows (CI); the default on a machine without CUDA")
    ap.add_argument("--no-compile", action="store_true", help="skip the torch.compile rows (they compile for minutes)")
    ap.add_argument("--skip-env", action="store_true")
    ap.add_argument("--out", type=Path, default=None, help="write the rows as JSON here")
    args = ap.parse_args()
    import torch

    cuda = torch.cuda.is_available()
    device = "cuda" if cuda else "cpu"
    small = args.small or not cuda
    started = time.perf_counter()
    report = {
        "command": " ".join(["python", "benchmarks/gpu_path.py", *sys.argv[1:]]),
        "device": torch.cuda.get_device_name(0) if cuda else f"CPU ({os.cpu_count()} cores, {platform.processor()})",
        "small": small,
        "torch": torch.__version__,
    }
    try:
        report["learner"] = learner_rows(device, small, not args.no_compile)
        report["env"] = [] if args.skip_env else env_rows(small, cuda)
    except Exception:  # noqa: BLE001 - keep what was measured; the trace says where it stopped
        report["error"] = traceback.format_exc().splitlines()[-1]
    report["wall_s"] = round(time.perf_counter() - started, 1)
    text = json.dumps(report, indent=2)
    print(text)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
