"""Issue 21 item 6: interventions (beyond the paper, off by default).

The operator takes over through a lerobot Teleoperator; on the simulated robot that is `accrue_sim_expert`,
the scripted expert holding the takeover button (its IS_INTERVENTION event) during a configured window of
control steps. The steps it drives execute and store its action, are marked in the sealed transitions and
in what the learner receives, counted in episode.json and the 20-episode intervention rate, shown to the
operator and written to the tracker. Without a robot.intervention section nothing changes.

The learner is tests/test_robot_hold's stand-in link, which here also keeps every episode it is pushed
(exactly the bytes a LearnerService stores)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from robot_workflow import run_stage
from test_robot_hold import fake_link, hold_workflow, use_link

from accrue.errors import AccrueError
from stages.errors import StageError

pytestmark = pytest.mark.timeout(600)
H = 4  # the test workflow's horizon
WINDOW = [2, 7]  # control steps 2..6 of the episode: chunk 0 steps 2-3, chunk 1 steps 0-2


def teleop(calib: Path, **config) -> dict:
    return {"teleop": "accrue_sim_expert", "config": {"calibration_dir": str(calib), **config}}


@pytest.fixture(scope="module")
def warm_store(tmp_path_factory):
    from artifacts.store import Store

    root = tmp_path_factory.mktemp("take-warm")
    Store.init(root / "store")
    run_stage(root / "store", hold_workflow(root / "hw.yaml", root / "calib"), 1, step="warmup")
    return root


@pytest.fixture
def store(warm_store, tmp_path):
    shutil.copytree(warm_store / "store", tmp_path / "store")
    return tmp_path


def last_checkpoint(store_root: Path, step: str) -> dict[int, tuple[dict, dict]]:
    """{index: (episode.json, transitions)} of the step's newest intra-step checkpoint."""
    from artifacts.auditlog import iter_events
    from artifacts.manifests import materialize
    from artifacts.store import Store

    st = Store.open(store_root)
    cid = [e["checkpoint"] for e in iter_events(st) if e.get("event") == "robot-episode-sealed"][-1]
    d = materialize(st, cid, store_root.parent / f"ckpt-{step}")
    out = {}
    for p in sorted((d / "episodes").glob("*/episode.json")):
        e = json.loads(p.read_text())
        with np.load(p.parent / "transitions.npz") as z:
            out[e["index"]] = (e, {k: z[k] for k in z.files})
    return out


def expected_marks(steps: np.ndarray, lo: int, hi: int) -> np.ndarray:
    marks = np.zeros((len(steps), H), dtype=bool)
    t = 0
    for i, n in enumerate(steps):
        for h in range(int(n)):
            marks[i, h] = lo <= t < hi
            t += 1
    return marks


def test_a_takeover_window_marks_exactly_its_steps_in_the_seal_and_what_the_learner_gets(store, monkeypatch):
    from accrue.robot.episode import intervention_rows, replay_from_episodes
    from accrue.robot.learner_service import read_npz
    from accrue.robot.operator import ScriptedOperator
    from accrue.robot.sim_robot import AccrueSimExpert
    from accrue.tracking import run_name, tracking_dir

    # every action the teleop answered, by (episode, control step): signal: events reads it every step, before
    # that step's events (the expert's step count moves with its events)
    given: dict[tuple, dict] = {}
    plain_action = AccrueSimExpert.get_action

    def get_action(self):
        a = plain_action(self)
        given[(self._episode, self._step)] = a
        return a

    monkeypatch.setattr(AccrueSimExpert, "get_action", get_action)
    shown: list[tuple[str, dict]] = []
    monkeypatch.setattr(ScriptedOperator, "show", lambda self, state: shown.append(("show", dict(state))))
    plain_reset = ScriptedOperator.wait_reset
    monkeypatch.setattr(
        ScriptedOperator,
        "wait_reset",
        lambda self, *a: (shown.append(("reset", {})), plain_reset(self, *a))[1],
    )

    received: dict[int, dict] = {}
    Link = fake_link()

    class Keeping(Link):
        def push(self, header, blob):
            received[int(header["index"])] = read_npz(blob)
            super().push(header, blob)

    use_link(monkeypatch, store / "store", Keeping)
    # train's episodes are 3, 4, 5 (after warmup's 0-2): the expert takes over in 3 and 5
    wf = hold_workflow(
        store / "hw.yaml", store / "calib", intervention=teleop(store / "tcalib", takeover=[WINDOW], episodes=[3, 5])
    )
    results = run_stage(store / "store", wf, 1, step="train")

    eps = last_checkpoint(store / "store", "train")
    assert sorted(eps) == [3, 4, 5]
    total_marked = 0
    for index, (e, arrays) in eps.items():
        lo, hi = WINDOW if index in (3, 5) else (0, 0)
        want = expected_marks(arrays["steps"], lo, hi)
        assert np.array_equal(arrays["intervention"], want), index  # exactly the window's steps
        assert e["interventions"] == int(want.sum()) == (hi - lo)
        assert e["intervened_chunks"] == int(want.any(axis=1).sum())
        total_marked += e["interventions"]
        assert [t for (k, t) in given if k == index] == list(range(e["control_steps"]))  # read every step
        for i, h in zip(*np.nonzero(want)):  # the stored action is the human's, as the teleop gave it
            a = given[(index, int(arrays["steps"][:i].sum()) + int(h))]
            assert np.allclose(arrays["action"][i, h], [a[k] for k in a], atol=1e-6)
        # the learner got the same transitions, flag and human action included (nothing reset the flag)
        assert set(received[index]) == set(arrays)
        for k in arrays:
            assert np.array_equal(received[index][k], arrays[k]), (index, k)

    # the learner's buffer rows (as LearnerService builds them) carry the human chunks, flagged per row
    rows = [received[i] for i in sorted(received)]
    from accrue.learner import ReplayBuffer

    buf = replay_from_episodes(ReplayBuffer(rows[0]["s"].shape[-1], H), rows, 0)
    flags = intervention_rows(rows)
    assert len(flags) == len(buf) and flags.sum() == 2 * 2
    stored = np.concatenate([r["action"] for r in rows])
    assert np.array_equal(buf.column("action").numpy(), stored)
    # the window (steps 2-6) touches chunks 0 and 1 of episodes 3 and 5, nothing else
    n3, n4, n5 = (len(received[i]["action"]) for i in (3, 4, 5))
    assert n3 >= 2 and n5 >= 2
    want_rows = np.zeros(n3 + n4 + n5, dtype=bool)
    want_rows[[0, 1, n3 + n4, n3 + n4 + 1]] = True
    assert np.array_equal(buf.column("intervention").numpy(), want_rows)
    assert np.array_equal(flags, want_rows)

    # the train step's replay artifact (warmup rows first, none driven) keeps the column through its shards
    from artifacts.manifests import materialize
    from artifacts.store import Store

    replay = materialize(Store.open(store / "store"), results["train"].outputs["replay"], store / "replay")
    committed = ReplayBuffer.load(replay)
    warm = len(committed) - len(want_rows)
    assert warm > 0 and committed.column("episode")[warm:].unique().tolist() == [3, 4, 5]
    assert np.array_equal(committed.column("intervention").numpy(), np.r_[np.zeros(warm, dtype=bool), want_rows])
    assert np.array_equal(committed.column("action")[warm:].numpy(), stored)

    # the window rate by hand: intervened control steps over all control steps of the (3) episodes
    steps = sum(e["control_steps"] for e, _ in eps.values())
    rate = total_marked / steps
    from accrue.robot.teleop import window_rate

    assert window_rate([(e["interventions"], e["control_steps"]) for e, _ in eps.values()]) == pytest.approx(rate)

    # shown: before the first reset prompt already (phase, window), and the counts during the session
    # (warmup ran again here: its robot.config names another calibration dir than the fixture's)
    first = next(i for i, (kind, s) in enumerate(shown) if kind == "show" and s["phase"] == "train")
    assert "window" in shown[first][1] and shown[first + 1][0] == "reset"
    states = [s for kind, s in shown[first:] if kind == "show"]
    assert any(s.get("intervening") for s in states) and all("intervention_rate_window" in s for s in states)
    assert states[-1]["intervention_rate_window"] == pytest.approx(round(rate, 4))

    # the tracker: robot/interventions per episode and the window rate
    from test_tracking import read_scalars

    scalars = read_scalars(tracking_dir(store / "store", run_name("hw", 1, "train")))
    assert [v for _, v in scalars["robot/interventions"]] == [5.0, 0.0, 5.0]
    assert scalars["robot/intervention_rate_window"][-1][1] == pytest.approx(rate, rel=1e-5)

    # the report's robot section: the rate per 20-episode window (here one window of three episodes)
    from artifacts.store import Store
    from stages.report.hardware import write_hardware_report
    from stages.workflow import load_workflow

    summary = write_hardware_report(Store.open(store / "store"), load_workflow(wf), store / "report")
    [w] = summary["interventions"][1]["windows"]
    assert w == {
        "episodes": "3-5",
        "intervened_steps": total_marked,
        "control_steps": steps,
        "episodes_with_interventions": 2,
        "rate": round(rate, 4),
    }
    assert (
        f"| 1 | 3-5 | {total_marked} | {steps} | 2 | {100 * rate:.1f}% |"
        in (store / "report" / "interventions.md").read_text()
    )


def test_the_operators_key_takes_over_from_the_next_step_until_the_episode_ends(tmp_path, monkeypatch):
    """signal: key - the operator's `i` (here at episode 1's second poll, i.e. after its second chunk) hands
    the robot to the teleop from the next control step; the next episode starts with the policy again."""
    from accrue.robot.operator import ScriptedOperator
    from artifacts.store import Store

    polls = {"n": 0}

    def poll(self):
        polls["n"] += 1
        return "intervene" if self.episode_now == 1 and polls["n"] == polls["at"] else None

    plain_reset = ScriptedOperator.wait_reset

    def wait_reset(self, episode, task, last):
        self.episode_now = episode
        polls["at"] = polls["n"] + 2
        return plain_reset(self, episode, task, last)

    monkeypatch.setattr(ScriptedOperator, "poll", poll)
    monkeypatch.setattr(ScriptedOperator, "wait_reset", wait_reset)
    Store.init(tmp_path / "store")
    section = {**teleop(tmp_path / "tcalib"), "signal": "key"}
    run_stage(
        tmp_path / "store", hold_workflow(tmp_path / "hw.yaml", tmp_path / "calib", intervention=section), 1, "warmup"
    )
    eps = last_checkpoint(tmp_path / "store", "warmup")
    for index, (e, arrays) in eps.items():
        want = np.zeros_like(arrays["intervention"])
        if index == 1:
            for i, n in enumerate(arrays["steps"]):
                want[i, : int(n)] = i >= 2  # every executed step from the third chunk on
        assert np.array_equal(arrays["intervention"], want), index
        assert e["interventions"] == int(want.sum())
    assert eps[1][0]["interventions"] > 0


def test_off_by_default_changes_nothing(tmp_path):
    """No robot.intervention: no flag, no count; an intervention section whose teleop never takes over
    executes exactly the same actions (only the all-False flag and the zero count are added)."""
    from artifacts.store import Store

    runs = {}
    for name, extra in (("off", {}), ("idle", {"intervention": teleop(tmp_path / "tcalib")})):
        root = tmp_path / name
        Store.init(root / "store")
        run_stage(root / "store", hold_workflow(root / "hw.yaml", tmp_path / "calib", **extra), 1, step="warmup")
        runs[name] = last_checkpoint(root / "store", "warmup")
    assert sorted(runs["off"]) == sorted(runs["idle"]) == [0, 1, 2]
    for index in runs["off"]:
        (e_off, a_off), (e_idle, a_idle) = runs["off"][index], runs["idle"][index]
        assert "intervention" not in a_off and "interventions" not in e_off
        assert not a_idle["intervention"].any() and e_idle["interventions"] == 0
        assert set(a_idle) - set(a_off) == {"intervention"}
        for k in a_off:
            assert np.array_equal(a_off[k], a_idle[k]), (index, k)


@pytest.mark.parametrize(
    "section, says",
    [
        ({"teleop": "no_such_teleop"}, "robot.intervention.teleop: unknown lerobot teleoperator type 'no_such_teleop'"),
        ({"teleop": "accrue_sim_expert", "config": {"speed": 3}}, "robot.intervention.config: not a valid"),
        (
            {"teleop": "accrue_sim_expert", "action_map": {"x.pos": "dx"}},
            "robot.intervention: 'x.pos' is not one of the robot's action keys",
        ),
        (
            {"teleop": "accrue_sim_expert", "action_map": {"dx": "delta_x"}},
            "robot.intervention.action_map: the teleoperator has no action 'delta_x' for 'dx'",
        ),
    ],
)
def test_a_bad_intervention_section_is_one_line(tmp_path, section, says):
    from artifacts.store import Store

    Store.init(tmp_path / "store")
    section = {**section, "config": {"calibration_dir": str(tmp_path / "tcalib"), **section.get("config", {})}}
    wf = hold_workflow(tmp_path / "hw.yaml", tmp_path / "calib", intervention=section)
    with pytest.raises(AccrueError) as err:
        run_stage(tmp_path / "store", wf, 1, step="warmup")
    line = str(err.value)
    assert "\n" not in line and says in line, line


def test_a_bad_signal_is_refused_when_the_workflow_loads(tmp_path):
    from stages.workflow import load_workflow

    wf = hold_workflow(tmp_path / "hw.yaml", tmp_path / "calib", intervention={"teleop": "gamepad", "signal": "x"})
    with pytest.raises(StageError) as err:
        load_workflow(wf)
    assert "\n" not in str(err.value) and "intervention.signal" in str(err.value)


def test_the_operators_i_key_toggles_the_takeover_only_when_it_is_on():
    from accrue.robot.operator_page import PageOperator

    audit: list[tuple[str, dict]] = []
    pg = PageOperator("op", terminal=False, audit=lambda ev, f: audit.append((ev, f)))
    try:
        pg.press("i")
        assert pg.poll() is None and "key 'i' does nothing here" in pg.state()["messages"][-1]
        pg.takeover_key = True
        pg.press("i")
        assert pg.poll() == "intervene"
        assert audit[-1][1]["action"] == "takeover" and audit[-1][1]["via"] == "page"
    finally:
        pg.close()


def test_lerobots_keyboard_ee_maps_onto_the_robots_action_keys(tmp_path):
    """lerobot's own keyboard end-effector teleop, found by name and built by lerobot's factory: its deltas
    drive the keys action_map names (scaled by action_scale), the keys it lacks are held (0 for deltas), and
    the result is the normalised action clipped to [-1, 1] like a policy's."""
    from lerobot.teleoperators.utils import TeleopEvents

    from accrue.robot.mapping import RobotMapping
    from accrue.robot.teleop import Intervention
    from accrue.sim.observation import ACTION_NAMES

    take = Intervention.from_dict(
        {
            "teleop": "keyboard_ee",
            "config": {"calibration_dir": str(tmp_path / "kcal")},
            "action_map": {"dx": "delta_x", "dy": "delta_y", "dz": "delta_z"},
            "action_scale": {"dz": 3.0},
        }
    )
    take.teleop = take.make_teleop()  # not connected: no keyboard listener in a test
    assert type(take.teleop).__name__ == "KeyboardEndEffectorTeleop"
    mapping = RobotMapping(action_limits=(0.5,) * 6).bind({"q": float}, {k: float for k in ACTION_NAMES}, "robot")
    take.connect(mapping)
    take.teleop.get_teleop_events = lambda: {TeleopEvents.IS_INTERVENTION: True}
    take.teleop.get_action = lambda: {"delta_x": 0.25, "delta_y": -1.0, "delta_z": 0.5, "gripper": 1.0}
    a = take.step({"q": 0.0}, mapping)
    # robot units / action_limits: 0.25 / 0.5, -1 / 0.5 -> clipped, 0.5 * 3 / 0.5 -> clipped; the rest held
    assert np.allclose(a, [0.5, -1.0, 1.0, 0.0, 0.0, 0.0]) and take.steps == 1
    take.teleop.get_teleop_events = lambda: {TeleopEvents.IS_INTERVENTION: False}
    assert take.step({"q": 0.0}, mapping) is None and take.steps == 1


def test_a_teleoperator_that_stops_answering_ends_the_episode_not_the_session(tmp_path, monkeypatch):
    """A stuck teleop (its get_action stops returning in episode 1, where the takeover window begins) is given
    up after robot.intervention.timeout_s: the episode ends as a fault, labelled a failure by the system, and
    the next episodes go on."""
    import threading

    from accrue.robot.sim_robot import AccrueSimExpert
    from artifacts.store import Store

    stuck = threading.Event()
    plain = AccrueSimExpert.get_action

    def get_action(self):  # signal: events reads it every step, before the step's events (which count steps)
        if self._episode == 1 and self._step >= WINDOW[0]:
            return stuck.wait(60)
        return plain(self)

    monkeypatch.setattr(AccrueSimExpert, "get_action", get_action)
    Store.init(tmp_path / "store")
    # every teleop call of episodes 0-2 has this deadline too: 2 s, which a loaded machine does not miss (0.3 could)
    section = {**teleop(tmp_path / "tcalib", takeover=[WINDOW], episodes=[1]), "timeout_s": 2.0}
    try:
        run_stage(
            tmp_path / "store",
            hold_workflow(tmp_path / "hw.yaml", tmp_path / "calib", intervention=section),
            1,
            "warmup",
        )
    finally:
        stuck.set()  # the worker thread left behind returns
    eps = last_checkpoint(tmp_path / "store", "warmup")
    assert sorted(eps) == [0, 1, 2]
    e = eps[1][0]
    assert e["end"] == "fault" and e["label"]["by"] == "system" and not e["label"]["success"]
    assert "the teleoperator did not answer get_action within 2 s" in e["reason"]
    assert e["control_steps"] == WINDOW[0] and e["interventions"] == 0  # it never drove a step
    assert eps[0][0]["end"] != "fault" and eps[2][0]["end"] != "fault"


def test_a_teleop_whose_package_is_missing_is_one_line_naming_the_extra(tmp_path, monkeypatch):
    """lerobot 0.6 checks a teleop's package itself (e.g. keyboard_ee's pynput) and raises its own
    ImportError; the intervention section turns it into one line naming lerobot's extra."""
    from lerobot.utils import import_utils

    from accrue.robot.teleop import Intervention

    monkeypatch.setitem(import_utils._require_package_cache, "pynput", False)
    take = Intervention.from_dict(
        {
            "teleop": "keyboard_ee",
            "config": {"calibration_dir": str(tmp_path / "kcal")},
            "action_map": {"dx": "delta_x"},
        }
    )
    with pytest.raises(AccrueError) as err:
        take.make_teleop()
    line = str(err.value)
    assert "\n" not in line and line.startswith("robot.intervention.teleop keyboard_ee: ")
    assert "'pynput'" in line and "lerobot[pynput-dep]" in line


TELEOP_PLUGIN = """
from dataclasses import dataclass

from lerobot.teleoperators.config import TeleoperatorConfig
from lerobot.teleoperators.teleoperator import Teleoperator


@TeleoperatorConfig.register_subclass("accrue_test_plugin_pad")
@dataclass
class PluginPadConfig(TeleoperatorConfig):
    gain: float = 1.0


class PluginPad(Teleoperator):
    config_class = PluginPadConfig
    name = "accrue_test_plugin_pad"

    def __init__(self, config):
        super().__init__(config)
        self.config = config

    action_features = property(lambda self: {"dx": float})
    feedback_features = property(lambda self: {})
    is_connected = property(lambda self: True)
    is_calibrated = property(lambda self: True)

    def connect(self, calibrate=True):
        pass

    def calibrate(self):
        pass

    def configure(self):
        pass

    def get_action(self):
        return {"dx": self.config.gain}

    def send_feedback(self, feedback):
        pass

    def disconnect(self):
        pass
"""


def test_an_installed_lerobot_teleoperator_plugin_is_found_without_an_imports_line(tmp_path, monkeypatch):
    """The teleop is found as the robot is (one shared lerobot_factory): a lerobot_teleoperator_* distribution
    registers its type on import; its config is checked in one line like a built-in's."""
    from accrue.robot.teleop import teleop_factory

    pkg = tmp_path / "lerobot_teleoperator_accrue_test"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("from .plugin_pad import PluginPad, PluginPadConfig\n")
    (pkg / "plugin_pad.py").write_text(TELEOP_PLUGIN)
    dist = tmp_path / "lerobot_teleoperator_accrue_test-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: lerobot_teleoperator_accrue_test\nVersion: 0.1\n")
    monkeypatch.syspath_prepend(str(tmp_path))

    pad = teleop_factory("accrue_test_plugin_pad", {"gain": 0.25, "calibration_dir": str(tmp_path / "pcal")})()
    assert type(pad).__name__ == "PluginPad" and pad.get_action() == {"dx": 0.25}
    with pytest.raises(AccrueError, match=r"^robot.intervention.config: not a valid PluginPadConfig"):
        teleop_factory("accrue_test_plugin_pad", {"no_such_field": 1})


def test_lerobots_keyboard_and_arm_teleops_connect_with_the_arguments_they_take(tmp_path, monkeypatch):
    """lerobot 0.6's KeyboardTeleop / GamepadTeleop take connect() with no argument, its arms take
    connect(calibrate=...): the takeover connects each the way its own signature allows (calling the keyboard
    with calibrate=False was a TypeError, so keyboard_ee and gamepad could never connect). Where the keyboard
    cannot capture keys (headless, Wayland) lerobot connects without a listener: that is one line, not a silent
    teleop that never acts."""
    import lerobot.teleoperators.keyboard.teleop_keyboard as kb

    from accrue.errors import AccrueError
    from accrue.robot.mapping import RobotMapping
    from accrue.robot.teleop import Intervention, connect_without_calibration
    from accrue.sim.observation import ACTION_NAMES

    calls: list[tuple] = []

    class NoArgs:
        def connect(self):
            calls.append(("no-args",))

    class Arm:
        def connect(self, calibrate: bool = True):
            calls.append(("arm", calibrate))

    connect_without_calibration(NoArgs())
    connect_without_calibration(Arm())
    assert calls == [("no-args",), ("arm", False)]

    mapping = RobotMapping(action_limits=(0.5,) * 6).bind({"q": float}, {k: float for k in ACTION_NAMES}, "robot")
    spec = {
        "teleop": "keyboard_ee",
        "config": {"calibration_dir": str(tmp_path / "k")},
        "action_map": {"dx": "delta_x"},
    }
    monkeypatch.setattr(kb, "pynput_can_capture", lambda: False)  # as on this headless machine, whatever DISPLAY is
    take = Intervention.from_dict(spec)
    with pytest.raises(AccrueError, match="KeyboardEndEffectorTeleop reports it is not connected after connect"):
        take.connect(mapping)

    # a keyboard that can capture: lerobot's own connect runs (its listener replaced by a stand-in thread)
    started = []

    class Listener:
        def __init__(self, on_press, on_release):
            pass

        def start(self):
            started.append(True)

        def is_alive(self):
            return True

    monkeypatch.setattr(kb, "pynput_can_capture", lambda: True)
    monkeypatch.setattr(kb, "PYNPUT_AVAILABLE", True)
    monkeypatch.setattr(kb, "keyboard", type("keyboard", (), {"Listener": Listener}), raising=False)
    take = Intervention.from_dict(spec)
    take.connect(mapping)
    assert started == [True] and take.teleop.is_connected
