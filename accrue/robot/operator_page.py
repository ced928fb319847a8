"""The operator page: a small local web server the actor runs for the person at the robot.

It shows the live state (task, phase, episode and step, the 20-episode running success, robot time,
learner version and health, interventions, a status line, the latest camera frame) and has a button
with a keyboard shortcut for every operator action. The page and the terminal are two views of one
operator: keys from either go into one queue, read by the same state machine (KeyOperator), and every
action is audited with the view it came from.

Every request needs the token (the store's link token: header X-Accrue-Token or ?token=...), compared
in constant time; a refused request gets 403 and an audit entry. Loopback by default. Only Python's
http.server, on its own threads; the page is one self-contained HTML document (no CDN) that polls
/state.json about four times a second.
"""

from __future__ import annotations

import hmac
import io
import json
import os
import queue
import secrets
import socket
import sys
import threading
from collections import deque
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Callable
from urllib.parse import parse_qs, urlsplit

from accrue.errors import AccrueError
from accrue.robot.operator import KEYS, KeyOperator, TtyKeys

REFUSED_EVENT = "robot-operator-page-refused"
STARTED_EVENT = "robot-operator-page-started"
TOKEN_HEADER = "X-Accrue-Token"
MESSAGES = 12  # lines of the operator's log the page keeps
REFUSALS_AUDITED = 20  # then one audit entry per 100 refusals (a caller without the token can't flood the log)
SHOWN_KEYS = (
    "task",
    "phase",
    "episode",
    "step",
    "window",
    "window_size",
    "max_steps",
    "robot_time_s",
    "learner_version",
    "learner_health",
    "interventions",
    "intervening",
    "intervention_rate_window",
    "status",
)


def _plain(v):
    """JSON-able values (numpy scalars and arrays from the episode loop included)."""
    if isinstance(v, (str, int, float, bool)) or v is None:
        return v
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if hasattr(v, "tolist"):  # numpy scalar or array
        return _plain(v.tolist())
    return str(v)


def encode_jpeg(frame) -> bytes:
    """An (H, W, 3) uint8 frame (or float in [0, 1], or grey (H, W)) as JPEG bytes (Pillow, via matplotlib)."""
    import numpy as np
    from PIL import Image

    a = np.asarray(frame)
    if a.dtype != np.uint8:
        a = (np.clip(a.astype(np.float32), 0.0, 1.0) * 255.0).astype(np.uint8)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    buf = io.BytesIO()
    Image.fromarray(a).save(buf, format="JPEG", quality=90)
    return buf.getvalue()


class PageOperator(KeyOperator):
    """The operator's page (and terminal, when stdin is a tty and `terminal` is not False)."""

    def __init__(
        self,
        name: str,
        console=None,
        listen: str = "127.0.0.1:0",
        token: str | None = None,
        terminal: bool | None = None,
        audit: Callable[[str, dict], None] | None = None,
    ):
        from rich.console import Console

        from accrue.robot.link_auth import parse_address

        super().__init__(name, audit)
        host, port = parse_address(listen, "robot.operator_page.listen", allow_zero=True)
        self.console = console or Console(stderr=True)
        self.token = token or secrets.token_urlsafe(32)
        self._lock = threading.Lock()  # the state below is read by the server's threads
        self._queue: queue.Queue[tuple[str, str]] = queue.Queue()
        self._shown: dict = {}
        self._frame = None
        self._frame_seq = 0
        self._jpeg: tuple[int, bytes] | None = None
        self._prompt = {"expect": "idle", "episode": None, "keys": "", "line": "starting"}
        self._messages: deque[str] = deque(maxlen=MESSAGES)
        self._actions = 0
        self._last_action: dict | None = None
        self._refused = 0
        self._closed = False

        bare = host[1:-1] if host.startswith("[") else host
        server_class = _Server6 if ":" in bare else _Server
        try:
            self._server = server_class((bare, port), _handler(self))
        except OSError as exc:
            raise AccrueError(
                f"robot.operator_page.listen: cannot listen on {listen} ({exc.strerror or exc})"
            ) from None
        bound_host, bound_port = self._server.server_address[:2]
        self.url, self.listening = page_urls(bound_host, bound_port)
        self._serving = threading.Thread(
            target=self._server.serve_forever, kwargs={"poll_interval": 0.2}, name="operator-page", daemon=True
        )
        self._serving.start()

        if terminal is None:
            terminal = sys.stdin.isatty()
        self._tty: TtyKeys | None = None
        self._reader: threading.Thread | None = None
        self._wake_r = self._wake_w = None
        if terminal:
            self._tty = TtyKeys("robot.operator: page with terminal: true")
            self._wake_r, self._wake_w = os.pipe()
            self._reader = threading.Thread(target=self._read_terminal, name="operator-terminal", daemon=True)
            self._reader.start()
        import atexit

        atexit.register(self.close)
        if self.listening:
            self.console.print(self.listening, markup=False, highlight=False)
        self.audit(STARTED_EVENT, {"via": "page", "operator": name, "url": self.url, "terminal": bool(terminal)})

    # ------------------------------------------------------------------ the views' keys
    def _read_terminal(self) -> None:
        while True:
            key = self._tty.key(None, wake=self._wake_r)
            if key is None:  # woken by close()
                return
            self._queue.put(("terminal", key))

    def press(self, key: str, via: str = "page") -> None:
        """A key from a view (the page's buttons and shortcuts come here)."""
        self._queue.put((via, key))

    def _next(self, timeout: float | None) -> tuple[str, str] | None:
        try:
            return self._queue.get(block=timeout != 0, timeout=timeout or None)
        except queue.Empty:
            return None

    def _say(self, line: str) -> None:
        with self._lock:
            self._messages.append(line)
        self.console.print(line, markup=False, highlight=False)

    def tell(self, line: str) -> None:
        with self._lock:
            self._messages.append(f"robot: {line}")
        self.console.print(f"[bold yellow]robot:[/] {line}")

    def _expect(self, what: str, episode: int | None, keys: str, line: str) -> None:
        with self._lock:
            self._prompt = {"expect": what, "episode": episode, "keys": keys, "line": line}

    def _acted(self, via: str, action: str, fields: dict) -> None:
        with self._lock:
            self._actions += 1
            self._last_action = dict(fields)

    def wait_reset(self, episode: int, task: str, last: int | None):
        with self._lock:  # the task is known before the episode loop first shows anything
            self._shown["task"] = task
        return super().wait_reset(episode, task, last)

    # ------------------------------------------------------------------ the state
    def show(self, state: dict) -> None:
        shown = {k: _plain(v) for k, v in state.items() if k in SHOWN_KEYS}
        frame = state.get("frame")
        with self._lock:
            self._shown.update(shown)
            if frame is not None:
                self._frame = frame
                self._frame_seq += 1

    def state(self) -> dict:
        with self._lock:
            return {
                "operator": self.name,
                "prompt": dict(self._prompt),
                "paused": self.paused,
                "messages": list(self._messages),
                "actions": self._actions,
                "last_action": self._last_action,
                "shown": dict(self._shown),
                "frame_seq": self._frame_seq if self._frame is not None else None,
                "closed": self._closed,
            }

    def frame_jpeg(self) -> bytes | None:
        with self._lock:
            frame, seq, cached = self._frame, self._frame_seq, self._jpeg
        if frame is None:
            return None
        if cached is not None and cached[0] == seq:
            return cached[1]
        data = encode_jpeg(frame)  # outside the lock: the episode loop's show() never waits for it
        with self._lock:
            self._jpeg = (seq, data)
        return data

    # ------------------------------------------------------------------ requests
    def allowed(self, given: str | None) -> bool:
        return given is not None and hmac.compare_digest(given.encode(), self.token.encode())

    def refused(self, method: str, path: str, remote: str, reason: str) -> None:
        with self._lock:
            self._refused += 1
            n = self._refused
        if n <= REFUSALS_AUDITED or n % 100 == 0:
            self.audit(
                REFUSED_EVENT,
                {"via": "page", "method": method, "path": path, "remote": remote, "reason": reason, "refused": n},
            )

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._prompt = {"expect": "closed", "episode": None, "keys": "", "line": "the session ended"}
        if self._wake_w is not None:
            os.write(self._wake_w, b"x")
            self._reader.join(timeout=2)
            os.close(self._wake_w)
            os.close(self._wake_r)
        if self._tty is not None:
            self._tty.restore()
        self._server.shutdown()
        self._server.server_close()


def page_urls(host: str, port: int) -> tuple[str, str | None]:
    """(the URL to open on this machine, a line for the operator or None) for the address the page is bound
    to. Bound to all interfaces (0.0.0.0 or ::), http://0.0.0.0:PORT/ is no address a browser can open: the
    URL is loopback's, and the line says it listens on all interfaces and gives this host's name for a
    browser elsewhere on the network."""
    if host not in ("0.0.0.0", "::"):
        return f"http://{f'[{host}]' if ':' in host else host}:{port}/", None
    url = f"http://{'127.0.0.1' if host == '0.0.0.0' else '[::1]'}:{port}/"
    return url, (
        f"operator page: listening on all interfaces ({host} port {port}); on this machine open {url}, "
        f"from another one http://{socket.gethostname()}:{port}/ (or this machine's address on that network)"
    )


class _Server(ThreadingHTTPServer):
    daemon_threads = True  # a browser's open connection never keeps the actor from exiting


class _Server6(_Server):
    address_family = socket.AF_INET6


def _handler(op: PageOperator):
    class Handler(BaseHTTPRequestHandler):
        server_version = "accrue-operator"
        sys_version = ""

        def log_message(self, format, *args):  # noqa: A002 - http.server's name
            pass  # four requests a second, and their URLs can hold the token: nothing on the console

        def _send(self, code: int, body: bytes, ctype: str) -> None:
            self.send_response(code)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.send_header("Referrer-Policy", "no-referrer")
            self.end_headers()
            self.wfile.write(body)

        def _json(self, code: int, obj) -> None:
            self._send(code, json.dumps(obj).encode(), "application/json")

        def _authorised(self) -> bool:
            url = urlsplit(self.path)
            given = self.headers.get(TOKEN_HEADER)
            if given is None:
                given = (parse_qs(url.query).get("token") or [None])[0]
            if op.allowed(given):
                return True
            op.refused(self.command, url.path, self.client_address[0], "no token" if given is None else "wrong token")
            if url.path == "/" and self.command == "GET":
                self._send(403, TOKEN_FORM.encode(), "text/html; charset=utf-8")
            else:
                self._json(403, {"error": "this page needs the operator token"})
            return False

        def do_GET(self):  # noqa: N802 - http.server's name
            if not self._authorised():
                return
            path = urlsplit(self.path).path
            if path == "/":
                self._send(200, PAGE.encode(), "text/html; charset=utf-8")
            elif path == "/state.json":
                self._json(200, op.state())
            elif path == "/frame.jpg":
                data = op.frame_jpeg()
                if data is None:
                    self._json(404, {"error": "no camera frame yet"})
                else:
                    self._send(200, data, "image/jpeg")
            else:
                self._json(404, {"error": f"no such page {path}"})

        def do_POST(self):  # noqa: N802 - http.server's name
            if not self._authorised():
                return
            path = urlsplit(self.path).path
            if path != "/action":
                self._json(404, {"error": f"no such action endpoint {path}"})
                return
            try:
                n = int(self.headers.get("Content-Length") or 0)
                key = json.loads(self.rfile.read(min(n, 4096)) or b"{}").get("key")
            except (ValueError, AttributeError):
                key = None
            if not isinstance(key, str) or len(key) != 1:
                self._json(400, {"error": 'send {"key": K}, one of ' + ", ".join(KEYS)})
                return
            op.press(key.lower(), via="page")
            self._json(200, {"queued": key.lower()})

    return Handler


TOKEN_FORM = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>accrue operator: token</title><link rel="icon" href="data:,">
<style>body{font:16px system-ui,sans-serif;margin:3em;background:#111;color:#eee}
input{font:inherit;width:32em}button{font:inherit}</style></head>
<body><h1>accrue operator page</h1>
<p>This page needs the operator token: the store's link token, in <code>STORE/robot/link-token</code>.</p>
<form method="get" action="/"><input name="token" type="password" autofocus placeholder="token">
<button type="submit">open</button></form></body></html>
"""

PAGE = r"""<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>accrue operator</title>
<link rel="icon" href="data:,">
<meta name="viewport" content="width=device-width, initial-scale=1">
<style>
  :root { --ok: #2e9d4a; --bad: #c8372d; --none: #444; --fg: #eee; --bg: #15171a; --panel: #1f2226; }
  * { box-sizing: border-box; }
  body { margin: 0; font: 15px system-ui, sans-serif; background: var(--bg); color: var(--fg); }
  header { display: flex; gap: 1.5em; align-items: baseline; padding: .6em 1em; background: var(--panel); }
  header h1 { font-size: 1.1em; margin: 0; }
  #conn { margin-left: auto; font-size: .9em; color: #aaa; }
  #conn.lost { color: var(--bad); font-weight: bold; }
  main { display: grid; grid-template-columns: minmax(240px, 1fr) minmax(320px, 1.3fr); gap: 1em; padding: 1em; }
  .panel { background: var(--panel); border-radius: 6px; padding: .8em 1em; }
  #frame-box { display: flex; align-items: center; justify-content: center; min-height: 240px; background: #000;
               border-radius: 6px; }
  #frame { width: 100%; max-width: 480px; image-rendering: pixelated; display: none; }
  #no-frame { color: #888; }
  dl { display: grid; grid-template-columns: max-content 1fr; gap: .25em 1em; margin: 0; }
  dt { color: #aaa; } dd { margin: 0; font-variant-numeric: tabular-nums; }
  #marks { display: flex; gap: 3px; margin: .4em 0; }
  #marks span { width: 14px; height: 14px; border-radius: 2px; background: var(--none); }
  #marks span.ok { background: var(--ok); } #marks span.bad { background: var(--bad); }
  #prompt { font-size: 1.25em; margin: .2em 0 .6em; min-height: 1.5em; }
  #paused { color: #f0b429; font-weight: bold; display: none; }
  .health-ok { color: var(--ok); } .health-lost, .health-holding { color: var(--bad); font-weight: bold; }
  #buttons { display: grid; grid-template-columns: repeat(4, 1fr); gap: .5em; }
  button { font: inherit; padding: .7em .4em; border-radius: 6px; border: 1px solid #555; background: #2b3036;
           color: var(--fg); cursor: pointer; }
  button:disabled { opacity: .35; cursor: default; }
  button kbd { display: inline-block; margin-left: .4em; padding: 0 .35em; border: 1px solid #777;
               border-radius: 3px; font-size: .85em; }
  #btn-s { background: #1f4d2c; } #btn-f { background: #5a2420; } #btn-a { background: #4a1d1d; }
  #messages { font: 13px ui-monospace, monospace; white-space: pre-wrap; color: #ccc; margin: .5em 0 0;
              max-height: 14em; overflow-y: auto; }
  #status { color: #9cc3ff; }
</style>
</head>
<body data-expect="" data-episode="" data-actions="0" data-closed="false">
<header>
  <h1>accrue operator</h1>
  <span id="who"></span>
  <span id="task"></span>
  <span id="conn">connecting</span>
</header>
<main>
  <section>
    <div id="frame-box"><img id="frame" alt="latest camera frame"><span id="no-frame">no camera frame</span></div>
    <div class="panel" style="margin-top:1em">
      <dl>
        <dt>phase</dt><dd id="phase">-</dd>
        <dt>episode</dt><dd id="episode">-</dd>
        <dt>step</dt><dd id="step">-</dd>
        <dt id="window-label">running success</dt><dd><span id="window-text">-</span><div id="marks"></div></dd>
        <dt>robot time</dt><dd id="robot-time">-</dd>
        <dt>learner</dt><dd><span id="learner-version">-</span> <span id="learner-health"></span></dd>
        <dt>interventions</dt><dd><span id="interventions">-</span> <span id="intervening"></span>
          <span id="intervention-rate"></span></dd>
        <dt>status</dt><dd id="status">-</dd>
      </dl>
    </div>
  </section>
  <section class="panel">
    <div id="prompt">waiting for the actor</div>
    <div id="paused">PAUSED (p resumes)</div>
    <div id="buttons">
      <button id="btn-r" data-key="r" disabled>reset done<kbd>r</kbd></button>
      <button id="btn-s" data-key="s" disabled>success<kbd>s</kbd></button>
      <button id="btn-f" data-key="f" disabled>failure<kbd>f</kbd></button>
      <button id="btn-e" data-key="e" disabled>end episode<kbd>e</kbd></button>
      <button id="btn-p" data-key="p" disabled>pause / resume<kbd>p</kbd></button>
      <button id="btn-l" data-key="l" disabled>re-label last<kbd>l</kbd></button>
      <button id="btn-a" data-key="a" disabled>abort<kbd>a</kbd></button>
      <button id="btn-i" data-key="i" disabled>take over / give back<kbd>i</kbd></button>
    </div>
    <pre id="messages"></pre>
  </section>
</main>
<script>
"use strict";
const token = new URLSearchParams(location.search).get("token") || "";
const headers = { "X-Accrue-Token": token };
const $ = (id) => document.getElementById(id);
let frameSeq = null, frameUrl = null, stopped = false;

function text(id, v, fmt) { $(id).textContent = (v === undefined || v === null) ? "-" : (fmt ? fmt(v) : String(v)); }

async function press(key) {
  const b = $("btn-" + key);
  if (!b || b.disabled) return;
  await fetch("/action", { method: "POST", headers: { ...headers, "Content-Type": "application/json" },
                           body: JSON.stringify({ key }) });
}

async function loadFrame(seq) {
  const r = await fetch("/frame.jpg?seq=" + seq, { headers });
  if (!r.ok) return;
  const url = URL.createObjectURL(await r.blob());
  $("frame").src = url;
  if (frameUrl) URL.revokeObjectURL(frameUrl);
  frameUrl = url;
  $("frame").style.display = "block";
  $("no-frame").style.display = "none";
}

function render(st) {
  const s = st.shown || {}, p = st.prompt || {};
  text("who", st.operator, (v) => "operator: " + v);
  text("task", s.task);
  text("phase", s.phase);
  text("episode", s.episode);
  text("step", s.step, (v) => s.max_steps ? v + " of at most " + s.max_steps : String(v));
  const w = s.window || [], size = Number(s.window_size) || 20;  // the stop rule's window (robot.stop_window)
  $("window-label").textContent = "success (last " + size + ")";
  text("window-text", w.length ? w.filter(Boolean).length + "/" + w.length : null);
  const marks = $("marks");
  marks.replaceChildren(...Array.from({ length: size }, (_, i) => {
    const m = document.createElement("span");
    if (i < w.length) m.className = w[i] ? "ok" : "bad";
    return m;
  }));
  text("robot-time", s.robot_time_s, (v) => Number(v).toFixed(1) + " s");
  text("learner-version", s.learner_version, (v) => "weights v" + v);
  const h = $("learner-health");
  h.textContent = s.learner_health || "";
  h.className = s.learner_health ? "health-" + s.learner_health : "";
  // between episodes the count is the last episode's, and nobody drives (a takeover ends with its episode)
  const acting = p.expect === "episode", ended = p.expect !== "episode" && p.expect !== "label";
  text("interventions", s.interventions,
       (v) => v + (ended && s.episode !== null && s.episode !== undefined
         ? " steps driven in episode " + s.episode : " steps driven in this episode"));
  $("intervening").textContent = s.intervening && acting ? "OPERATOR DRIVING" : "";
  $("intervening").className = s.intervening && acting ? "health-holding" : "";
  const rate = s.intervention_rate_window;  // absent: interventions are off
  $("intervention-rate").textContent = rate === undefined || rate === null ? ""
    : "(" + (100 * Number(rate)).toFixed(1) + "% of the steps of the last " + size + " sealed episodes)";
  text("status", s.status);
  $("prompt").textContent = p.line || "";
  $("paused").style.display = st.paused ? "block" : "none";
  const keys = p.keys || "";
  for (const b of document.querySelectorAll("#buttons button")) {
    const k = b.dataset.key;  // paused: reset waits for resume (the actor would refuse it anyway)
    b.disabled = st.closed || !keys.includes(k) || (k === "r" && st.paused);
  }
  // button meanings while re-labelling: s and f label the last episode
  $("btn-s").firstChild.textContent = p.expect === "relabel" ? "re-label success" : "success";
  $("btn-f").firstChild.textContent = p.expect === "relabel" ? "re-label failure" : "failure";
  const msgs = $("messages");
  msgs.textContent = (st.messages || []).join("\n");
  msgs.scrollTop = msgs.scrollHeight;
  document.body.dataset.expect = p.expect || "";
  document.body.dataset.episode = p.episode === null || p.episode === undefined ? "" : String(p.episode);
  document.body.dataset.actions = String(st.actions);
  document.body.dataset.closed = String(st.closed);
  if (st.frame_seq !== null && st.frame_seq !== frameSeq) { frameSeq = st.frame_seq; loadFrame(st.frame_seq); }
}

async function tick() {
  let wait = 250;
  try {
    const r = await fetch("/state.json", { headers });
    if (r.status === 403) {
      stopped = true;
      $("conn").textContent = "refused: wrong or missing token (open the page with ?token=...)";
      $("conn").className = "lost";
      return;
    }
    render(await r.json());
    $("conn").textContent = "live";
    $("conn").className = "";
  } catch (e) {
    // between steps the actor starts a new server (a fixed listen port keeps this page working)
    $("conn").textContent = "no connection to the actor: retrying";
    $("conn").className = "lost";
    document.body.dataset.expect = "";
    for (const b of document.querySelectorAll("#buttons button")) b.disabled = true;
    wait = 1000;
  }
  if (!stopped) setTimeout(tick, wait);
}

for (const b of document.querySelectorAll("#buttons button")) b.addEventListener("click", () => press(b.dataset.key));
document.addEventListener("keydown", (ev) => {
  if (ev.ctrlKey || ev.metaKey || ev.altKey) return;
  const k = ev.key.toLowerCase();
  if ("rsfeplai".includes(k) && k.length === 1) { ev.preventDefault(); press(k); }
});
tick();
</script>
</body>
</html>
"""
