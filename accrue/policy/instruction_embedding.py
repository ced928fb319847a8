"""A fixed-size, deterministic embedding of an instruction string for policies without language input.

ACT and Diffusion take no text, so accrue conditions them on the task by feeding this vector as
`observation.environment_state`. Words and word pairs are hashed into a fixed number of signed
buckets (the "hashing trick"), so new instructions at later stages never change the input shape
and the same text always maps to the same vector, on any machine.
"""

from __future__ import annotations

import hashlib
import re

import numpy as np

ENV_STATE_KEY = "observation.environment_state"
DEFAULT_EMBEDDING_DIM = 32

_TOKEN = re.compile(r"[a-z0-9]+")


def _signed_bucket(token: str, dim: int) -> tuple[int, float]:
    digest = hashlib.blake2b(token.encode("utf-8"), digest_size=8).digest()
    value = int.from_bytes(digest, "little")
    return value % dim, (1.0 if (value >> 63) & 1 else -1.0)


def embed_instruction(text: str, dim: int = DEFAULT_EMBEDDING_DIM) -> np.ndarray:
    """(dim,) float32 unit vector; identical texts (up to case and punctuation) give identical vectors."""
    if dim < 1:
        raise ValueError(f"embedding dim must be >= 1, got {dim}")
    words = _TOKEN.findall(text.lower())
    tokens = [f"w:{w}" for w in words] + [f"b:{a}_{b}" for a, b in zip(words, words[1:])]
    vec = np.zeros(dim, dtype=np.float64)
    for token in tokens or ["<empty>"]:
        index, sign = _signed_bucket(token, dim)
        vec[index] += sign
    norm = np.linalg.norm(vec)
    if norm == 0.0:  # every token cancelled out: fall back to the whole-string bucket
        index, sign = _signed_bucket(f"s:{text}", dim)
        vec[index] = sign
        norm = 1.0
    return (vec / norm).astype(np.float32)


def embed_instructions(texts: list[str], dim: int = DEFAULT_EMBEDDING_DIM) -> np.ndarray:
    """(len(texts), dim) float32."""
    return np.stack([embed_instruction(t, dim) for t in texts]).astype(np.float32)
