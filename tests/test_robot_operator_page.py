"""The operator page (issue 21 item 5): every request needs the token (a refused one is 403 and in the
audit), the live state and the camera frame are served, the page's keys and the terminal's go into one
operator; and a real browser (Debian's headless Chromium, driven by playwright) runs a whole simulated
warmup session from the page (reset, labels, pause, re-label, end, abort), which the audit log and the
sealed labels (via="page") show; and with robot.intervention, the page's interventions row and its `i` button
(a takeover from the page, in the audit log and in the sealed transitions)."""

from __future__ import annotations

import io
import json
import os
import queue
import shutil
import threading
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from test_robot_operator import tty_keys  # noqa: F401 - a fixture (its pty), shared with that file

from accrue.errors import AccrueError

CHROMIUM = "chromium"  # Debian's headless-capable Chromium, looked up on PATH
CAMERA = True  # the episode loop shows a frame only once the robot has observed one


def request(url: str, path: str, token: str | None = None, data: dict | None = None, header: bool = True):
    """(status, body bytes) of one request; the token as header or as ?token=."""
    if token is not None and not header:
        path += ("&" if "?" in path else "?") + f"token={token}"
    req = urllib.request.Request(
        url.rstrip("/") + path,
        data=None if data is None else json.dumps(data).encode(),
        headers={"X-Accrue-Token": token} if token is not None and header else {},
    )
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.read()


@pytest.fixture
def make_page():
    """make(**PageOperator keywords) -> (a PageOperator "ann", its console output, its audit records); every
    page made is closed after the test."""
    from rich.console import Console

    from accrue.robot.operator_page import PageOperator

    made = []

    def make(**kwargs):
        out, audited = io.StringIO(), []
        op = PageOperator(
            "ann",
            **{"console": Console(file=out, width=300), "audit": lambda e, f: audited.append((e, f)), **kwargs},
        )
        made.append(op)
        return op, out, audited

    yield make
    for op in made:
        op.close()


@pytest.fixture
def page(make_page):
    op, _, audited = make_page(token="s3cret-token", terminal=False)
    return op, audited


def test_every_request_needs_the_token_and_a_refusal_is_audited(page):
    op, audited = page
    assert op.url.startswith("http://127.0.0.1:") and "token" not in op.url
    for path in ("/", "/state.json", "/frame.jpg"):
        assert request(op.url, path)[0] == 403
        assert request(op.url, path, token="s3cret-tokem")[0] == 403
        assert request(op.url, path, token="s3cret-tokem", header=False)[0] == 403
    status, body = request(op.url, "/action", data={"key": "a"})
    assert status == 403 and op._queue.empty()  # a refused action never reaches the operator
    status, body = request(op.url, "/")
    assert b"needs the operator token" in body and b"s3cret" not in body
    refused = [f for e, f in audited if e == "robot-operator-page-refused"]
    assert len(refused) == 11 and {f["reason"] for f in refused} == {"no token", "wrong token"}
    assert all(f["via"] == "page" and f["remote"] == "127.0.0.1" and "token" not in f["path"] for f in refused)
    assert not any("s3cret" in json.dumps(f) for _, f in audited)  # the token is never audited
    assert request(op.url, "/state.json", token="s3cret-token")[0] == 200
    assert request(op.url, "/state.json?x=1", token="s3cret-token", header=False)[0] == 200
    status, body = request(op.url, "/", token="s3cret-token", header=False)
    assert status == 200 and b"accrue operator" in body and b"<script" in body
    assert b"http://" not in body and b"https://" not in body  # self-contained: nothing fetched from elsewhere


def test_state_and_frame_are_what_was_shown(page):
    op, _ = page
    token = op.token
    assert request(op.url, "/frame.jpg", token)[0] == 404  # no camera frame yet
    frame = np.zeros((48, 64, 3), dtype=np.uint8)
    frame[:, :32] = (250, 10, 10)  # left half red
    op.show(
        {
            "task": "nist/rect_peg",
            "phase": "train",
            "episode": np.int64(7),
            "step": 40,
            "window": [np.bool_(True), False, True],
            "robot_time_s": np.float32(12.5),
            "learner_version": 3,
            "learner_health": "ok",
            "interventions": 0,
            "status": "episode 7 running",
            "frame": frame,
            "not_a_state_key": object(),
        }
    )
    op.show({"step": 44})  # a partial update keeps the rest
    state = json.loads(request(op.url, "/state.json", token)[1])
    assert state["shown"] == {
        "task": "nist/rect_peg",
        "phase": "train",
        "episode": 7,
        "step": 44,
        "window": [True, False, True],
        "robot_time_s": 12.5,
        "learner_version": 3,
        "learner_health": "ok",
        "interventions": 0,
        "status": "episode 7 running",
    }
    assert state["frame_seq"] == 1 and state["operator"] == "ann"
    status, jpeg = request(op.url, "/frame.jpg", token)
    assert status == 200 and jpeg[:2] == b"\xff\xd8"
    from PIL import Image

    img = np.asarray(Image.open(io.BytesIO(jpeg)))
    assert img.shape == (48, 64, 3) and img[:, :20, 0].mean() > 200 and img[:, 44:, 0].mean() < 30


def test_page_keys_drive_the_operator_and_are_audited(page):
    op, audited = page
    token = op.token
    out: queue.Queue = queue.Queue()
    t = threading.Thread(target=lambda: out.put(op.wait_reset(1, "nist/rect_peg", 0)))
    t.start()
    for key in "lfr":  # re-label episode 0 a failure, reset done
        assert request(op.url, "/action", token, data={"key": key}) == (200, json.dumps({"queued": key}).encode())
    assert request(op.url, "/action", token, data={"key": "rr"})[0] == 400
    assert request(op.url, "/action", token, data={"nokey": 1})[0] == 400
    answer = out.get(timeout=10)
    t.join()
    assert answer.go and answer.relabel.success is False and answer.relabel.via == "page"
    state = json.loads(request(op.url, "/state.json", token)[1])
    assert state["prompt"]["expect"] == "episode" and state["prompt"]["keys"] == "epa"
    assert state["actions"] == 2 and state["last_action"]["action"] == "reset"
    assert "episode 0 re-labelled failure" in state["messages"]
    op.press("e")
    assert op.poll() == "end"
    actions = [(f["action"], f["via"], f.get("episode")) for e, f in audited if e == "robot-operator-action"]
    assert actions == [("relabel", "page", 0), ("reset", "page", 1), ("end", "page", 1)]


def test_the_terminal_and_the_page_are_one_operator(tty_keys, make_page):
    op, console, audited = make_page()
    assert op._tty is not None  # terminal None: a tty is there, so it is read too
    tty_keys("xr")  # a stray key at the terminal, then reset done there
    assert op.wait_reset(0, "nist/rect_peg", None).go
    assert "key 'x' does nothing here" in console.getvalue()
    state = json.loads(request(op.url, "/state.json", op.token)[1])
    assert any("key 'x' does nothing here" in m for m in state["messages"])  # the page sees the same lines
    request(op.url, "/action", op.token, data={"key": "s"})  # labelled on the page
    label = op.label(0, "done, 40 steps")
    assert label.success and label.via == "page"
    op.close()
    actions = [(f["action"], f["via"]) for e, f in audited if e == "robot-operator-action"]
    assert actions == [("reset", "terminal"), ("label", "page")]
    with pytest.raises(urllib.error.URLError):  # closed: the server is gone
        urllib.request.urlopen(op.url + "state.json", timeout=5)


def test_listen_mistakes_are_one_line(page):
    from accrue.robot.operator_page import PageOperator

    op, _ = page
    with pytest.raises(AccrueError, match=r"robot.operator_page.listen: 'localhost' is not HOST:PORT"):
        PageOperator("ann", listen="localhost", terminal=False)
    port = op.url.rsplit(":", 1)[1].strip("/")
    with pytest.raises(AccrueError, match=rf"robot.operator_page.listen: cannot listen on 127.0.0.1:{port} "):
        PageOperator("ann", listen=f"127.0.0.1:{port}", terminal=False)


@pytest.mark.parametrize("everywhere, here", [("0.0.0.0", "127.0.0.1"), ("::", "[::1]")])
def test_listening_on_all_interfaces_gives_a_url_a_browser_can_open(make_page, everywhere, here):
    import socket

    try:
        op, out, audited = make_page(
            listen=f"{'[::]' if everywhere == '::' else everywhere}:0", token="s3cret-token", terminal=False
        )
    except AccrueError as exc:
        if everywhere == "::":
            pytest.skip(f"no IPv6 here: {exc}")
        raise
    port = op._server.server_address[1]
    assert op.url == f"http://{here}:{port}/"  # not http://{everywhere}:PORT/, which no browser opens
    assert request(op.url, "/state.json", "s3cret-token")[0] == 200
    said = out.getvalue()
    assert f"listening on all interfaces ({everywhere} port {port})" in said
    assert f"on this machine open {op.url}" in said
    assert f"from another one http://{socket.gethostname()}:{port}/" in said
    [started] = [f for e, f in audited if e == "robot-operator-page-started"]
    assert started["url"] == op.url


def test_a_page_on_one_address_prints_no_all_interfaces_line(page):
    op, _ = page
    assert op.listening is None and op.url == f"http://127.0.0.1:{op._server.server_address[1]}/"
    assert "all interfaces" not in op.console.file.getvalue()


# ---------------------------------------------------------------------- a real browser, a whole session


def find_chromium() -> str:
    """The browser's path (shutil.which). None there: the test fails when the CI variable is set (.ci/run
    installs it, so CI must not pass without running the browser tests), and is skipped, naming the
    missing binary, anywhere else."""
    found = shutil.which(CHROMIUM)
    if found is None:
        why = f"no `{CHROMIUM}` on PATH: apt-get install chromium chromium-driver (.ci/run installs them)"
        if os.environ.get("CI", "").lower() not in ("", "0", "false", "no"):
            pytest.fail(f"CI={os.environ['CI']} and the browser test cannot run: {why}", pytrace=False)
        pytest.skip(why)
    return found


@pytest.fixture
def chromium() -> str:
    return find_chromium()


@pytest.mark.parametrize("ci", [None, "", "0", "false", "true", "1"])
def test_a_missing_browser_fails_under_ci_and_is_skipped_naming_it_elsewhere(monkeypatch, ci):
    if ci is None:
        monkeypatch.delenv("CI", raising=False)
    else:
        monkeypatch.setenv("CI", ci)
    monkeypatch.setattr(shutil, "which", lambda name: {"chromium": "/opt/b/chromium"}.get(name))
    assert find_chromium() == "/opt/b/chromium"  # found on PATH, wherever it is
    monkeypatch.setattr(shutil, "which", lambda name: None)
    under_ci = ci in ("true", "1")
    with pytest.raises(pytest.fail.Exception if under_ci else pytest.skip.Exception) as info:
        find_chromium()
    assert "no `chromium` on PATH" in str(info.value)
    assert (f"CI={ci}" in str(info.value)) is under_ci


def page_workflow(tmp_path: Path) -> Path:
    """The tests' tiny hardware workflow with the page operator and the simulated robot's front camera."""
    from robot_workflow import write_hw_workflow

    wf = write_hw_workflow(tmp_path / "hw.yaml", tmp_path / "calib")
    text = wf.read_text()
    text = text.replace("operator: scripted", 'operator: page\n  operator_page: {listen: "127.0.0.1:0"}')
    if CAMERA:
        text = text.replace("estimate_noise: 0.3}", "estimate_noise: 0.3, render_cameras: [front], image_size: 96}")
    wf.write_text(text)
    return wf


class SessionThread:
    """The stage in a thread of this process, with a hook on the page operator make_operator builds."""

    def __init__(
        self,
        store: Path,
        wf: Path,
        step: str,
        monkeypatch,
        hold_episode: int | None = None,
        hold_key: str = "e",
        seen: threading.Event | None = None,
    ):
        from robot_workflow import run_stage

        from accrue.robot import operator_page

        made: queue.Queue = queue.Queue()
        pressed = threading.Event()

        class Recorded(operator_page.PageOperator):
            def __init__(self, *args, **kwargs):
                super().__init__(*args, **kwargs)
                made.put(self)

            def press(self, key, via="page"):
                super().press(key, via)
                if key == hold_key:
                    pressed.set()

            def poll(self):
                # a person presses the hold key (e, i) while the episode runs: the episode waits for it at its
                # first chunk's end, so the test need not race a fast simulated episode; with `seen`, once the
                # page has been shown the operator driving, the episode waits until the test has seen it too
                if hold_episode is not None and self._episode == hold_episode:  # polled in an episode
                    assert pressed.wait(60), f"{hold_key} never came from the page"
                    if seen is not None and self.state()["shown"].get("intervening"):
                        assert seen.wait(60), "the test never saw the takeover on the page"
                return super().poll()

        monkeypatch.setattr(operator_page, "PageOperator", Recorded)
        self.error: BaseException | None = None

        def run():
            try:
                run_stage(store, wf, 1, step=step)
            except BaseException as exc:  # noqa: BLE001 - reported to the test
                self.error = exc

        self.thread = threading.Thread(target=run, name="stage", daemon=True)
        self.thread.start()
        self.made = made

    def operator(self):
        while True:
            try:
                return self.made.get(timeout=1)
            except queue.Empty:
                assert self.thread.is_alive(), f"the stage ended before its operator page started: {self.error!r}"


def wait_prompt(pg, expect: str, episode: int | None = None, timeout_s: float = 60) -> None:
    cond = f"document.body.dataset.expect === {json.dumps(expect)}"
    if episode is not None:
        cond += f" && document.body.dataset.episode === '{episode}'"
    pg.wait_for_function(cond, timeout=timeout_s * 1000)


@pytest.fixture
def headless(chromium):
    """Headless Chromium (playwright), closed after the test. expect() waits up to 60 s: the page follows the
    session, which waits on nothing but the page, and on a loaded machine (a cold first episode renders the
    camera) a state can take longer than playwright's 5 s default to appear."""
    from playwright.sync_api import expect, sync_playwright

    expect.set_options(timeout=60_000)
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=chromium, args=["--no-sandbox", "--disable-gpu"])
        yield b
        b.close()


@pytest.fixture
def store(tmp_path) -> Path:
    """An empty store at tmp_path/store."""
    from artifacts.store import Store

    Store.init(tmp_path / "store")
    return tmp_path / "store"


def open_page(b, url: str, store: Path, height: int = 760):
    """A tab of browser `b` on the operator page at `url`, with the store's link token."""
    from accrue.robot.link_auth import store_token

    pg = b.new_page(viewport={"width": 1100, "height": height})
    pg.goto(url + f"?token={store_token(store)}")
    return pg


@pytest.mark.slow
def test_a_whole_simulated_session_from_the_page(tmp_path, monkeypatch, store, headless):
    from playwright.sync_api import expect
    from robot_workflow import robot_events

    from artifacts.manifests import materialize
    from artifacts.store import Store
    from stages.errors import StageError

    wf = page_workflow(tmp_path)
    session = SessionThread(store, wf, "warmup", monkeypatch, hold_episode=1)
    op = session.operator()
    assert request(op.url, "/state.json")[0] == 403  # no token: refused and in the store's audit log
    pg = open_page(headless, op.url, store)
    wait_prompt(pg, "reset", 0)
    expect(pg.locator("#task")).to_have_text("nist/rect_peg")
    expect(pg.locator("#conn")).to_have_text("live")
    pg.keyboard.press("l")  # nothing to re-label before the first episode: the page says so
    expect(pg.locator("#messages")).to_contain_text("no episode to re-label yet")
    pg.click("#btn-r")
    wait_prompt(pg, "label", 0)
    expect(pg.locator("#phase")).to_have_text("warmup")
    if CAMERA:
        expect(pg.locator("#frame")).to_be_visible()  # the simulated camera's frame
    pg.click("#btn-s")
    wait_prompt(pg, "reset", 1)
    expect(pg.locator("#window-text")).to_have_text("1/1")
    expect(pg.locator("#marks span.ok")).to_have_count(1)
    pg.keyboard.press("p")
    expect(pg.locator("#paused")).to_be_visible()
    expect(pg.locator("#btn-r")).to_be_disabled()  # paused: no reset until resumed
    pg.click("#btn-p")
    expect(pg.locator("#paused")).to_be_hidden()
    pg.click("#btn-l")  # re-label episode 0 a failure
    wait_prompt(pg, "relabel", 0)
    expect(pg.locator("#btn-f")).to_have_text("re-label failuref")
    pg.keyboard.press("f")
    wait_prompt(pg, "reset", 1)
    expect(pg.locator("#messages")).to_contain_text("episode 0 re-labelled failure")
    pg.keyboard.press("r")
    wait_prompt(pg, "episode", 1)
    pg.click("#btn-e")  # end episode 1 early
    wait_prompt(pg, "label", 1)
    pg.click("#btn-f")
    wait_prompt(pg, "reset", 2)
    expect(pg.locator("#window-text")).to_have_text("0/2")
    expect(pg.locator("#marks span.bad")).to_have_count(2)
    pg.click("#btn-a")
    session.thread.join(timeout=60)
    assert not session.thread.is_alive()
    expect(pg.locator("#conn")).to_contain_text("no connection")  # the step ended, its server with it
    assert isinstance(session.error, StageError) and "aborted by the operator" in str(session.error)

    actions = [e for e in robot_events(store, "robot-operator-action")]
    assert [(e["action"], e.get("episode"), e.get("success")) for e in actions] == [
        ("reset", 0, None),
        ("label", 0, True),
        ("pause", None, None),
        ("resume", None, None),
        ("relabel", 0, False),
        ("reset", 1, None),
        ("end", 1, None),
        ("label", 1, False),
        ("abort", 2, None),
    ]
    assert all(e["via"] == "page" and e["phase"] == "warmup" and e["stage"] == 1 for e in actions)
    refused = robot_events(store, "robot-operator-page-refused")
    assert [(e["path"], e["reason"]) for e in refused] == [("/state.json", "no token")]
    sealed = robot_events(store, "robot-episode-sealed")
    assert [(e["index"], e["success"], e["end"]) for e in sealed] == [(0, True, "done"), (1, False, "operator")]
    relabelled = robot_events(store, "robot-episode-relabelled")
    assert [(e["index"], e["success"], e["was"]) for e in relabelled] == [(0, False, True)]
    ended = robot_events(store, "robot-session-ended")
    assert [e["how"] for e in ended] == ["aborted by the operator"]
    discarded = robot_events(store, "robot-episode-discarded")
    assert discarded == []  # aborted at the reset prompt: no episode was in progress
    # the sealed labels themselves say they came from the page
    last = sealed[-1]["checkpoint"]  # episode 1 was sealed after episode 0's re-label
    sealed_dir = materialize(Store.open(store), last, tmp_path / "sealed")
    ep0 = json.loads((sealed_dir / "episodes" / "000000" / "episode.json").read_text())
    ep1 = json.loads((sealed_dir / "episodes" / "000001" / "episode.json").read_text())
    assert ep0["label"]["via"] == "page" and ep0["label"]["success"] is False
    assert ep0["relabels"][0]["via"] == "page" and ep0["relabels"][0]["success"] is True
    assert ep0["label"]["note"] == "re-label of episode 0"
    assert ep1["label"]["via"] == "page" and ep1["end"] == "operator"


SCREENSHOT = os.environ.get("ACCRUE_OPERATOR_SCREENSHOT")


@pytest.mark.skipif(not SCREENSHOT, reason="makes docs/operator-page.png: ACCRUE_OPERATOR_SCREENSHOT=PATH")
def test_screenshot_of_a_training_session(tmp_path, monkeypatch, store, headless):
    """docs/operator-page.png: stage 1 warmup and training driven from the page (labels as the simulated
    robot reports them, as a person watching would), photographed at a label prompt mid-training."""
    from accrue.robot import learner_client
    from accrue.robot.link_auth import store_token

    monkeypatch.setitem(learner_client._AHEAD, "on", True)  # as `accrue stage run`: warmup starts train's learner
    wf = page_workflow(tmp_path)
    session = SessionThread(store, wf, "train", monkeypatch)
    token = store_token(store)
    pg = headless.new_page(viewport={"width": 1100, "height": 720})
    for phase, episodes in (("warmup", 3), ("train", 9)):
        op = session.operator()
        pg.goto(op.url + f"?token={token}")
        for i in range(episodes):
            # train's robot is held before its first action until its learner is up (a busy machine: minutes)
            wait_prompt(pg, "reset", timeout_s=300 if phase == "train" and i == 0 else 60)
            pg.click("#btn-r")
            wait_prompt(pg, "label")
            ok = bool(op_success(pg))
            pg.click("#btn-s" if ok else "#btn-f")
        if phase == "warmup":  # its last episode may still be re-labelled: r finishes the step
            wait_prompt(pg, "finish")
            pg.click("#btn-r")
        if phase == "train":
            wait_prompt(pg, "reset")
            pg.click("#btn-r")
            wait_prompt(pg, "label")
            pg.wait_for_function("document.getElementById('frame').complete")
            Path(SCREENSHOT).parent.mkdir(parents=True, exist_ok=True)
            pg.screenshot(path=SCREENSHOT)
            pg.click("#btn-a")
    session.thread.join(timeout=60)


def op_success(pg) -> bool:
    """What the person saw: the episode's end line says 'done' when the plug seated."""
    return "(done," in (pg.text_content("#prompt") or "")


def intervention_page_workflow(tmp_path: Path) -> Path:
    """The page workflow without a camera, with the simulated expert as the teleop the operator's `i` hands
    the robot to (robot.intervention signal: key)."""
    from robot_workflow import write_hw_workflow

    wf = write_hw_workflow(tmp_path / "hw.yaml", tmp_path / "calib")
    take = {"teleop": "accrue_sim_expert", "config": {"calibration_dir": str(tmp_path / "tcalib")}, "signal": "key"}
    text = wf.read_text().replace(
        "operator: scripted",
        f'operator: page\n  operator_page: {{listen: "127.0.0.1:0"}}\n  intervention: {json.dumps(take)}',
    )
    wf.write_text(text)
    return wf


@pytest.mark.slow
def test_the_page_shows_interventions_and_its_i_button_takes_over(tmp_path, monkeypatch, store, headless):
    """With robot.intervention (signal: key) the page's `i` button, enabled only during an episode, hands the
    robot to the teleop from the next chunk: the page shows OPERATOR DRIVING while it drives, then the
    episode's count and the window rate the sealed episode gives; the audit log has the takeover from the
    page, and the sealed transitions mark exactly the chunks after it."""
    from playwright.sync_api import expect
    from robot_workflow import robot_events

    from artifacts.manifests import materialize
    from artifacts.store import Store
    from stages.errors import StageError

    seen = threading.Event()
    session = SessionThread(store, intervention_page_workflow(tmp_path), "warmup", monkeypatch, 0, "i", seen)
    op = session.operator()
    pg = open_page(headless, op.url, store)
    wait_prompt(pg, "reset", 0)
    expect(pg.locator("#interventions")).to_have_text("0 steps driven in this episode")
    expect(pg.locator("#intervention-rate")).to_have_text("(0.0% of the steps of the last 20 sealed episodes)")
    expect(pg.locator("#btn-i")).to_be_disabled()  # no episode running: nothing to take over
    pg.click("#btn-r")
    wait_prompt(pg, "episode", 0)
    expect(pg.locator("#intervening")).to_have_text("")
    expect(pg.locator("#btn-i")).to_be_enabled()
    pg.click("#btn-i")
    expect(pg.locator("#intervening")).to_have_text("OPERATOR DRIVING")
    driving = pg.text_content("#interventions")
    seen.set()  # the episode goes on, the expert driving it to its end
    wait_prompt(pg, "label", 0)
    pg.click("#btn-s")
    wait_prompt(pg, "reset", 1)
    expect(pg.locator("#intervening")).to_have_text("")  # the takeover ended with its episode
    expect(pg.locator("#btn-i")).to_be_disabled()
    count, rate = pg.text_content("#interventions"), pg.text_content("#intervention-rate")
    pg.click("#btn-a")
    session.thread.join(timeout=60)
    assert not session.thread.is_alive()
    assert isinstance(session.error, StageError) and "aborted by the operator" in str(session.error)

    actions = robot_events(store, "robot-operator-action")
    assert [(e["action"], e.get("episode"), e["via"]) for e in actions] == [
        ("reset", 0, "page"),
        ("takeover", 0, "page"),
        ("label", 0, "page"),
        ("abort", 1, "page"),
    ]
    [sealed] = robot_events(store, "robot-episode-sealed")
    ep = materialize(Store.open(store), sealed["checkpoint"], tmp_path / "sealed") / "episodes" / "000000"
    e = json.loads((ep / "episode.json").read_text())
    with np.load(ep / "transitions.npz") as z:
        marks, steps = z["intervention"], z["steps"]
    # `i` came at the first chunk's end: every executed step from the second chunk on is the teleop's
    want = np.zeros_like(marks)
    for i, n in enumerate(steps):
        want[i, : int(n)] = i >= 1
    assert len(steps) >= 3 and np.array_equal(marks, want)
    assert e["interventions"] == int(want.sum()) > 0
    # what the page showed: the count while driving (the chunks done so far), then the sealed count and rate
    assert 0 < int(driving.split()[0]) < e["interventions"] and driving.endswith(" steps driven in this episode")
    assert count == f"{e['interventions']} steps driven in episode 0"
    assert rate.startswith("(") and rate.endswith("% of the steps of the last 20 sealed episodes)")
    shown_rate = float(rate[1:].split("%")[0])
    assert shown_rate == pytest.approx(100 * e["interventions"] / e["control_steps"], abs=0.051)
