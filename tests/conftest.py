"""Test-wide settings: nothing reaches the network, rendering is headless."""
import os

for _key, _value in {
    "HF_HUB_OFFLINE": "1",
    "HF_DATASETS_OFFLINE": "1",
    "TRANSFORMERS_OFFLINE": "1",
    "MUJOCO_GL": "egl",
    "RERUN": "off",
}.items():
    os.environ.setdefault(_key, _value)
