"""The live scope's page: a Bokeh server on 127.0.0.1 that streams a :class:`ScopeRing` to a
browser (issue 27).

The server runs in its own thread with its own event loop; a periodic callback of each page
(every ``period`` s) copies the rows written since its last call out of the ring (lock-free, see
:mod:`hil.scope.ring`), keeps every ``stride``-th row so that the window on screen holds at most
``max_points`` points per trace, and sends them with ``ColumnDataSource.stream``. The cycle never
waits for it.

Access: only 127.0.0.1 is bound; the page's URL carries a per-run token (``?token=...``). A
request for the page without it or with a wrong one is answered 403 (Bokeh's auth hook: the
request is redirected to a handler that refuses). The page's websocket needs a session id signed
with a per-run secret (Bokeh's signed sessions), which only an authorised page load hands out,
and an ``Origin`` of 127.0.0.1:PORT or localhost:PORT (``allow_websocket_origin``).

The page: positions (mm), following errors (um), the controller's output (N m or N), the motor's
speed (mm/s) and the supervisor's state; channels chosen with check boxes; a rolling window
(Select); freeze and resume; every trip or fault drawn as a vertical span with its reason; export
of the rows in view as CSV (in the browser, no server round trip). BokehJS is served from the
bokeh package itself: nothing is fetched from the network.
"""
from __future__ import annotations

import asyncio
import hmac
import logging
import secrets
import threading

import numpy as np

from hil.scope.ring import SCOPE_CHANNELS, ScopeRing

__all__ = ["ScopeServer", "DISPLAY", "WINDOWS"]

log = logging.getLogger(__name__)

# channel -> (factor from SI, unit shown, figure)
DISPLAY = {
    "x_cmd": (1e3, "mm", "position"), "x_motor": (1e3, "mm", "position"), "x_table": (1e3, "mm", "position"),
    "x_tip": (1e3, "mm", "position"), "e_table": (1e6, "um", "error"), "e_tip": (1e6, "um", "error"),
    "output": (1.0, "N m", "output"), "speed": (1e3, "mm/s", "speed"), "state": (1.0, "", "state"),
}
WINDOWS = ("0.5 s", "1 s", "2 s", "5 s", "10 s", "30 s", "60 s")
COLOURS = {"x_cmd": "black", "x_motor": "#1f77b4", "x_table": "#2ca02c", "x_tip": "#d62728",
           "e_table": "#2ca02c", "e_tip": "#d62728", "output": "#9467bd", "speed": "#8c564b", "state": "#ff7f0e"}
REFUSED = "refused: this scope's URL carries a token (printed on stderr where it was started)"

_EXPORT_JS = """
const d = src.data, t = d['t'], x0 = xr.start, x1 = xr.end;
const cols = Object.keys(d).filter(c => c !== 'index');
let out = cols.join(',') + '\\n';
for (let i = 0; i < t.length; i++) {
  if (t[i] < x0 || t[i] > x1) continue;
  out += cols.map(c => d[c][i]).join(',') + '\\n';
}
const blob = new Blob([out], {type: 'text/csv'});
const a = document.createElement('a');
a.href = URL.createObjectURL(blob); a.download = 'scope.csv';
document.body.appendChild(a); a.click(); a.remove();
"""


def _columns(rows: np.ndarray) -> dict[str, np.ndarray]:
    """Ring rows -> the page's columns in display units (``t`` in s)."""
    out = {"t": rows[:, 0].copy()}
    for i, name in enumerate(SCOPE_CHANNELS[1:], start=1):
        out[name] = rows[:, i] * DISPLAY[name][0]
    return out


class ScopeServer:
    """The Bokeh server of one run, in its own thread.

    Parameters
    ----------
    ring : ScopeRing
        What the cycle writes.
    port : int
        0: any free port (the URL says which).
    token : str
        Default: a new random one (``secrets.token_urlsafe``).
    title, output_unit
        The page's title; the unit of the controller's output (``N m`` rotary, ``N`` linear).
    max_points, period
        Points per trace at most; seconds between two updates of the page.
    """

    def __init__(self, ring: ScopeRing, port: int = 0, token: str | None = None, title: str = "hil scope",
                 output_unit: str = "N m", max_points: int = 2000, period: float = 0.05):
        self.ring = ring
        self.port = int(port)
        self.token = token or secrets.token_urlsafe(16)
        self.title = title
        self.output_unit = output_unit
        self.max_points = int(max_points)
        self.period = float(period)
        self.sessions = []            # the live pages' state (tests read what was streamed)
        self._thread = None
        self._loop = None
        self._ready = threading.Event()
        self._error = None

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}/scope?token={self.token}"

    # --- the server's thread ------------------------------------------------------------------------
    def start(self) -> str:
        """Bind 127.0.0.1, start serving in a thread; returns the URL (with the token)."""
        from bokeh.server.util import bind_sockets
        try:
            sockets, self.port = bind_sockets("127.0.0.1", self.port)
        except OSError as exc:
            from hil.errors import UserError
            raise UserError(f"port {self.port}: cannot listen on 127.0.0.1 ({exc.strerror})") from None
        self._thread = threading.Thread(target=self._serve, args=(sockets,), name="hil-scope", daemon=True)
        self._thread.start()
        self._ready.wait(30)
        if self._error is not None:
            raise self._error
        return self.url

    def _serve(self, sockets) -> None:
        try:
            loop = asyncio.new_event_loop()
            asyncio.set_event_loop(loop)
            from bokeh.application import Application
            from bokeh.application.handlers.function import FunctionHandler
            from bokeh.server.server import BaseServer
            from bokeh.server.tornado import BokehTornado
            from tornado.httpserver import HTTPServer
            from tornado.ioloop import IOLoop
            origins = [f"127.0.0.1:{self.port}", f"localhost:{self.port}"]
            app = BokehTornado({"/scope": Application(FunctionHandler(self._make_doc))},
                               extra_websocket_origins=origins, secret_key=secrets.token_bytes(32),
                               sign_sessions=True, generate_session_ids=True, auth_provider=_token_auth(self.token))
            http = HTTPServer(app)
            http.add_sockets(sockets)
            self._loop = IOLoop.current()
            self._server = BaseServer(self._loop, app, http)
            self._server.start()
        except Exception as exc:          # said in the caller's thread
            self._error = exc
            self._ready.set()
            return
        self._ready.set()
        self._loop.start()

    def stop(self) -> None:
        """Stop serving (from any thread)."""
        if self._loop is None:
            return

        def _stop():
            self._server.stop()
            self._server.io_loop.stop()
        self._loop.add_callback(_stop)
        self._thread.join(10)
        self._loop = None

    # --- one page ------------------------------------------------------------------------------------
    def _make_doc(self, doc) -> None:
        req = doc.session_context.request if doc.session_context else None
        given = (req.arguments.get("token") or [b""])[0] if req is not None else b""
        given = given.decode() if isinstance(given, bytes) else str(given)
        if not hmac.compare_digest(given, self.token):       # a second check: no data without the token
            from bokeh.models import Div
            doc.add_root(Div(text=REFUSED))
            return
        page = _Page(self, doc)
        self.sessions.append(page)


def _token_auth(token: str):
    """Bokeh's auth hook: the page with ``?token=`` right; the websocket (its session id is signed
    with the run's secret, given only with an authorised page); anything else redirected to
    ``/refused`` (403)."""
    from bokeh.server.auth_provider import AuthProvider
    from tornado.web import HTTPError, RequestHandler

    class Refused(RequestHandler):
        def get(self):
            raise HTTPError(403, REFUSED)

    class TokenAuth(AuthProvider):
        @property
        def get_user(self):
            def user(handler):
                if handler.request.path.endswith("/ws"):
                    return "page"             # the signed session id is checked by Bokeh
                given = handler.get_argument("token", "")
                return "page" if hmac.compare_digest(given, token) else None
            return user

        @property
        def login_url(self):
            return "/refused"

        @property
        def login_handler(self):
            return Refused

    return TokenAuth()


class _Page:
    """One browser page: its figures, its data source and its periodic update."""

    def __init__(self, server: ScopeServer, doc):
        from bokeh.layouts import column, row
        from bokeh.models import (
            Button,
            CheckboxGroup,
            ColumnDataSource,
            CustomJS,
            Div,
            LabelSet,
            Range1d,
            Select,
            Toggle,
        )
        from bokeh.plotting import figure
        self.server, self.ring, self.doc = server, server.ring, doc
        self.window = 5.0
        self.frozen = False
        self.next_row = 0
        self.next_event = 0
        self.stride = 1
        self.source = ColumnDataSource(_columns(np.zeros((0, len(SCOPE_CHANNELS)))))
        self.events = ColumnDataSource({"t": [], "kind": [], "reason": [], "y": []})
        self.x_range = Range1d(0.0, self.window)
        units = dict(DISPLAY)
        units["output"] = (1.0, server.output_unit, "output")
        figs, self.lines = {}, {}
        for key, label in (("position", "position (mm)"), ("error", "following error (um)"),
                           ("output", f"output ({server.output_unit})"), ("speed", "motor speed (mm/s)"),
                           ("state", "supervisor state")):
            f = figure(height=90 if key == "state" else 200, sizing_mode="stretch_width", x_range=self.x_range,
                       y_axis_label=label, tools="pan,box_zoom,wheel_zoom,reset,save", output_backend="webgl")
            f.vspan(x="t", source=self.events, line_color="red", line_width=2)
            figs[key] = f
        for name in SCOPE_CHANNELS[1:]:
            fig = figs[units[name][2]]
            self.lines[name] = fig.line("t", name, source=self.source, color=COLOURS[name],
                                        legend_label=f"{name} [{units[name][1]}]" if units[name][1] else name)
        for f in figs.values():
            f.legend.location = "top_left"
            f.legend.click_policy = "hide"
        figs["position"].add_layout(LabelSet(x="t", y=5, y_units="screen", text="reason", source=self.events,
                                             text_color="red", text_font_size="11px", x_offset=3))
        figs["state"].xaxis.axis_label = "t (s)"
        names = list(SCOPE_CHANNELS[1:])
        self.channels = CheckboxGroup(labels=names, active=list(range(len(names))), inline=True)
        self.channels.on_change("active", lambda attr, old, new: self._show(names, new))
        self.window_select = Select(title="time base", value="5 s", options=list(WINDOWS), width=100)
        self.window_select.on_change("value", lambda attr, old, new: self._set_window(float(new.split()[0])))
        self.freeze = Toggle(label="freeze", active=False, width=100)
        self.freeze.on_change("active", lambda attr, old, new: self._freeze(new))
        export = Button(label="export CSV", width=100)
        export.js_on_event("button_click", CustomJS(args={"src": self.source, "xr": self.x_range}, code=_EXPORT_JS))
        self.trips = Div(text="no trip")
        doc.title = server.title
        doc.add_root(column(Div(text=f"<b>{server.title}</b>"),
                            row(self.window_select, self.freeze, export, self.trips), self.channels,
                            *figs.values(), sizing_mode="stretch_width"))
        doc.add_periodic_callback(self.update, int(server.period * 1000))

    def _show(self, names, active) -> None:
        for i, n in enumerate(names):
            self.lines[n].visible = i in active

    def _set_window(self, seconds: float) -> None:
        self.window = seconds
        self._reload()

    def _freeze(self, frozen: bool) -> None:
        self.frozen = frozen
        self.freeze.label = "resume" if frozen else "freeze"
        if not frozen:
            self._reload()

    def _stride_for(self, rows_per_s: float) -> int:
        return max(1, int(np.ceil(self.window * rows_per_s / self.server.max_points)))

    def _reload(self) -> None:
        """The whole window again from the ring (a new time base, after a freeze)."""
        first, rows = self.ring.window(most=self.ring.capacity)
        if rows.shape[0] >= 2:
            dt = float(np.median(np.diff(rows[-min(rows.shape[0], 100):, 0]))) or 1e-3
            n = int(self.window / dt) + 1
            rows, first = rows[-n:], max(first, first + rows.shape[0] - n)
            self.stride = self._stride_for(1.0 / dt)
        keep = (np.arange(first, first + rows.shape[0]) % self.stride) == 0
        self.source.data = _columns(rows[keep])
        self.next_row = first + rows.shape[0]
        self._follow()

    def update(self) -> None:
        """The periodic callback (the server's thread): new rows and events from the ring."""
        self.next_event, new = self.ring.events(self.next_event)
        for row, t, kind, reason in new:
            if kind in ("trip", "fault", "aborted"):
                text = f"{kind} at {t:.4f} s: {reason}"
                self.events.stream({"t": [t], "kind": [kind], "reason": [text], "y": [0.0]})
                self.trips.text = "<span style='color:red'>" + "<br>".join(self.events.data["reason"]) + "</span>"
        if self.frozen:
            return
        first, rows = self.ring.window(since=self.next_row)
        if rows.shape[0] == 0:
            return
        if self.next_row == 0 and self.stride == 1 and rows.shape[0] >= 2:
            dt = float(np.median(np.diff(rows[:, 0]))) or 1e-3
            self.stride = self._stride_for(1.0 / dt)
        keep = (np.arange(first, first + rows.shape[0]) % self.stride) == 0
        self.next_row = first + rows.shape[0]
        if keep.any():
            self.source.stream(_columns(rows[keep]), rollover=self.server.max_points)
        self._follow()

    def _follow(self) -> None:
        t = self.source.data["t"]
        if len(t):
            end = float(t[-1])
            self.x_range.start, self.x_range.end = max(end - self.window, float(t[0])), max(end, float(t[0]) + 1e-3)
