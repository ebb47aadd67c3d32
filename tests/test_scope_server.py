"""The live scope's server (issue 27): only 127.0.0.1, a per-run token, no foreign websocket
origin, and the page's data source gets the record's values."""
import threading
import time
import urllib.error
import urllib.request

import numpy as np
import pytest
from conftest import CONFIG

from hil.io.measurement import read
from hil.scope.ring import ScopeRing, feed
from hil.scope.server import ScopeServer


def _channels(n=3000, period=1e-3):
    t = np.arange(n) * period
    ch = {n: np.sin(2 * np.pi * (i + 1) * t) * 1e-3 for i, n in
          enumerate(["x_cmd", "x_motor", "x_table", "x_tip", "e_table", "e_tip"])}
    ch["torque"] = np.cos(t)
    ch["t"] = t
    return ch


@pytest.fixture
def served():
    ring = ScopeRing()
    feed(ring, _channels(), status="tripped", reason="following error 2.1 mm > 1 mm", pace=None)
    server = ScopeServer(ring, period=0.02)
    server.start()
    yield server
    server.stop()


def _get(url):
    try:
        with urllib.request.urlopen(url, timeout=20) as r:
            return r.status, r.read().decode()
    except urllib.error.HTTPError as exc:
        return exc.code, ""


def _wait(cond, timeout=10.0):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if cond():
            return True
        time.sleep(0.02)
    return False


def test_only_loopback_and_the_token(served):
    assert served.url.startswith("http://127.0.0.1:")
    base = served.url.split("?")[0]
    assert _get(base)[0] == 403
    assert _get(base + "?token=" + "x" * len(served.token))[0] == 403
    assert not served.sessions                              # no page, no data for them
    status, html = _get(served.url)
    assert status == 200 and "bokeh" in html.lower()
    assert "cdn.bokeh.org" not in html                      # BokehJS from the package: no network
    assert _wait(lambda: served.sessions and len(served.sessions[0].source.data["t"]) > 0)


def test_the_page_gets_the_rows_decimated_and_the_trip(served):
    status, _ = _get(served.url)
    assert status == 200
    page = served.sessions[0]
    assert _wait(lambda: len(page.events.data["t"]) == 1 and len(page.source.data["t"]) > 0)
    t = np.asarray(page.source.data["t"])
    # a 5 s window at 1 kHz is 5000 rows, at most 2000 points: every third row (of the 3000 there are)
    assert page.stride == 3 and t.size == 1000 and np.allclose(np.diff(t), 3e-3)
    ch = _channels()
    np.testing.assert_allclose(page.source.data["x_table"], ch["x_table"][::3] * 1e3)     # mm
    np.testing.assert_allclose(page.source.data["e_tip"], ch["e_tip"][::3] * 1e6)         # um
    assert page.events.data["t"][0] == pytest.approx(2.999)
    assert "following error 2.1 mm" in page.events.data["reason"][0]
    assert "following error 2.1 mm" in page.trips.text


def test_a_foreign_origin_is_refused_for_the_websocket(served):
    """Bokeh's allow_websocket_origin: a websocket from another origin gets 403, the same
    request from the page's own origin is let through to the session check."""
    from tornado.httpclient import HTTPClientError, HTTPRequest
    from tornado.ioloop import IOLoop
    from tornado.websocket import websocket_connect
    port = served.port
    ws = f"ws://127.0.0.1:{port}/scope/ws"

    async def attempt(origin):
        req = HTTPRequest(ws, headers={"Origin": origin, "Sec-WebSocket-Protocol": "bokeh, nonsense"})
        try:
            conn = await websocket_connect(req)
        except HTTPClientError as exc:
            return exc.code
        msg = await conn.read_message()     # the server closes a connection without a valid session
        conn.close()
        return msg
    assert IOLoop(make_current=False).run_sync(lambda: attempt("http://evil.example:80")) == 403
    assert IOLoop(make_current=False).run_sync(lambda: attempt(f"http://127.0.0.1:{port}")) is None


@pytest.mark.slow
@pytest.mark.realtime
def test_hil_scope_replays_a_record(tmp_path, monkeypatch, capsys):
    """``hil scope RECORD.csv``: the page's data source gets the record's values."""
    from hil.cli import main
    from hil.commands import scope as scope_cmd
    assert main(["move", "--config", str(CONFIG / "paper_bench.toml"), "--stroke", "10mm", "--feed",
                 "7000mm/min", "--tacc", "200ms", "--dwell", "0.2s", "--out", str(tmp_path)]) == 0
    record = tmp_path / "move.csv"
    started = []
    real_start = scope_cmd.start_scope
    monkeypatch.setattr(scope_cmd, "start_scope", lambda *a, **k: started.append(real_start(*a, **k)) or started[-1])
    rc = []
    th = threading.Thread(target=lambda: rc.append(main(["scope", str(record), "--speed", "100", "--hold", "4s"])))
    th.start()
    try:
        assert _wait(lambda: started)
        server = started[0]
        assert _get(server.url)[0] == 200
        page = server.sessions[0]
        m = read(record)
        assert _wait(lambda: page.ring.events()[0] == 1
                     and len(page.source.data["t"]) == len(m))
        np.testing.assert_allclose(page.source.data["x_tip"], m["x_tip"] * 1e3)
        np.testing.assert_allclose(page.source.data["output"], m["torque"])
    finally:
        th.join(30)
    assert rc == [0]
    assert "hil scope: scope at http://127.0.0.1:" in capsys.readouterr().err


def test_bad_input_is_one_line(tmp_path, capsys):
    from hil.cli import main
    assert main(["scope", str(tmp_path / "none.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "none.csv" in err
    assert main(["scope", str(tmp_path / "none.csv"), "--speed", "0"]) == 2
    assert "--speed 0: expected a positive number" in capsys.readouterr().err
    assert main(["move", "--config", str(CONFIG / "paper_bench.toml"), "--stroke", "10mm", "--feed", "7000mm/min",
                 "--tacc", "200ms", "--scope", "--scope-port", "70000", "--out", str(tmp_path)]) == 2
    assert "--scope-port 70000: expected a port" in capsys.readouterr().err


def _in_page(page, fn):
    """Run ``fn`` in the page's own thread (Bokeh's next-tick callback, with the document's lock)."""
    done, out = threading.Event(), []

    def tick():
        try:
            out.append(fn())
        finally:
            done.set()
    page.doc.add_next_tick_callback(tick)
    assert done.wait(10)
    return out[0] if out else None


def _page(server):
    assert _get(server.url)[0] == 200
    assert _wait(lambda: server.sessions)
    return server.sessions[-1]


def test_a_trip_holds_the_rolling_view_with_the_cycles_before_it(served):
    """The record ends in a trip at 2.999 s: the rolling view freezes around it (4 s of the 5 s time
    base before it) and keeps every shown row before it; its reason is on the page."""
    page = _page(served)
    assert _wait(lambda: "held at the trip" in page.status.text)
    assert page.freeze.active and page.frozen and page.freeze.label == "resume"
    assert (page.x_range.start, page.x_range.end) == pytest.approx((2.999 - 4.0, 2.999 + 1.0))
    t = np.asarray(page.source.data["t"])
    assert t[0] == 0.0 and t[-1] == pytest.approx(2.997) and t.size == 1000
    assert "following error 2.1 mm" in page.trips.text and page.events.data["t"] == [pytest.approx(2.999)]
    _in_page(page, lambda: setattr(page.freeze, "active", False))       # resume: rolls on
    assert not page.frozen and page.status.text == "rolling"


def test_single_shot_on_a_rising_level_shows_pre_and_post_time():
    """x_cmd = 100 mm/s * t crosses 50 mm at t = 0.5 s: armed single shot with 100 ms before and
    50 ms after shows exactly that window, the trigger marked, then waits to be armed again."""
    ring = ScopeRing()
    server = ScopeServer(ring, period=0.02)
    server.start()
    try:
        page = _page(server)

        def setup():
            page.source_select.value = "channel"
            page.channel_select.value = "x_cmd"
            page.slope_select.value = "rising"
            page.level_input.value = "50"
            page.pre_input.value = "100ms"
            page.post_input.value = "50ms"
            page.mode_select.value = "single"
        _in_page(page, setup)
        assert page.armed and "armed: waiting for x_cmd rising through 50 mm" in page.status.text
        t = np.arange(1000) * 1e-3
        ch = {n: np.zeros_like(t) for n in ["x_motor", "x_table", "x_tip", "e_table", "e_tip", "torque"]}
        ch.update(t=t, x_cmd=0.1 * t)
        feed(ring, ch, pace=None)
        assert _wait(lambda: "single shot" in page.status.text)
        assert not page.armed
        assert page.triggered_at == pytest.approx(0.5, abs=1e-9)
        assert (page.x_range.start, page.x_range.end) == pytest.approx((0.4, 0.55))
        assert page.trigger_spans[0].location == pytest.approx(0.5)
        shown = np.asarray(page.source.data["t"])
        assert shown[0] == pytest.approx(0.4) and shown[-1] == pytest.approx(0.55) and shown.size == 151
        np.testing.assert_allclose(page.source.data["x_cmd"], 100.0 * shown)
        # a bad level is said on the page, the trigger kept
        _in_page(page, lambda: setattr(page.level_input, "value", "fifty"))
        assert "level 'fifty': expected a number in mm" in page.status.text and page.trigger.level == 50.0
    finally:
        server.stop()


def test_cursors_and_the_csv_of_the_view(served):
    page = _page(served)
    assert _wait(lambda: page.frozen)                 # held at the trip

    def cursors():
        page.cursor_inputs[0].value = "1.0"
        page.cursor_inputs[1].value = "1.0625"
    _in_page(page, cursors)
    assert "<b>B-A</b> 62.500 ms" in page.readout.text
    assert page.cursor_spans[1][0].location == 1.0625
    # x_tip = sin(2 pi 4 t) mm: 0 at A, 1 at B (within the interpolation between shown rows)
    row = next(r for r in page.readout.text.split("<tr>") if r.startswith("<td>x_tip</td>"))
    a, b, d = (float(c.split("</td>")[0]) for c in row.split("<td>")[2:5])
    assert a == pytest.approx(0.0, abs=0.02) and b == pytest.approx(1.0, abs=0.02) and d == pytest.approx(b - a)
    text = _in_page(page, page.export_csv)
    lines = text.splitlines()
    assert lines[0].startswith("# hil scope export 1") and lines[1].startswith("t [s],x_cmd [mm],x_motor [mm]")
    data = np.loadtxt(lines[2:], delimiter=",")
    t = np.asarray(page.source.data["t"])
    keep = (t >= page.x_range.start) & (t <= page.x_range.end)
    np.testing.assert_array_equal(data[:, 0], t[keep])
    np.testing.assert_array_equal(data[:, 3], np.asarray(page.source.data["x_table"])[keep])
    assert page.csv.text == text


def test_the_server_thread_does_not_keep_a_real_time_priority(served):
    """The loop's runtime.priority raises every thread of the process to SCHED_FIFO, the scope's
    server too: the server's next frame puts its thread back to the ordinary policy."""
    import os
    if not hasattr(os, "sched_setscheduler"):
        pytest.skip("no sched_setscheduler on this platform")
    _page(served)
    tid = served.native_id
    try:
        os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(10))
    except PermissionError:
        pytest.skip("real-time scheduling not permitted here (CAP_SYS_NICE)")
    assert _wait(lambda: os.sched_getscheduler(tid) == os.SCHED_OTHER, 5.0)


def test_the_server_in_its_own_process_reads_the_shared_ring(tmp_path):
    """ScopeProcess (what the commands start): the page served by a child process from the ring
    written here; the token checked there; a taken port one line; stopped, its file gone and the
    ring still readable here."""
    import os
    import socket

    from hil.errors import UserError
    from hil.scope.server import ScopeProcess
    server = ScopeProcess()
    try:
        server.ring.write(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0)
        server.ring.event(0.0, "trip", "Überlast ✓")
        url = server.start()
        assert server.running and os.path.exists(server.path) and str(server.path).count("hil-scope-")
        assert _get(url.split("?")[0])[0] == 403 and _get(url)[0] == 200
        attached = ScopeRing.attach(server.path, server.ring.capacity, server.ring.n_events)
        assert attached.window()[1][0, 1:9].tolist() == [1, 2, 3, 4, 5, 6, 7, 8]
        assert attached.events()[1] == [(0, 0.0, "trip", "Überlast ✓")]
        attached.close()
        with socket.socket() as taken:
            taken.bind(("127.0.0.1", 0))
            taken.listen()
            second = ScopeProcess(port=taken.getsockname()[1])
            with pytest.raises(UserError, match=f"port {taken.getsockname()[1]}: cannot listen on 127.0.0.1"):
                second.start()
            assert not second.running and not os.path.exists(second.path)
    finally:
        server.stop()
    assert not server.running and not os.path.exists(server.path)
    assert server.ring.count == 1 and server.ring.window()[1][0, 1] == 1.0


def test_normal_mode_rearms_after_each_window():
    """x_cmd = 10 mm * sin(2 pi t) rises through 0 at t = 0, 1, 2, ...: in normal mode with 100 ms
    before and 200 ms after, the page shows the window around each rising crossing in turn; the
    last one it shows is at the last whole second of the rows fed."""
    ring = ScopeRing()
    server = ScopeServer(ring, period=0.02)
    server.start()
    try:
        page = _page(server)

        def setup():
            page.source_select.value = "channel"
            page.channel_select.value = "x_cmd"
            page.level_input.value = "0"
            page.pre_input.value = "100ms"
            page.post_input.value = "200ms"
            page.mode_select.value = "normal"
        _in_page(page, setup)
        t = np.arange(3500) * 1e-3 + 0.5            # from 0.5 s: the crossings at 1, 2 and 3 s
        ch = {n: np.zeros_like(t) for n in ["x_motor", "x_table", "x_tip", "e_table", "e_tip", "torque"]}
        ch.update(t=t, x_cmd=0.01 * np.sin(2 * np.pi * t))
        seen = []

        def watch():
            if page.triggered_at is not None and (not seen or seen[-1] != page.triggered_at):
                seen.append(page.triggered_at)
            return len(seen) == 3
        feeder = threading.Thread(target=feed, args=(ring, ch), kwargs={"pace": 2.0})    # twice real time
        feeder.start()
        try:
            assert _wait(watch, 10.0), seen
        finally:
            feeder.join()
        assert seen == [pytest.approx(1.0, abs=1e-9), pytest.approx(2.0, abs=1e-9), pytest.approx(3.0, abs=1e-9)]
        assert page.armed and (page.x_range.start, page.x_range.end) == pytest.approx((2.9, 3.2))
    finally:
        server.stop()
