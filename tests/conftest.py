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


@pytest.fixture(autouse=True)
def sim_task_list_left_as_found():
    """An SO-101 workflow's robot.imports (accrue.robot.sim_robot.so101_tasks) adds so101/* to the process's
    task list, and tests that iterate list_tasks() expect the simulator's tasks (with their USD files) only:
    after each test those tasks go and the module is forgotten, so the next workflow that names it imports
    it again and registers them anew."""
    import sys

    yield
    tasks = sys.modules.get("accrue.sim.tasks")
    if sys.modules.pop("accrue.robot.sim_robot.so101_tasks", None) is not None and tasks is not None:
        for task_id in [t for t, spec in tasks._REGISTRY.items() if spec.family == "so101"]:
            del tasks._REGISTRY[task_id]
