"""The live scope as a person uses it (issue 27, item 6): ``hil drive-sim`` (the simulated CiA 402
drive in its own process, socketcand on 127.0.0.1), ``hil move --backend canopen --scope`` against
it, the page opened in headless Chromium; the test waits for the traces, the drive faults (its
``--fault emcy=0x2310@6``: 6 s into the move), and the page must show the trip marker with its
reason and keep the cycles before it.

What the page shows is read from the page itself through the DevTools protocol (tornado's
websocket client: a dependency of bokeh): the text of the rendered DOM (Bokeh's widgets live in
shadow roots, so ``--dump-dom`` cannot see them; a small walker collects their text) and
BokehJS's own document (the data the plots draw). Screenshots of the rolling view and of the
trip go to out/browser/ (a CI artefact; docs/scope_rolling.png and docs/scope_trip.png are copies).

Skipped with the reason where no Chromium is installed (Debian: apt-get install chromium). Slow
(about 20 to 30 s: two processes, a browser and a 6 s move), so marked ``slow``.
"""
from __future__ import annotations

import base64
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CANOPEN = str(ROOT / "config" / "paper_bench_canopen.toml")
HIL = [sys.executable, "-c", "import sys; from hil.cli import main; sys.exit(main(sys.argv[1:]))"]
CHROMIUM = next((p for p in map(shutil.which, ("chromium", "chromium-browser", "google-chrome")) if p), None)
SCREENSHOTS = ROOT / "out" / "browser"
FAULT_AT = 6.0           # s into the move: the page is up and streaming well before
# the subject is the drive's fault: a loaded test machine (a browser beside two processes) must not
# trip the host's overrun watchdog, its PDO-miss limit, its frozen-feedback rule or the drive-side
# guards (heartbeat, SYNC loss: the host sets them on the drive) first
TOLERANT = [x for kv in ("supervisor.overrun_cycles=100", "canopen.pdo_miss_limit=100", "supervisor.frozen_cycles=100",
                         "canopen.heartbeat_timeout=2s", "canopen.drive_heartbeat_timeout=2s",
                         "canopen.sync_timeout=400ms", "runtime.priority=50") for x in ("--set", kv)]

# what the page shows: the rendered text (shadow roots included) and BokehJS's document
PROBE = r"""(() => {
  const texts = [];
  const walk = (root) => {
    for (const e of root.querySelectorAll('*')) { if (e.shadowRoot) walk(e.shadowRoot); }
    for (const e of root.querySelectorAll('div, span')) {
      if (!e.children.length && e.textContent) texts.push(e.textContent);
    }
  };
  walk(document);
  const doc = (window.Bokeh && Bokeh.documents.length) ? Bokeh.documents[0] : null;
  if (!doc) return JSON.stringify({ready: false, text: texts.join('\n')});
  const m = (n) => doc.get_model_by_name(n);
  const t = Array.from(m('traces').data.t);
  return JSON.stringify({ready: true, text: texts.join('\n'), t: t, markers: Array.from(m('trip_markers').data.t),
                         reasons: Array.from(m('trip_markers').data.reason), status: m('status').text,
                         trips: m('trips').text});
})()"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class DevTools:
    """The page's DevTools protocol over a websocket (tornado's client, on its own event loop)."""

    def __init__(self, ws_url: str):
        from tornado.ioloop import IOLoop
        from tornado.websocket import websocket_connect
        self.loop = IOLoop(make_current=False)
        self.conn = self.loop.run_sync(lambda: websocket_connect(ws_url), timeout=20)
        self.next_id = 0

    def call(self, method: str, **params) -> dict:
        self.next_id += 1
        mid = self.next_id

        async def roundtrip():
            await self.conn.write_message(json.dumps({"id": mid, "method": method, "params": params}))
            while True:
                msg = await self.conn.read_message()
                if msg is None:
                    raise RuntimeError("DevTools closed the connection")
                reply = json.loads(msg)
                if reply.get("id") == mid:
                    return reply
        reply = self.loop.run_sync(roundtrip, timeout=60)
        if "error" in reply:
            raise RuntimeError(f"{method}: {reply['error']}")
        return reply["result"]

    def probe(self) -> dict:
        r = self.call("Runtime.evaluate", expression=PROBE, returnByValue=True)
        return json.loads(r["result"]["value"])

    def screenshot(self, path: Path) -> None:
        data = self.call("Page.captureScreenshot", format="png")["data"]
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(base64.b64decode(data))

    def close(self) -> None:
        self.conn.close()
        self.loop.close()


def _wait(what: str, cond, timeout: float, proc=None):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        got = cond()
        if got:
            return got
        if proc is not None and proc.poll() is not None:
            break
        time.sleep(0.1)
    raise AssertionError(f"{what}: not within {timeout} s")


def _stop(proc, sig=signal.SIGINT, wait=20.0) -> None:
    if proc is None or proc.poll() is not None:
        return
    proc.send_signal(sig)
    try:
        proc.wait(wait)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason="no Chromium installed (Debian: apt-get install chromium; "
                                             ".ci/run installs it)")
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="signals and sockets as on Linux")
def test_the_page_shows_a_drive_fault_with_the_cycles_before_it(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT), HIL_STATE_DIR=str(tmp_path / "state"))
    port = _free_port()
    drive = host = browser = devtools = None
    host_err: list[str] = []
    try:
        drive = subprocess.Popen(HIL + ["drive-sim", "--config", CANOPEN, "--port", str(port), "--json",
                                        "--priority", "50", "--fault", f"emcy=0x2310@{FAULT_AT:g}"],
                                 env=env, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        assert json.loads(drive.stdout.readline())["port"] == port            # the drive is up
        # 800 mm at 100 mm/s: the move lasts past the fault
        host = subprocess.Popen(HIL + ["move", "--config", CANOPEN, "--backend", "canopen",
                                       "--set", "canopen.interface=socketcand", "--set", "canopen.channel=can0",
                                       "--set", f"canopen.port={port}", *TOLERANT, "--stroke", "800mm", "--feed", "6000mm/min",
                                       "--amax", "2m/s^2", "--out", str(tmp_path / "out"), "--scope",
                                       "--scope-hold", "120s", "--json"],
                                env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        url = None
        for line in host.stderr:                  # the URL with its token, on stderr
            host_err.append(line)
            m = re.search(r"scope at (http://127\.0\.0\.1:\d+/scope\?token=\S+)", line)
            if m:
                url = m.group(1)
                break
        assert url, "".join(host_err)
        threading.Thread(target=lambda: host_err.extend(host.stderr), daemon=True).start()   # keep it drained
        debug_port = _free_port()
        browser = subprocess.Popen([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                                    "--no-first-run", "--disable-background-networking", "--disable-component-update",
                                    "--disable-sync", "--hide-scrollbars", "--window-size=1400,1500",
                                    f"--user-data-dir={tmp_path / 'profile'}", f"--remote-debugging-port={debug_port}",
                                    url], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                   preexec_fn=lambda: os.nice(10))      # the loop first, as on a real axis

        def page_ws():
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{debug_port}/json/list", timeout=2) as r:
                    pages = [p for p in json.loads(r.read()) if p.get("type") == "page" and "/scope" in p["url"]]
            except OSError:
                return None
            return pages[0]["webSocketDebuggerUrl"] if pages else None
        devtools = DevTools(_wait("Chromium's DevTools", page_ws, 30, browser))

        # the traces, before the fault: the rolling view streams
        def streaming():
            p = devtools.probe()
            return p if p["ready"] and len(p["t"]) > 50 else None
        try:
            before = _wait("the traces on the page", streaming, 30, host)
        except AssertionError as exc:
            raise AssertionError(f"{exc}; host rc {host.poll()}: {''.join(host_err)[-2000:]}; page: "
                                 f"{devtools.probe()}") from None
        assert not before["markers"] and "no trip" in before["text"], f"a trip before the page showed traces: {before['reasons']}"
        assert before["t"][-1] < FAULT_AT
        devtools.screenshot(SCREENSHOTS / "scope_rolling.png")     # (slow on a loaded machine: the fault
        rolled = not devtools.probe()["markers"]                  # may have come meanwhile)

        # the fault: the marker, its reason, the view held around it
        def tripped():
            p = devtools.probe()
            return p if p["markers"] and "held at the trip" in p["status"] else None
        after = _wait("the trip on the page", tripped, 40, host)
        time.sleep(0.5)                           # the last frames of the controlled stop
        after = devtools.probe()
        devtools.screenshot(SCREENSHOTS / "scope_trip.png")
    finally:
        if devtools is not None:
            devtools.close()
        _stop(browser, signal.SIGTERM)
        _stop(host)                               # Ctrl-C ends the scope's hold
        _stop(drive)
    if not rolled:
        (SCREENSHOTS / "scope_rolling.png").unlink()        # not a rolling view: none rather than a wrong one
    t_trip = after["markers"][0]
    # the reason as the host reported it, on the rendered page (DOM text) and with the marker
    out = json.loads(host.stdout.read())
    assert out["stop"] == "drive_fault" and "EMCY 0x2310" in out["reason"], out
    assert after["reasons"][0].endswith(f" at {t_trip:.4f} s: {out['reason']}")
    shown = after["text"]
    assert f" at {t_trip:.4f} s: {out['reason']}" in shown and "held at the trip" in shown
    # the trip is about FAULT_AT into the move (the drive's clock starts when it is enabled)
    assert FAULT_AT - 0.5 < t_trip < FAULT_AT + 1.0
    # the cycles before it are kept: the 4 s of the 5 s time base before the trip, at 250 Hz
    # (4 ms), decimated to at most 2000 points in 5 s (every 3rd row, 12 ms)
    t = after["t"]
    kept = [x for x in t if x <= t_trip]
    assert kept[0] <= t_trip - 3.5 and len(kept) >= 3.5 / 0.012
    assert all(b > a for a, b in zip(t, t[1:]))


@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason="no Chromium installed (Debian: apt-get install chromium; "
                                             ".ci/run installs it)")
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc and signals as on Linux")
def test_the_timing_benchmark_compares_a_run_with_the_page_streaming():
    """benchmarks/bench_canopen_timing.py --scope: the same run without and with the page open in
    Chromium, in one invocation; the page's figures on the second."""
    out = subprocess.run([sys.executable, str(ROOT / "benchmarks/bench_canopen_timing.py"), "--transport", "virtual",
                          "--rate", "250", "--duration", "3", "--scope", "--json"], cwd=ROOT, capture_output=True,
                         text=True, timeout=300, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert out.returncode == 0, out.stderr[-2000:]
    without, with_page = json.loads(out.stdout)["results"]
    assert (without["scope"], with_page["scope"]) == (False, True) and with_page["transport"].endswith("+scope")
    assert without["cycles"] == with_page["cycles"] == 750
    assert "page_frames_per_s" not in without
    assert with_page["page_frames_per_s"] > 0 and 0 < with_page["server_cpu_pct_of_one_core"] < 100
    assert 0 < with_page["page_latency_p50_ms"] <= with_page["page_latency_p99_ms"] <= with_page["page_latency_max_ms"]


@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason="no Chromium installed (Debian: apt-get install chromium; "
                                             ".ci/run installs it)")
@pytest.mark.skipif(not hasattr(os, "sched_setaffinity") or len(os.sched_getaffinity(0)) < 2,
                    reason="pinning needs Linux and two CPUs")
def test_the_timing_benchmark_repeats_with_the_loop_pinned():
    """--repeat 2 --loop-cpu N --peer: two interleaved triples (without, with the page, with a busy
    process where the page runs), the loop on CPU N, and the noise of the two repetitions computed
    from the runs it printed; --points sets the page's points a trace."""
    pin = max(os.sched_getaffinity(0))
    out = subprocess.run([sys.executable, str(ROOT / "benchmarks/bench_canopen_timing.py"), "--transport", "virtual",
                          "--rate", "250", "--duration", "2", "--scope", "--repeat", "2", "--loop-cpu", str(pin),
                          "--peer", "--points", "500", "--json"], cwd=ROOT, capture_output=True, text=True,
                         timeout=400, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert out.returncode == 0, out.stderr[-2000:]
    doc = json.loads(out.stdout)
    res = doc["results"]
    assert [(r["scope"], r["peer"], r["repetition"], r["loop_cpu"], r["scope_nice"]) for r in res] == [
        (False, False, 0, pin, None), (True, False, 0, pin, 10), (False, True, 0, pin, None),
        (False, False, 1, pin, None), (True, False, 1, pin, 10), (False, True, 1, pin, None)]
    assert res[2]["transport"].endswith("+busy page CPU") and "page_frames_per_s" not in res[2]
    assert res[2]["load"] == "page CPU busy" and res[2]["peer_nice"] == 10
    assert [r["page_points_per_trace"] for r in res if r["scope"]] == [500, 500]
    assert all(0 < r["browser_cpu_pct_of_one_core"] for r in res if r["scope"])
    (summary,) = doc["scope_noise"]
    p99 = summary["noise"]["lateness_p99_us"]
    a, b = [res[0]["lateness_p99_us"], res[3]["lateness_p99_us"]], [res[1]["lateness_p99_us"], res[4]["lateness_p99_us"]]
    c = [res[2]["lateness_p99_us"], res[5]["lateness_p99_us"]]
    assert p99["without"] == a and p99["with"] == b and p99["peer"] == c
    assert p99["spread"] == pytest.approx(max(abs(a[0] - a[1]), abs(b[0] - b[1])))
    assert p99["difference"] == pytest.approx((b[0] + b[1]) / 2 - (a[0] + a[1]) / 2)
    assert p99["difference_to_peer"] == pytest.approx((b[0] + b[1]) / 2 - (c[0] + c[1]) / 2)


# the page's downloads (an anchor with ``download`` clicked) kept instead of saved: [name, data URL]
CATCH_DOWNLOADS = r"""(() => {
  window.__downloads = [];
  HTMLAnchorElement.prototype.click = function () {
    const name = this.download;
    fetch(this.href).then((r) => r.blob()).then((b) => {
      const fr = new FileReader();
      fr.onload = () => window.__downloads.push([name, fr.result]);
      fr.readAsDataURL(b);
    });
  };
  return true;
})()"""


@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason="no Chromium installed (Debian: apt-get install chromium; "
                                             ".ci/run installs it)")
def test_export_png_is_the_whole_view(tmp_path):
    """The page's "export PNG": one image of every pane (positions, error, output, speed, state),
    not one plot's: as tall as the five plots together (4 x 200 + 90 px), as wide as the page,
    with the traces drawn in the top pane (x_cmd) and in the bottom one (state)."""
    import io

    import matplotlib.image
    import numpy as np

    from hil.scope.ring import ScopeRing, feed
    from hil.scope.server import ScopeServer
    ring = ScopeRing()
    t = np.arange(2000) * 1e-3
    ch = {n: np.zeros_like(t) for n in ["x_motor", "x_table", "x_tip", "e_table", "e_tip", "torque"]}
    ch.update(t=t, x_cmd=0.01 * np.sin(2 * np.pi * t))
    feed(ring, ch, pace=None, status="tripped", reason="following error")
    server = ScopeServer(ring)
    url = server.start()
    debug_port = _free_port()
    browser = devtools = None
    try:
        browser = subprocess.Popen([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                                    "--no-first-run", "--disable-background-networking", "--hide-scrollbars",
                                    "--window-size=1200,1500", f"--user-data-dir={tmp_path / 'profile'}",
                                    f"--remote-debugging-port={debug_port}", url],
                                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

        def page_ws():
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{debug_port}/json/list", timeout=2) as r:
                    pages = [p for p in json.loads(r.read()) if p.get("type") == "page" and "/scope" in p["url"]]
            except OSError:
                return None
            return pages[0]["webSocketDebuggerUrl"] if pages else None
        devtools = DevTools(_wait("Chromium's DevTools", page_ws, 30, browser))

        def js(expr):
            return devtools.call("Runtime.evaluate", expression=expr, returnByValue=True,
                                 awaitPromise=True)["result"].get("value")
        _wait("the traces on the page", lambda: (p := devtools.probe())["ready"] and len(p["t"]) > 100, 30, browser)
        time.sleep(0.5)                                   # the frame drawn
        assert js(CATCH_DOWNLOADS)
        js("Bokeh.index.get_one(Bokeh.documents[0].get_model_by_name('export_png')).button_el.click()")
        got = _wait("the PNG download", lambda: js("JSON.stringify(window.__downloads)") != "[]", 20, browser)
        assert got
        ((name, data),) = json.loads(js("JSON.stringify(window.__downloads)"))
        width = js("window.innerWidth")
    finally:
        if devtools is not None:
            devtools.close()
        _stop(browser, signal.SIGTERM)
        server.stop()
    assert name == "scope.png" and data.startswith("data:image/png;base64,")
    png = base64.b64decode(data.split(",", 1)[1])
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    (SCREENSHOTS / "scope_export.png").write_bytes(png)          # what a person gets (a CI artefact)
    img = matplotlib.image.imread(io.BytesIO(png), format="png")
    h, w = img.shape[:2]
    assert 4 * 200 + 90 <= h < 4 * 200 + 90 + 100 and width * 0.8 <= w <= width
    # a trace's pixels (not white, not grey): the sine of x_cmd (black) in the top pane, state in the last
    ink = np.abs(img[:, :, :3] - 1.0).sum(axis=2) > 0.5
    assert ink[:200].sum() > 500 and ink[-90:].sum() > 100
