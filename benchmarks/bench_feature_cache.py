"""What the frozen encoder's per-frame feature cache saves: frames/s of E(I) without it and with it.

    .venv/bin/python benchmarks/bench_feature_cache.py [--model dinov2-small] [--frames 48] [--size 64]

The encoder is the workflow's (accrue.encoders.make_encoder): `--model` an alias (dinov2-small: DINOv2
ViT-S/14 at 224 px, as the robot docs' download gives) or any timm model name, its weights made here from
`--seed` and saved to a temporary safetensors file (the speed does not depend on the values, and nothing is
downloaded). `--frames` distinct (h, w, 3) uint8 frames of `--size` px, as a robot's camera gives them, are
encoded three ways, each timed over every frame:

    no cache        each frame's forward pass (a fresh encoder: every frame a miss)
    memory cache    the same frames again in that process (every frame a hit: hash + lookup), as the
                    workflow steps' encoder keeps them
    disk cache      an encoder given a cache directory that another one filled (hash + one .npy per frame)

One torch thread (the stages' setting). Prints one line per way with frames/s and ms per frame.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def seeded_weights(model: str, seed: int, path: Path) -> str:
    """The spec of an encoder `model` whose weights are drawn from `seed` and saved at `path`."""
    import timm
    import torch
    from safetensors.torch import save_file

    from accrue.encoders import ALIASES

    name, size = ALIASES.get(model, (model, None))
    torch.manual_seed(seed)
    net = timm.create_model(name, pretrained=False, num_classes=0, **({"img_size": size} if size else {}))
    save_file(net.state_dict(), str(path))
    return f"{model}:{path}"


def timed(encode, frames: np.ndarray) -> tuple[float, np.ndarray]:
    """(seconds for every frame, one frame at a time as the actor encodes them, the features)."""
    started = time.perf_counter()
    out = np.concatenate([encode(frames[i : i + 1]) for i in range(len(frames))])
    return time.perf_counter() - started, out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="dinov2-small")
    parser.add_argument("--frames", type=int, default=48)
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    import torch

    from accrue.encoders import make_encoder

    torch.set_num_threads(1)
    n = args.frames
    frames = np.random.default_rng(args.seed).integers(0, 256, (args.frames, args.size, args.size, 3), np.uint8)
    with tempfile.TemporaryDirectory() as tmp:
        spec = seeded_weights(args.model, args.seed, Path(tmp) / "weights.safetensors")
        encoder = make_encoder(spec)  # as the workflows' steps make it: the cache in the process's memory
        encoder.encode(frames[:1] ^ 1)  # the first forward's one-off costs (allocations) are not a frame's
        cold, first = timed(encoder.encode, frames)
        warm, again = timed(encoder.encode, frames)
        writer = make_encoder(spec, cache_dir=Path(tmp) / "cache")
        writer.encode(frames)  # computed once more and written, one .npy per frame
        reader = make_encoder(spec, cache_dir=Path(tmp) / "cache")
        disk, read = timed(reader.encode, frames)
    assert (encoder.cache.misses, encoder.cache.hits, reader.cache.hits) == (n + 1, n, n)
    assert np.array_equal(first, again) and np.allclose(first, read, atol=1e-6)  # the same features served
    print(
        f"encoder {encoder.encoder_id.split('-')[0]} ({encoder.feature_dim} features), {n} frames of "
        f"{args.size}x{args.size} px, 1 torch thread"
    )
    for name, seconds in (("no cache", cold), ("memory cache", warm), ("disk cache", disk)):
        print(f"{name:>13}: {n / seconds:10.1f} frames/s  ({1000 * seconds / n:8.3f} ms/frame)")
    print(f"{'speed-up':>13}: {cold / warm:.0f}x from memory, {cold / disk:.0f}x from disk")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
