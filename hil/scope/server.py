"""The live scope's page: a Bokeh server on 127.0.0.1 that streams a :class:`ScopeRing` to a
browser (issue 27).

:class:`ScopeServer` runs in a thread with its own event loop; a periodic callback of each page
(every ``period`` s) copies the rows written since its last call out of the ring (lock-free, see
:mod:`hil.scope.ring`), keeps every ``stride``-th row so that the window on screen holds at most
``max_points`` points per trace, and sends them with ``ColumnDataSource.stream``. For a run, the
commands use :class:`ScopeProcess`: the same server in a process of its own (``python -m
hil.scope.server``), the ring a shared file mapping, so that the server never holds the
interpreter lock of the process whose cycle writes the ring. The cycle never waits for it.

Access: only 127.0.0.1 is bound; the page's URL carries a per-run token (``?token=...``). A
request for the page without it or with a wrong one is answered 403 (Bokeh's auth hook: the
request is redirected to a handler that refuses). The page's websocket needs a session id signed
with a per-run secret (Bokeh's signed sessions), which only an authorised page load hands out,
and an ``Origin`` of 127.0.0.1:PORT or localhost:PORT (``allow_websocket_origin``).

The page (:class:`_Page`): positions (mm), following errors (um), the controller's output (N m or
N), the motor's speed (mm/s) and the supervisor's state; channels chosen with check boxes; modes
rolling, normal and single shot on a trigger (a channel's level or edge, a trip, a move's start;
pre- and post-trigger time); freeze and resume; two cursors (a tap or a typed time) with their
differences; every trip or fault drawn as a vertical line with its reason, and the rolling view
held around a trip; the view's CSV made here and handed to the browser as a download; the view's
PNG, every pane in one image, composed by BokehJS in the page (each plot's save tool: one pane). The rules (trigger, capture, cursors, CSV) are plain Python in
:mod:`hil.scope.view`. BokehJS is served from the bokeh package itself: nothing is fetched from
the network.
"""
from __future__ import annotations

import asyncio
import hmac
import logging
import os
import secrets
import threading

import numpy as np

from hil.scope.ring import SCOPE_CHANNELS, ScopeRing

__all__ = ["ScopeServer", "ScopeProcess", "DISPLAY", "WINDOWS"]

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

MODES = ("rolling", "normal", "single")

# the one piece of JavaScript: hand the CSV the server made (hil.scope.view.view_csv) to the browser
_DOWNLOAD_JS = """
const a = document.createElement('a');
a.href = URL.createObjectURL(new Blob([src.text], {type: 'text/csv'}));
a.download = 'scope.csv'; document.body.appendChild(a); a.click(); a.remove();
"""
# and the whole view as one PNG: BokehJS composes the column of plots (every pane, its legend, the
# trip markers and cursors) into one canvas (LayoutDOMView.export), as each plot's save tool does for one
_PNG_JS = """
Bokeh.index.get_one(plots).export('png').to_blob().then((blob) => {
  const a = document.createElement('a');
  a.href = URL.createObjectURL(blob);
  a.download = 'scope.png'; document.body.appendChild(a); a.click(); a.remove();
});
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
                 output_unit: str = "N m", max_points: int = 2000, period: float = 0.04):
        self.ring = ring
        self.port = int(port)
        self.token = token or secrets.token_urlsafe(16)
        self.title = title
        self.output_unit = output_unit
        self.max_points = int(max_points)
        self.period = float(period)
        self.sessions = []            # the live pages' state (tests read what was streamed)
        self._thread = None
        self.native_id = None         # the server thread's id (Linux: its task id)
        self._loop = None
        self._ready = threading.Event()
        self._error = None

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}/scope?token={self.token}"

    @property
    def running(self) -> bool:
        return self._loop is not None

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
        self.native_id = threading.get_native_id()
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


def ordinary_priority() -> None:
    """Keep the calling thread (the server's) at the ordinary scheduling policy. The loop, with
    ``runtime.priority``, raises every thread of the process to its real-time priority, this one
    too, which would then compete with the cycle; called on every frame (one system call)."""
    if not hasattr(os, "sched_getscheduler"):
        return
    try:
        if os.sched_getscheduler(0) != os.SCHED_OTHER:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except OSError:              # not Linux-like, or not allowed: nothing to undo then either
        pass


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
    """One browser page: its figures, its data source, its controls and its periodic update.

    Modes (``mode`` Select): ``rolling`` streams the newest rows over the time base; ``normal``
    shows the window around each trigger, re-arming after it; ``single`` shows the first trigger
    after *arm* and holds it. A trip in the rolling view holds the view around the trip (the
    cycles before it stay on the page until *resume*). The trigger, the capture, the cursors and
    the CSV are plain Python (:mod:`hil.scope.view`)."""

    def __init__(self, server: ScopeServer, doc):
        from bokeh.events import Tap
        from bokeh.layouts import column, row
        from bokeh.models import (
            Button,
            CheckboxGroup,
            ColumnDataSource,
            CustomJS,
            Div,
            LabelSet,
            RadioButtonGroup,
            Range1d,
            Select,
            Span,
            TextInput,
            Toggle,
        )
        from bokeh.plotting import figure

        from hil.scope.view import SLOPES, Trigger
        self.server, self.ring, self.doc = server, server.ring, doc
        self.window = 5.0
        self.mode = "rolling"
        self.frozen = False
        self.armed = False
        self.next_row = 0
        self.next_event = 0
        self.stride = 1
        self.trip_times: list[float] = []
        self.ended_at = None                 # the time of the last end of a run (complete, trip, ...)
        self.search_row, self.search_t, self.pending = 0, -np.inf, None
        self.triggered_at = None
        self.cursor_t = [None, None]
        self.exports = 0
        self.trigger = Trigger(source="trip", channel="e_table", slope="rising", level=0.0, pre=1.0, post=0.2)
        self.units = {n: DISPLAY[n][1] for n in SCOPE_CHANNELS[1:]}
        self.units["output"] = server.output_unit
        self.source = ColumnDataSource(_columns(np.zeros((0, len(SCOPE_CHANNELS)))), name="traces")
        self.events = ColumnDataSource({"t": [], "kind": [], "reason": [], "y": []}, name="trip_markers")
        self.x_range = Range1d(0.0, self.window)
        figs, self.lines = {}, {}
        self.cursor_spans, self.trigger_spans = ([], []), []
        # canvas, not webgl: a browser without a GPU (a VM, headless Chromium) renders WebGL in
        # software, about ten times slower for these 2000 points a trace (0.5 against 6 frames/s measured)
        for key, label in (("position", "position (mm)"), ("error", "following error (um)"),
                           ("output", f"output ({server.output_unit})"), ("speed", "motor speed (mm/s)"),
                           ("state", "supervisor state")):
            f = figure(height=90 if key == "state" else 200, sizing_mode="stretch_width", x_range=self.x_range,
                       y_axis_label=label, tools="pan,box_zoom,wheel_zoom,reset,save", output_backend="canvas")
            f.vspan(x="t", source=self.events, line_color="red", line_width=2)
            for spans, colour in zip(self.cursor_spans, ("#444444", "#888888")):
                spans.append(Span(location=None, dimension="height", line_color=colour, line_dash="dashed"))
                f.add_layout(spans[-1])
            self.trigger_spans.append(Span(location=None, dimension="height", line_color="orange", line_width=2))
            f.add_layout(self.trigger_spans[-1])
            f.on_event(Tap, lambda event: self._tap(event.x))
            figs[key] = f
        for name in SCOPE_CHANNELS[1:]:
            fig = figs[DISPLAY[name][2]]
            unit = self.units[name]
            self.lines[name] = fig.line("t", name, source=self.source, color=COLOURS[name],
                                        legend_label=f"{name} [{unit}]" if unit else name)
        for f in figs.values():
            f.legend.location = "top_left"
            f.legend.click_policy = "hide"
        figs["position"].add_layout(LabelSet(x="t", y=5, y_units="screen", text="reason", source=self.events,
                                             text_color="red", text_font_size="11px", x_offset=3))
        figs["state"].xaxis.axis_label = "t (s)"
        # one time axis, at the bottom, as on a scope's screen: the panes share it, and its labels
        # are measured and drawn once a frame rather than five times
        for key in ("position", "error", "output", "speed"):
            figs[key].xaxis.visible = False
        names = list(SCOPE_CHANNELS[1:])
        self.channels = CheckboxGroup(labels=names, active=list(range(len(names))), inline=True)
        self.channels.on_change("active", lambda attr, old, new: self._show(names, new))
        self.mode_select = Select(title="mode", value="rolling", options=list(MODES), width=100, name="mode")
        self.mode_select.on_change("value", lambda attr, old, new: self._set_mode(new))
        self.window_select = Select(title="time base", value="5 s", options=list(WINDOWS), width=100)
        self.window_select.on_change("value", lambda attr, old, new: self._set_window(float(new.split()[0])))
        self.freeze = Toggle(label="freeze", active=False, width=100, name="freeze")
        self.freeze.on_change("active", lambda attr, old, new: self._freeze(new))
        arm = Button(label="arm", width=80, name="arm")
        arm.on_click(self._arm_clicked)
        export = Button(label="export CSV", width=100, name="export")
        export.on_click(self.export_csv)
        self.plots = column(*figs.values(), sizing_mode="stretch_width", name="plots")
        export_png = Button(label="export PNG", width=100, name="export_png")
        export_png.js_on_click(CustomJS(args={"plots": self.plots}, code=_PNG_JS))
        # the CSV is made here (view_csv); the page only hands the text to the browser as a download
        self.csv = Div(text="", visible=False, name="csv")
        self.csv.js_on_change("text", CustomJS(args={"src": self.csv}, code=_DOWNLOAD_JS))
        self.source_select = Select(title="trigger on", value="trip", width=110, name="trigger_source",
                                    options=[("channel", "a channel"), ("trip", "a trip"), ("move", "a move's start")])
        self.channel_select = Select(title="channel", value="e_table", options=names, width=100, name="trigger_channel")
        self.slope_select = Select(title="slope", value="rising", options=list(SLOPES), width=90, name="trigger_slope")
        self.level_input = TextInput(title=f"level ({self.units['e_table']})", value="0", width=90, name="level")
        self.pre_input = TextInput(title="pre-trigger", value="1s", width=80, name="pre")
        self.post_input = TextInput(title="post-trigger", value="200ms", width=80, name="post")
        for w in (self.source_select, self.channel_select, self.slope_select, self.level_input, self.pre_input,
                  self.post_input):
            w.on_change("value", lambda attr, old, new: self._trigger_changed())
        self.cursor_pick = RadioButtonGroup(labels=["tap sets A", "tap sets B"], active=0)
        self.cursor_inputs = (TextInput(title="cursor A (s)", value="", width=90, name="cursor_a"),
                              TextInput(title="cursor B (s)", value="", width=90, name="cursor_b"))
        for i, w in enumerate(self.cursor_inputs):
            w.on_change("value", lambda attr, old, new, i=i: self._cursor_typed(i, new))
        self.readout = Div(text="", name="readout")
        self.status = Div(text="rolling", name="status")
        self.trips = Div(text="no trip", name="trips")
        doc.title = server.title
        doc.add_root(column(Div(text=f"<b>{server.title}</b>"),
                            row(self.mode_select, self.window_select, self.freeze, arm, export, export_png,
                                self.status),
                            row(self.source_select, self.channel_select, self.slope_select, self.level_input,
                                self.pre_input, self.post_input),
                            row(self.cursor_pick, *self.cursor_inputs, self.readout),
                            self.trips, self.channels, self.plots, self.csv, sizing_mode="stretch_width"))
        doc.add_periodic_callback(self.update, int(server.period * 1000))

    # --- controls ------------------------------------------------------------------------------------
    def _show(self, names, active) -> None:
        for i, n in enumerate(names):
            self.lines[n].visible = i in active
        self._readout()

    def _set_window(self, seconds: float) -> None:
        self.window = seconds
        if self.mode == "rolling" and not self.frozen:
            self._reload()

    def _freeze(self, frozen: bool) -> None:
        self.frozen = frozen
        self.freeze.label = "resume" if frozen else "freeze"
        if not frozen:
            if self.mode == "rolling":
                self._reload()
                self.status.text = "rolling"
            else:
                self._arm()

    def _set_mode(self, mode: str) -> None:
        self.mode = mode
        if self.freeze.active:
            self.freeze.active = False        # its callback rolls on or arms
        elif mode == "rolling":
            self.armed, self.pending = False, None
            for s in self.trigger_spans:
                s.location = None
            self._reload()
            self.status.text = "rolling"
        else:
            self._arm()

    def _arm_clicked(self) -> None:
        if self.mode == "rolling":
            self.mode_select.value = "single"     # its callback arms
        elif self.freeze.active:
            self.freeze.active = False
        else:
            self._arm()

    def _arm(self) -> None:
        """Wait for the trigger in the rows written from now on."""
        self.armed, self.pending = True, None
        self.search_row = max(self.ring.count - 1, 0)
        self.search_t = self.ring.last_t if self.ring.count else -np.inf
        self.status.text = f"armed: waiting for {self.trigger.describe(self.units.get(self.trigger.channel, ''))}"

    def _trigger_changed(self) -> None:
        """The trigger's settings from the page (errors said in the status line, the old ones kept)."""
        from hil.units import parse_option
        channel = self.channel_select.value
        self.level_input.title = f"level ({self.units.get(channel, '')})"
        try:
            level = float(self.level_input.value)
            if not np.isfinite(level):
                raise ValueError
        except ValueError:
            self.status.text = f"level {self.level_input.value!r}: expected a number in {self.units.get(channel)}"
            return
        try:
            pre = parse_option(self.pre_input.value, "time", "pre-trigger")
            post = parse_option(self.post_input.value, "time", "post-trigger")
        except Exception as exc:           # a UnitError: its one line
            self.status.text = str(exc)
            return
        if pre < 0 or post < 0:
            self.status.text = "pre- and post-trigger time: expected 0 s or more"
            return
        t = self.trigger
        t.source, t.channel, t.slope, t.level, t.pre, t.post = (self.source_select.value, channel,
                                                                self.slope_select.value, level, pre, post)
        if self.mode != "rolling":
            self._arm()

    def _tap(self, x) -> None:
        if x is not None:
            self.cursor_inputs[self.cursor_pick.active].value = f"{x:.6f}"     # its callback sets the cursor

    def _cursor_typed(self, which: int, text: str) -> None:
        try:
            value = float(text) if text.strip() else None
        except ValueError:
            self.status.text = f"cursor {'AB'[which]} {text!r}: expected a time in s"
            return
        self.cursor_t[which] = value
        for s in self.cursor_spans[which]:
            s.location = value
        self._readout()

    def _readout(self) -> None:
        """Both cursors' times, their difference, and each shown channel's values there."""
        from hil.scope.view import cursor_values
        ta, tb = self.cursor_t
        if ta is None or tb is None:
            self.readout.text = "tap a plot (or type a time) to place cursors A and B"
            return
        shown = [n for n in SCOPE_CHANNELS[1:] if self.lines[n].visible]
        cells = "".join(f"<tr><td>{n}</td><td>{a:.6g}</td><td>{b:.6g}</td><td>{d:.6g}</td><td>{self.units[n]}</td></tr>"
                        for n, a, b, d in cursor_values(self.source.data, shown, ta, tb))
        self.readout.text = (f"<b>A</b> {ta:.6f} s, <b>B</b> {tb:.6f} s, <b>B-A</b> {(tb - ta) * 1e3:.3f} ms"
                             f"<table><tr><th></th><th>A</th><th>B</th><th>B-A</th><th></th></tr>{cells}</table>")

    def export_csv(self) -> str:
        """The rows in view as CSV (each column with its unit): handed to the browser as a download."""
        from hil.scope.view import view_csv
        self.exports += 1
        x0, x1 = self.x_range.start, self.x_range.end
        text = view_csv(self.source.data, {"t": "s", **self.units}, x0, x1, names=SCOPE_CHANNELS[1:])
        self.csv.text = f"# hil scope export {self.exports}: t {x0:.6f} s to {x1:.6f} s\n" + text
        return self.csv.text

    # --- the data ------------------------------------------------------------------------------------
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
        ordinary_priority()
        self.next_event, new = self.ring.events(self.next_event)
        trips = []
        for row, t, kind, reason in new:
            if kind in ("trip", "fault", "aborted"):
                text = f"{kind} at {t:.4f} s: {reason}"
                self.events.stream({"t": [t], "kind": [kind], "reason": [text], "y": [0.0]})
                self.trips.text = "<span style='color:red'>" + "<br>".join(self.events.data["reason"]) + "</span>"
                self.trip_times.append(t)
                trips.append(t)
            if kind != "start":
                self.ended_at = t
        if self.frozen:
            return
        if self.mode == "rolling":
            self._roll()
            if trips:
                self._hold_at(trips[0])
        elif self.armed:
            self._look_for_trigger()

    def _roll(self) -> None:
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
        if self.cursor_t[0] is not None and self.cursor_t[1] is not None:
            self._readout()

    def _hold_at(self, t_trip: float) -> None:
        """A trip in the rolling view: hold the view around it (most of the time base before it)."""
        self.freeze.active = True             # its callback freezes
        self.x_range.start, self.x_range.end = t_trip - 0.8 * self.window, t_trip + 0.2 * self.window
        self.status.text = f"held at the trip at {t_trip:.4f} s (resume rolls on)"

    def _look_for_trigger(self) -> None:
        """Armed: find the trigger in the rows since the last look, then wait for its post-trigger
        time (or the run's end) and show the capture."""
        from hil.scope.view import capture
        if self.pending is None:
            first, rows = self.ring.window(since=max(self.search_row - 2, 0))
            if rows.shape[0] == 0 and not self.trip_times:
                return
            hit = self.trigger.find(_columns(rows), self.trip_times, self.search_t)
            self.search_row = first + rows.shape[0]
            if hit is None:
                return
            self.pending = hit
            self.status.text = f"triggered at {hit:.4f} s: waiting for the post-trigger time"
        t_trig, post = self.pending, self.trigger.post
        if self.ring.last_t < t_trig + post and not (self.ended_at is not None and self.ended_at >= t_trig):
            return
        first, rows = self.ring.window(most=self.ring.capacity)
        shown = capture(rows, t_trig, self.trigger.pre, post, self.server.max_points)
        self.source.data = _columns(shown)
        self.x_range.start, self.x_range.end = t_trig - self.trigger.pre, t_trig + post
        for s in self.trigger_spans:
            s.location = t_trig
        self.triggered_at, self.pending = t_trig, None
        if self.mode == "single":
            self.armed = False
            self.status.text = f"single shot: triggered at {t_trig:.4f} s (arm for the next)"
        else:
            # the next trigger after the window shown; its rows are searched from there
            self.search_t = t_trig + post
            self.search_row = first + int(np.searchsorted(rows[:, 0], self.search_t, side="left"))
            self.status.text = f"triggered at {t_trig:.4f} s"
        if self.cursor_t[0] is not None and self.cursor_t[1] is not None:
            self._readout()

    def _follow(self) -> None:
        t = self.source.data["t"]
        if len(t):
            end = float(t[-1])
            self.x_range.start, self.x_range.end = max(end - self.window, float(t[0])), max(end, float(t[0]) + 1e-3)


RING_PREFIX = "hil-scope-"       # the rings' files (in /dev/shm where there is one)
SERVER_NICE = 10                 # the server's niceness (added to its parent's): below the loop and the drive


def ring_folder():
    """Where the rings' files go: ``/dev/shm`` (memory) where there is one, else the temporary folder."""
    import tempfile
    from pathlib import Path
    return Path("/dev/shm") if Path("/dev/shm").is_dir() else Path(tempfile.gettempdir())


def remove_stale_rings(folder=None) -> list[str]:
    """Remove the ring files a run that ended without cleaning up left behind (killed with SIGKILL,
    a power cut of a tmpfs that survived): the files with :data:`RING_PREFIX` whose writer no
    longer holds their lock (:class:`ScopeProcess` holds an exclusive ``flock`` on its file while
    it lives; the kernel drops it however the process ends). A file still being created (empty,
    younger than a minute) is left alone. Returns the paths removed."""
    import fcntl
    import time
    removed = []
    for path in (folder or ring_folder()).glob(RING_PREFIX + "*"):
        try:
            st = path.stat()
            if st.st_uid != os.getuid() or (st.st_size == 0 and time.time() - st.st_mtime < 60):
                continue
            fd = os.open(path, os.O_RDONLY)
        except OSError:              # gone meanwhile, or not ours to read
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:              # its writer lives
            os.close(fd)
            continue
        try:
            path.unlink()
            removed.append(str(path))
        except OSError:
            pass
        finally:
            os.close(fd)
    if removed:
        log.info("removed %d ring file(s) a run left behind: %s", len(removed), ", ".join(removed))
    return removed


def server_cpus(loop_cpu: int | None) -> set[int] | None:
    """The CPUs the scope's server (and anything else beside the loop) may run on: those of this
    process but the loop's (``runtime.loop_cpu``); None where nothing is pinned, or where the
    loop's CPU is the only one (then they share it, with a warning)."""
    if loop_cpu is None or not hasattr(os, "sched_getaffinity"):
        return None
    others = os.sched_getaffinity(0) - {loop_cpu}
    if not others:
        import warnings
        warnings.warn(f"runtime.loop_cpu {loop_cpu}: the only CPU this process may use; the scope's server "
                      f"shares it with the loop", RuntimeWarning, stacklevel=2)
        return None
    return others


def place_server(cpus: set[int] | None, nice: int) -> None:
    """Put the calling process (the scope's server, before it starts threads) on ``cpus`` and
    ``nice`` steps below its parent's priority: it never takes the loop's CPU, and where it shares
    one with other work it yields (Linux; elsewhere the niceness only). Linux keeps both per
    thread: every thread already started (numpy's, at import) is placed too, and the threads
    started later inherit it."""
    tids = [int(t) for t in os.listdir("/proc/self/task")] if os.path.isdir("/proc/self/task") else [0]
    if cpus and hasattr(os, "sched_setaffinity"):
        for tid in tids:
            os.sched_setaffinity(tid, cpus)
    if nice and hasattr(os, "setpriority"):
        for tid in tids:
            os.setpriority(os.PRIO_PROCESS, tid, min(os.getpriority(os.PRIO_PROCESS, tid) + nice, 19))


class ScopeProcess:
    """The scope's server in a process of its own (what the commands use): the ring is a shared
    file mapping (``/dev/shm`` where there is one) the cycle writes here and the server reads there,
    so the server never holds this process's interpreter lock, which the cycle needs (a thread
    here would: at ordinary priority, preempted while holding it, it stalls a real-time loop;
    at the loop's priority it competes with it). The token goes to the child on its stdin (not its
    command line, which other users of the machine can read); closing that pipe (or this process
    ending) stops it.

    The server runs ``nice`` steps below this process's priority and, with ``loop_cpu`` (the CPU
    the loop is pinned to, ``runtime.loop_cpu``), on the other CPUs (:func:`server_cpus`). The
    ring's file is locked while this object lives; rings of runs killed before they could remove
    theirs are removed when the next one is made (:func:`remove_stale_rings`).

    Parameters: as :class:`ScopeServer`, less the ring (made here: ``capacity`` rows, ``events``);
    ``loop_cpu``, ``nice``.
    """

    def __init__(self, capacity: int = 1 << 16, events: int = 64, port: int = 0, token: str | None = None,
                 title: str = "hil scope", output_unit: str = "N m", max_points: int = 2000, period: float = 0.04,
                 loop_cpu: int | None = None, nice: int = SERVER_NICE):
        import fcntl
        import tempfile
        self.port, self.token = int(port), token or secrets.token_urlsafe(16)
        self.title, self.output_unit, self.max_points, self.period = title, output_unit, int(max_points), float(period)
        self.cpus, self.nice = server_cpus(loop_cpu), int(nice)
        folder = ring_folder()
        remove_stale_rings(folder)
        fd, path = tempfile.mkstemp(prefix=RING_PREFIX, dir=folder)
        fcntl.flock(fd, fcntl.LOCK_EX)       # held while this run lives (remove_stale_rings)
        self._lock = fd
        self.path = path
        self.ring = ScopeRing(capacity, events, path=path)
        self.proc = None

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}/scope?token={self.token}"

    @property
    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def start(self) -> str:
        """Start the server's process; returns the URL once it listens (a bad port: UserError)."""
        import subprocess
        import sys
        from pathlib import Path

        import hil
        from hil.errors import UserError
        root = str(Path(hil.__file__).resolve().parents[1])
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([root] + [p for p in [os.environ.get("PYTHONPATH")] if p]))
        cpus = ",".join(map(str, sorted(self.cpus))) if self.cpus else "-"
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "hil.scope.server", self.path, str(self.ring.capacity), str(self.ring.n_events),
             str(self.port), self.title, self.output_unit, str(self.max_points), str(self.period), cpus,
             str(self.nice)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env)
        self.proc.stdin.write(self.token + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline().strip()
        if not line.isdigit():
            self.stop()
            raise UserError(line.removeprefix("error: ") or "the scope's server did not start")
        self.port = int(line)
        return self.url

    def stop(self) -> None:
        """Stop the server's process; the ring stays readable here (its file is removed)."""
        import subprocess
        if self.proc is not None:
            try:
                self.proc.stdin.close()
            except OSError:
                pass
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
            self.proc.stdout.close()
        try:
            os.unlink(self.path)
        except FileNotFoundError:
            pass
        if self._lock is not None:          # after the file is gone: no other run removes it meanwhile
            os.close(self._lock)
            self._lock = None


def _serve_shared(argv: list[str]) -> int:
    """The child of :class:`ScopeProcess`: serve the ring mapped from ``argv[0]`` until stdin closes."""
    import sys
    path, capacity, events, port, title, unit, max_points, period, cpus, nice = argv
    # placed before the server starts its threads: they inherit it
    place_server(None if cpus == "-" else {int(c) for c in cpus.split(",")}, int(nice))
    token = sys.stdin.readline().strip()
    ring = ScopeRing.attach(path, int(capacity), int(events))
    server = ScopeServer(ring, port=int(port), token=token, title=title, output_unit=unit,
                         max_points=int(max_points), period=float(period))
    try:
        server.start()
    except Exception as exc:               # said by the parent, in one line
        print(f"error: {exc}", flush=True)
        return 2
    print(server.port, flush=True)
    try:
        sys.stdin.read()                   # until the parent closes it, or ends
    except KeyboardInterrupt:              # Ctrl-C reaches the whole process group: the parent decides
        sys.stdin.read()
    server.stop()
    return 0


if __name__ == "__main__":
    import signal
    import sys
    signal.signal(signal.SIGINT, signal.SIG_IGN)     # Ctrl-C is the parent's: it ends the hold, then closes stdin
    sys.exit(_serve_shared(sys.argv[1:]))
