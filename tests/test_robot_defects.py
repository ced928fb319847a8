"""Issue 20's defects of the robot path: lerobot's own robots found by type name (a missing SDK named in
one line with the extra to install), and `r` from a person at the terminal resetting the simulated scene."""

from __future__ import annotations

import importlib.util

import pytest

from accrue.errors import AccrueError


def test_builtin_robot_types_are_found_without_an_imports_line():
    from accrue.robot.robot_types import builtin_module, builtin_types

    assert builtin_module("so101_follower") == "lerobot.robots.so_follower"
    assert builtin_module("koch_follower") == "lerobot.robots.koch_follower"
    assert builtin_module("no_such_arm") is None
    assert "accrue_sim" not in builtin_types()  # only lerobot's own robots


@pytest.mark.skipif(importlib.util.find_spec("scservo_sdk") is not None, reason="lerobot[feetech] is installed")
def test_so101_without_its_sdk_is_one_line_naming_the_extra(tmp_path):
    from accrue.robot.bridge import robot_factory

    with pytest.raises(AccrueError) as err:
        robot_factory("so101_follower", {"port": "/dev/ttyACM0", "id": "arm0", "calibration_dir": str(tmp_path)})
    line = str(err.value)
    # lerobot 0.6 checks for the SDK's distribution before importing it, and names it
    assert "\n" not in line and "'feetech-servo-sdk'" in line and "pip install 'lerobot[feetech]'" in line
    assert line.startswith("robot.type so101_follower: lerobot.robots.so_follower needs")


def test_robot_imports_line_missing_module_is_one_line():
    from accrue.robot.bridge import robot_factory

    with pytest.raises(AccrueError, match=r"robot.imports: no_such_robot_pkg needs 'no_such_robot_pkg'"):
        robot_factory("accrue_sim", {}, ("no_such_robot_pkg",))


def keyed_terminal():
    """accrue's TerminalOperator reading keys from a script instead of a tty: what a person types."""
    from rich.console import Console

    from accrue.robot.operator import TerminalOperator

    class KeyedTerminal(TerminalOperator):
        def __init__(self, name, console=None, audit=None):
            self.name, self.console, self._saved = name, console or Console(stderr=True), None
            self._audit = audit
            self.typed = list("rs" * 20)  # reset done, success; again and again

        def _key(self, timeout):
            return None if timeout == 0 else self.typed.pop(0)  # nothing typed during an episode

    return KeyedTerminal


def test_r_at_the_terminal_resets_the_simulated_scene(tmp_path, monkeypatch):
    """Every warmup episode starts from a fresh scene: before the fix, episode 2 on was 'done, 0 steps'."""
    from robot_workflow import robot_events, run_stage, write_hw_workflow

    from accrue.robot import operator as operator_module
    from artifacts.store import Store

    monkeypatch.setattr(operator_module, "TerminalOperator", keyed_terminal())
    Store.init(tmp_path / "store")
    wf = write_hw_workflow(tmp_path / "hw.yaml", tmp_path / "calib")
    wf.write_text(wf.read_text().replace("operator: scripted", "operator: terminal"))
    run_stage(tmp_path / "store", wf, 1, step="warmup")
    sealed = robot_events(tmp_path / "store", "robot-episode-sealed")
    assert len(sealed) == 3
    for e in sealed:  # each episode acted on a fresh scene: robot time > 0, labelled by the person
        assert e["robot_time_s"] > 0 and e["label_by"] == "scripted-test", e


PLUGIN = """
from dataclasses import dataclass

from lerobot.robots.config import RobotConfig
from lerobot.robots.robot import Robot


@RobotConfig.register_subclass("accrue_test_plugin_arm")
@dataclass
class PluginArmConfig(RobotConfig):
    gain: float = 1.0


class PluginArm(Robot):
    config_class = PluginArmConfig
    name = "accrue_test_plugin_arm"

    def __init__(self, config):
        super().__init__(config)
        self.config, self._connected, self.sent = config, False, []

    observation_features = property(lambda self: {"x.pos": float})
    action_features = property(lambda self: {"x.pos": float})
    is_connected = property(lambda self: self._connected)
    is_calibrated = property(lambda self: True)

    def connect(self, calibrate=True):
        self._connected = True

    def calibrate(self):
        pass

    def configure(self):
        pass

    def get_observation(self):
        return {"x.pos": self.config.gain}

    def send_action(self, action):
        self.sent.append(action)
        return action

    def disconnect(self):
        self._connected = False
"""


def test_installed_lerobot_robot_plugin_is_found_without_an_imports_line(tmp_path, monkeypatch):
    """lerobot 0.6's plugin convention: a distribution named lerobot_robot_* registers its robot on import."""
    from accrue.robot.bridge import robot_factory

    pkg = tmp_path / "lerobot_robot_accrue_test"
    pkg.mkdir()
    (pkg / "__init__.py").write_text(
        "from .config_plugin_arm import PluginArmConfig\nfrom .plugin_arm import PluginArm\n"
    )
    (pkg / "config_plugin_arm.py").write_text(PLUGIN.split("class PluginArm(Robot)")[0])
    (pkg / "plugin_arm.py").write_text(
        "from lerobot.robots.robot import Robot\n\nfrom .config_plugin_arm import PluginArmConfig\n\n\n"
        "class PluginArm(Robot)" + PLUGIN.split("class PluginArm(Robot)")[1]
    )
    dist = tmp_path / "lerobot_robot_accrue_test-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: lerobot_robot_accrue_test\nVersion: 0.1\n")
    monkeypatch.syspath_prepend(str(tmp_path))

    make = robot_factory("accrue_test_plugin_arm", {"gain": 2.5, "calibration_dir": str(tmp_path / "calib")})
    robot = make()
    robot.connect()
    assert type(robot).__name__ == "PluginArm" and robot.get_observation() == {"x.pos": 2.5}
    with pytest.raises(AccrueError, match="robot.config: not a valid PluginArmConfig"):
        robot_factory("accrue_test_plugin_arm", {"no_such_field": 1})
