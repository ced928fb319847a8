"""Recognise a lerobot policy checkpoint directory and say clearly what is missing or unsupported."""

from __future__ import annotations

import json
from pathlib import Path

from accrue.errors import AccrueError

CONFIG_FILE = "config.json"
WEIGHTS_FILE = "model.safetensors"
PREPROCESSOR_FILE = "policy_preprocessor.json"
POSTPROCESSOR_FILE = "policy_postprocessor.json"

# Policy types that need more than lerobot's core install, and what the user must provide.
NEEDS_EXTRAS = {
    "smolvla": "lerobot[smolvla] and the SmolVLM2 weights and processor in the local HF cache "
    "(or a local path in config.json 'vlm_model_name')",
    "pi0": "lerobot[pi] with lerobot's patched transformers and the PaliGemma tokenizer in the local HF cache",
    "pi05": "lerobot[pi] with lerobot's patched transformers and the PaliGemma tokenizer in the local HF cache",
    "pi0_fast": "lerobot[pi] with lerobot's patched transformers and the PaliGemma tokenizer in the local HF cache",
    "groot": "lerobot[groot] (flash-attn, CUDA) and the GR00T base model and eagle processor in the local HF cache",
}


def read_checkpoint_config(checkpoint_dir: Path) -> dict:
    """The parsed config.json of a checkpoint dir, after checking the files lerobot needs are there."""
    checkpoint_dir = Path(checkpoint_dir)
    if not checkpoint_dir.is_dir():
        raise AccrueError(f"policy checkpoint {checkpoint_dir} does not exist or is not a directory")
    for name in (CONFIG_FILE, WEIGHTS_FILE, PREPROCESSOR_FILE, POSTPROCESSOR_FILE):
        if not (checkpoint_dir / name).is_file():
            raise AccrueError(f"policy checkpoint {checkpoint_dir} is missing {name}")
    try:
        config = json.loads((checkpoint_dir / CONFIG_FILE).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise AccrueError(f"policy checkpoint {checkpoint_dir}: {CONFIG_FILE} is not valid JSON ({exc})") from exc
    if not isinstance(config, dict) or not isinstance(config.get("type"), str):
        raise AccrueError(f"policy checkpoint {checkpoint_dir}: {CONFIG_FILE} has no policy 'type'")
    return config


def check_policy_type_known(policy_type: str, checkpoint_dir: Path) -> None:
    import lerobot.policies.factory  # noqa: F401 - registers every policy config type
    from lerobot.configs.policies import PreTrainedConfig

    import accrue.policy.chunk_mlp  # noqa: F401 - and accrue's own (the embedded base policy)

    known = PreTrainedConfig.get_known_choices()
    if policy_type not in known:
        raise AccrueError(
            f"policy checkpoint {checkpoint_dir}: unknown policy type '{policy_type}' "
            f"(this lerobot knows: {', '.join(sorted(known))})"
        )


def input_shapes(config: dict) -> dict[str, tuple[int, ...]]:
    """Input feature name -> shape, from a checkpoint's config.json."""
    return {k: tuple(v["shape"]) for k, v in (config.get("input_features") or {}).items()}


def first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__
