"""Test-wide settings: nothing reaches the network, rendering is headless."""

import os

import pytest

for _key, _value in {
    "HF_HUB_OFFLINE": "1",
    "HF_DATASETS_OFFLINE": "1",
    "TRANSFORMERS_OFFLINE": "1",
    "MUJOCO_GL": "egl",
    "RERUN": "off",
}.items():
    os.environ.setdefault(_key, _value)


@pytest.fixture()
def one_torch_thread():
    """Tiny networks: more torch threads only add overhead on the 2-core CI machine."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(autouse=True)
def cwd_is_left_as_found():
    """A test that changes directory without monkeypatch breaks every later test that uses a
    relative path (CI failed this way once); this puts it back and names the test that did it."""
    before = os.getcwd()
    yield
    after = os.getcwd()
    if after != before:
        os.chdir(before)
        pytest.fail(f"the test left the working directory at {after}", pytrace=False)
