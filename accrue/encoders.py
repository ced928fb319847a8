"""Frozen visual encoders E for the actor-critic state s = (E(I), q) (paper Sec. IV-A).

The encoder is independent of the base policy and fixed across stages, so features of a frame are
computed once and cached on disk under (encoder id, frame hash). The encoder id includes a hash of
the weights file, so a different file can never be served stale features.

Specs:  "none"                          -> (B, 0) features, for state-only runs
        "<model>:<weights.safetensors>" -> a timm model loaded offline from that file, where <model>
                                           is an alias below or any timm model name
"""

from __future__ import annotations

import functools
import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from accrue.errors import AccrueError

# alias -> (timm model name, input size used on CPU; DINOv2's native 518 px is too slow there)
ALIASES = {
    "dinov2-small": ("vit_small_patch14_dinov2.lvd142m", 224),
    "dinov2-base": ("vit_base_patch14_dinov2.lvd142m", 224),
    "dinov2-small-reg": ("vit_small_patch14_reg4_dinov2.lvd142m", 224),
    "dinov3-small": ("vit_small_patch16_dinov3.lvd1689m", 224),
    "dinov3-small-plus": ("vit_small_plus_patch16_dinov3.lvd1689m", 224),
    "dinov3-base": ("vit_base_patch16_dinov3.lvd1689m", 224),
}


def _file_digest(path: Path) -> str:
    h = hashlib.blake2b(digest_size=16)
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def frame_hash(image: np.ndarray) -> str:
    """Content hash of one (h, w, 3) uint8 frame, shape included."""
    h = hashlib.blake2b(digest_size=16)
    h.update(repr(image.shape).encode())
    h.update(np.ascontiguousarray(image).tobytes())
    return h.hexdigest()


def _check_images(images: np.ndarray) -> np.ndarray:
    images = np.asarray(images)
    if images.ndim != 4 or images.shape[-1] != 3 or images.dtype != np.uint8:
        raise AccrueError(f"encoder input must be (B, h, w, 3) uint8, got {images.dtype} {list(images.shape)}")
    return images


class FeatureCache:
    """Features by frame hash: one .npy per frame under <dir>/<encoder id>/ab/<hash>.npy, or in memory."""

    def __init__(self, encoder_id: str, cache_dir: Path | None):
        self.dir = Path(cache_dir) / encoder_id if cache_dir is not None else None
        self._memory: dict[str, np.ndarray] = {}
        self.hits = 0
        self.misses = 0

    def _path(self, key: str) -> Path:
        assert self.dir is not None
        return self.dir / key[:2] / f"{key}.npy"

    def get(self, key: str) -> np.ndarray | None:
        found = self._memory.get(key)
        if found is None and self.dir is not None and self._path(key).is_file():
            found = np.load(self._path(key))
        if found is None:
            self.misses += 1
        else:
            self.hits += 1
        return found

    def put(self, key: str, features: np.ndarray) -> None:
        if self.dir is None:
            self._memory[key] = features
            return
        path = self._path(key)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".tmp{np.random.randint(1 << 30)}.npy")
        np.save(tmp, features)
        tmp.replace(path)  # atomic publish: a reader never sees half a file


class NoEncoder:
    """State-only runs: zero visual features."""

    encoder_id = "none"
    feature_dim = 0

    def __init__(self):
        self.cache = FeatureCache("none", None)

    def encode(self, images: np.ndarray) -> np.ndarray:
        return np.zeros((len(images), 0), dtype=np.float32)


class TimmEncoder:
    """A frozen timm backbone returning its pooled embedding per frame."""

    def __init__(self, model_name: str, weights: Path, image_size: int | None, cache_dir: Path | None):
        import timm
        import torch

        if not weights.is_file():
            raise AccrueError(f"encoder weights file {weights} does not exist (download it once, then pass its path)")
        kwargs = {"img_size": image_size} if image_size else {}
        try:
            self.model = timm.create_model(
                model_name,
                pretrained=True,
                num_classes=0,
                pretrained_cfg_overlay=dict(file=str(weights)),
                **kwargs,
            )
        except RuntimeError as exc:
            raise AccrueError(
                f"encoder weights {weights} do not fit timm model '{model_name}': {str(exc).splitlines()[0]}"
            ) from exc
        except Exception as exc:  # noqa: BLE001 - unknown names, unreadable files
            raise AccrueError(
                f"cannot build encoder '{model_name}' from {weights}: {str(exc).splitlines()[0]}"
            ) from exc
        self.model.eval().requires_grad_(False)
        config = timm.data.resolve_model_data_config(self.model)
        # timm's data config reports the pretrained size even when img_size overrides it
        self.input_size = (image_size, image_size) if image_size else tuple(config["input_size"][1:])
        self.mean = torch.tensor(config["mean"]).view(1, 3, 1, 1)
        self.std = torch.tensor(config["std"]).view(1, 3, 1, 1)
        self.feature_dim = int(self.model.num_features)
        self.encoder_id = f"{model_name}@{self.input_size[0]}x{self.input_size[1]}-{_file_digest(weights)}"
        self.cache = FeatureCache(self.encoder_id, cache_dir)

    def _forward(self, images: np.ndarray) -> np.ndarray:
        import torch
        import torch.nn.functional as F

        x = torch.from_numpy(np.ascontiguousarray(images)).permute(0, 3, 1, 2).float() / 255.0
        if tuple(x.shape[-2:]) != self.input_size:
            x = F.interpolate(x, size=self.input_size, mode="bilinear", align_corners=False, antialias=True)
        with torch.no_grad():
            return self.model((x - self.mean) / self.std).float().numpy()

    def encode(self, images: np.ndarray) -> np.ndarray:
        images = _check_images(images)
        out = np.empty((len(images), self.feature_dim), dtype=np.float32)
        keys = [frame_hash(img) for img in images]
        todo = []
        for i, key in enumerate(keys):
            cached = self.cache.get(key)
            if cached is None:
                todo.append(i)
            else:
                out[i] = cached
        if todo:
            fresh = self._forward(images[todo])
            for row, i in enumerate(todo):
                out[i] = fresh[row]
                self.cache.put(keys[i], fresh[row])
        return out


@dataclass(frozen=True)
class EncoderSpec:
    model_name: str
    weights: Path
    image_size: int | None


def parse_spec(spec: str) -> EncoderSpec | None:
    """None for "none"; otherwise "<model>:<weights path>"."""
    if spec.strip().lower() == "none":
        return None
    model, sep, path = spec.partition(":")
    if not sep or not model or not path:
        raise AccrueError(
            f"encoder spec '{spec}' must be 'none' or '<model>:<weights file>', e.g. dinov2-small:/models/dinov2_small.safetensors"
        )
    name, size = ALIASES.get(model, (model, None))
    return EncoderSpec(name, Path(path).expanduser(), size)


def encoder_identity(spec: str) -> str:
    """What a step computing s = (E(I), q) keys on: the model, its input size and the weights file's digest
    (a path names a file; a new file under the same path is a new encoder). "none" for none."""
    parsed = parse_spec(spec)
    if parsed is None:
        return "none"
    if not parsed.weights.is_file():
        raise AccrueError(
            f"encoder weights file {parsed.weights} does not exist (download it once, then pass its path)"
        )
    stat = parsed.weights.stat()
    return f"{parsed.model_name}@{parsed.image_size or 'native'}-{_cached_digest(str(parsed.weights), stat.st_size, stat.st_mtime_ns)}"


@functools.lru_cache(maxsize=16)
def _cached_digest(path: str, size: int, mtime_ns: int) -> str:
    return _file_digest(Path(path))  # size and mtime in the key: a rewritten file is hashed again


def make_encoder(spec: str, cache_dir: Path | str | None = None, image_size: int | None = None):
    """An object with .encode(images (B,h,w,3) uint8) -> (B, F) float32, .feature_dim, .encoder_id, .cache."""
    parsed = parse_spec(spec)
    if parsed is None:
        return NoEncoder()
    try:
        import timm
    except ImportError as exc:
        raise AccrueError("encoders need the 'timm' package (pip install 'timm>=1.0,<1.1')") from exc
    if parsed.model_name not in timm.list_models(pretrained=True) and parsed.model_name not in timm.list_models():
        raise AccrueError(
            f"unknown encoder model '{parsed.model_name}' (aliases: {', '.join(ALIASES)}, or any timm model name)"
        )
    return TimmEncoder(
        parsed.model_name, parsed.weights, image_size or parsed.image_size, Path(cache_dir) if cache_dir else None
    )
