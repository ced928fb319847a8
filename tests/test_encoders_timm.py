"""Frozen timm encoders loaded offline from a local safetensors file, with a frame-feature cache."""

from __future__ import annotations

import numpy as np
import pytest

from accrue.encoders import make_encoder
from accrue.errors import AccrueError

MODEL = "vit_tiny_patch16_224"


def _write_weights(path, seed: int):
    import timm
    import torch
    from safetensors.torch import save_file

    torch.manual_seed(seed)
    model = timm.create_model(MODEL, pretrained=False, num_classes=0, img_size=32)
    save_file(model.state_dict(), str(path))
    return model


def _images(n=3, seed=0, hw=(40, 48)):
    return np.random.default_rng(seed).integers(0, 256, (n, *hw, 3), dtype=np.uint8)


@pytest.fixture
def weights(tmp_path):
    path = tmp_path / "vit.safetensors"
    return path, _write_weights(path, seed=0)


def test_encoder_loads_weights_from_local_file(weights, tmp_path, monkeypatch):
    import torch
    import torch.nn.functional as F

    path, reference = weights
    monkeypatch.setattr("accrue.encoders.ALIASES", {"tiny": (MODEL, 32)})  # an alias with its input size
    encoder = make_encoder(f"tiny:{path}", cache_dir=tmp_path / "cache")
    images = _images()
    features = encoder.encode(images)
    assert features.shape == (3, encoder.feature_dim) == (3, 192) and features.dtype == np.float32

    x = F.interpolate(
        torch.from_numpy(images).permute(0, 3, 1, 2).float() / 255,
        size=(32, 32),
        mode="bilinear",
        align_corners=False,
        antialias=True,
    )
    with torch.no_grad():
        want = reference.eval()((x - 0.5) / 0.5).numpy()
    np.testing.assert_allclose(features, want, atol=1e-5)


def _tiny_encoder(path, cache_dir):
    return make_encoder(f"{MODEL}:{path}", cache_dir=cache_dir, image_size=32)


def test_cache_hits_on_repeated_frames_and_across_instances(weights, tmp_path, monkeypatch):
    path, _ = weights
    encoder = _tiny_encoder(path, tmp_path / "cache")
    images = _images(n=2)
    first = encoder.encode(images)
    assert (encoder.cache.hits, encoder.cache.misses) == (0, 2)
    batch = np.stack([images[1], images[1], _images(n=1, seed=9)[0]])
    again = encoder.encode(batch)
    assert (encoder.cache.hits, encoder.cache.misses) == (2, 3)
    np.testing.assert_array_equal(again[0], first[1])
    assert len(list((tmp_path / "cache" / encoder.encoder_id).rglob("*.npy"))) == 3

    fresh = _tiny_encoder(path, tmp_path / "cache")  # a new process would find the same files
    np.testing.assert_array_equal(fresh.encode(images), first)
    assert (fresh.cache.hits, fresh.cache.misses) == (2, 0)


def test_encoder_id_tracks_weights_file(tmp_path, monkeypatch):
    a, b = tmp_path / "a.safetensors", tmp_path / "b.safetensors"
    _write_weights(a, seed=0)
    _write_weights(b, seed=1)
    enc_a = _tiny_encoder(a, tmp_path / "cache")
    enc_b = _tiny_encoder(b, tmp_path / "cache")
    assert enc_a.encoder_id != enc_b.encoder_id and enc_a.encoder_id.startswith(MODEL)
    images = _images(n=1)
    assert not np.allclose(enc_a.encode(images), enc_b.encode(images))
    assert enc_b.cache.misses == 1  # never served features computed with other weights


def test_none_encoder_returns_empty_features():
    encoder = make_encoder("none")
    assert encoder.encode(_images(n=4)).shape == (4, 0)
    assert encoder.feature_dim == 0


def test_encoder_errors_are_one_line(tmp_path, weights):
    path, _ = weights
    for spec, message in [
        ("dinov2-small", "must be 'none' or '<model>:<weights file>'"),
        (f"dinov2-small:{tmp_path / 'missing.safetensors'}", "does not exist"),
        (f"not_a_model_xyz:{path}", "unknown encoder model"),
        (f"vit_small_patch16_224:{path}", "do not fit timm model"),
    ]:
        with pytest.raises(AccrueError, match=message) as info:
            make_encoder(spec)
        assert "\n" not in str(info.value)
    encoder = make_encoder("none")
    assert encoder.encoder_id == "none"
