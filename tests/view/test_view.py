"""``svss view`` end to end: the real command serving on loopback, fed by a real status
stream (the daemon's publisher and alarm checks: :mod:`.feed`) and a worker's output
folder into which tiles are written as the worker writes them (``save_tile``:
:mod:`.synthetic`).

- over HTTP: the page and its assets (nothing addressed elsewhere), the live status
  with its alarm on the event stream, a tile listed and drawn on the map once written;
- in a real headless Chromium (the system's: ``chromium`` on PATH, or ``$SVSS_CHROMIUM``;
  ``.ci/run`` installs it where it is missing) driven by Playwright: every request the
  page makes goes to 127.0.0.1, it shows the status and the alarm, a tile written
  after it loaded appears on it (list, map, contacts) and opens; screenshots are saved
  under the test's tmp dir and copied to /tmp/view_screens/.

Every wait has a deadline; none is a fixed sleep.
"""

from __future__ import annotations

import json
import os
import queue
import shutil
import signal
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path
from urllib.parse import urlsplit

import pytest

from .feed import StatusFeed
from .synthetic import write_synthetic_tile

ROOT = Path(__file__).resolve().parents[2]
RUN = "line-view"
DEADLINE_S = 30.0          # a loaded 2-core machine; each wait ends as soon as it is met
SCREENS_COPY = Path("/tmp/view_screens")
CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable",
                  "chromium-headless-shell")


def until(pred, what: str, timeout_s: float = DEADLINE_S, every_s: float = 0.1):
    """``pred()``'s first true value, polled until the deadline (AssertionError naming
    ``what`` then)."""
    deadline = time.monotonic() + timeout_s
    while True:
        v = pred()
        if v:
            return v
        if time.monotonic() > deadline:
            raise AssertionError(f"no {what} within {timeout_s} s")
        time.sleep(every_s)


def get(url: str, timeout_s: float = 10.0) -> tuple[bytes, str]:
    with urllib.request.urlopen(url, timeout=timeout_s) as r:
        return r.read(), r.headers.get("Content-Type", "")


def get_json(url: str):
    return json.loads(get(url)[0])


class View:
    """``svss view`` as a process on a free loopback port."""

    def __init__(self, endpoint: str, tiles: Path, feed: StatusFeed | None = None):
        self.tiles, self.feed = tiles, feed
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "svss", "view", "--connect", endpoint, "--tiles",
             str(tiles), "--port", "0"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            cwd=ROOT, text=True)
        lines: queue.Queue = queue.Queue()
        threading.Thread(target=lambda: [lines.put(x) for x in self.proc.stdout],
                         daemon=True).start()
        self.err: list[str] = []
        threading.Thread(target=lambda: self.err.extend(self.proc.stderr),
                         daemon=True).start()
        try:
            self.url = lines.get(timeout=DEADLINE_S).strip()
        except queue.Empty:
            self.stop()
            raise AssertionError(f"svss view printed no URL within {DEADLINE_S} s: "
                                 f"{''.join(self.err)}") from None

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)


@pytest.fixture(scope="module")
def view(tmp_path_factory):
    out = tmp_path_factory.mktemp("worker_out")
    (out / RUN).mkdir()                  # the worker's run folder (svss worker --out OUT)
    feed = StatusFeed(RUN)
    v = View(feed.endpoint, out, feed)
    try:
        yield v
    finally:
        v.stop()
        feed.stop()
    # no traceback from the server's threads
    assert "Traceback" not in "".join(v.err), "".join(v.err)


def tile_listed(v: View, name: str):
    t = get_json(v.url + "api/tiles")
    return t if name in [x["name"] for x in t["tiles"]] else None


def test_page_assets_status_and_a_tile_over_http(view):
    u = urlsplit(view.url)
    assert u.hostname == "127.0.0.1", view.url          # loopback by default
    page, ctype = get(view.url)
    assert ctype.startswith("text/html")
    for asset in ("/static/view.js", "/static/view.css"):
        assert asset.encode() in page
    # everything the page loads is the server's own: no absolute address in any asset
    for name in ("", "static/view.js", "static/view.css"):
        body = get(view.url + name)[0].decode().replace("http://www.w3.org/2000/svg", "")
        assert "http://" not in body and "https://" not in body, name   # (a namespace)
    # the live status, with its alarm, on the event stream
    with urllib.request.urlopen(view.url + "events", timeout=DEADLINE_S) as r:
        assert r.headers["Content-Type"].startswith("text/event-stream")
        deadline = time.monotonic() + DEADLINE_S
        event, status = None, None
        while time.monotonic() < deadline:
            line = r.readline().decode().rstrip("\n")
            if line.startswith("event: "):
                event = line[7:]
            elif line.startswith("data: ") and event == "status":
                m = json.loads(line[6:])
                if m["status"] and m["status"]["alarms"]:
                    status = m
                    break
        assert status is not None, "no status with an alarm on /events"
    assert not status["quiet"]
    assert status["status"]["run_id"] == RUN
    assert status["status"]["alarms"][0]["name"] == "pings.stopped"
    assert status["status"]["alarms"][0]["severity"] == "critical"
    assert status["text"].startswith("ALARMS (1):")
    # a tile the worker writes is listed, with its run's contacts, and drawn on the map
    write_synthetic_tile(view.tiles / RUN, 1, RUN)
    t = until(lambda: tile_listed(view, "tile_0001"), "tile_0001 in /api/tiles")
    assert t["run"] == RUN
    assert any(c["tile"] == "tile_0001.h5" for c in t["contacts"])
    assert all(c["latitude_deg"] is not None for c in t["contacts"])
    png, ctype = get(view.url + t["map"].lstrip("/"))
    assert ctype == "image/png" and png.startswith(b"\x89PNG")
    regions = get_json(view.url + "api/map")["regions"]
    assert "tile_0001" in [r["name"] for r in regions]
    quick, ctype = get(view.url + t["tiles"][-1]["quicklook"].lstrip("/"))
    assert ctype == "image/png" and quick.startswith(b"\x89PNG")
    one = get_json(view.url + "api/tile/tile_0001")
    assert one["detections"]
    assert one["sediment"] == ("1767 +/- 20 m/s estimated from 1 buried response(s); "
                               "configured 1500 m/s disagrees")
    # nothing outside the run folder is served
    for bad in ("files/..%2Fx_mip.png", "files/tile_0001.h5", "static/..%2F__init__.py",
                "api/tile/nope"):
        with pytest.raises(urllib.error.HTTPError) as e:
            get(view.url + bad)
        assert e.value.code == 404
    # served on loopback: a request naming another host (DNS rebinding) is refused
    req = urllib.request.Request(view.url, headers={"Host": f"evil.example:{u.port}"})
    with pytest.raises(urllib.error.HTTPError) as e:
        urllib.request.urlopen(req, timeout=10)
    assert e.value.code == 403


def chromium_path() -> str | None:
    exe = os.environ.get("SVSS_CHROMIUM")
    if exe:
        return exe
    for name in CHROMIUM_NAMES:
        found = shutil.which(name)
        if found:
            return found
    return None


@pytest.mark.slow
def test_page_in_headless_chromium(view, tmp_path):
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright (the test "
                                   "extras) drives the browser")
    exe = chromium_path()
    if exe is None:
        pytest.skip(f"no Chromium: none of {', '.join(CHROMIUM_NAMES)} on PATH and no "
                    "$SVSS_CHROMIUM (.ci/run installs the system's package)")
    screens = tmp_path / "screens"
    screens.mkdir()
    requests, outside = [], []

    def route(r):
        host = urlsplit(r.request.url).hostname
        if host != "127.0.0.1":
            outside.append(r.request.url)
            return r.abort()
        return r.continue_()

    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=exe)
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 1000})
            page.route("**/*", route)
            page.on("request", lambda r: requests.append(r.url))
            errors = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            ms = DEADLINE_S * 1000

            def js_until(expr: str, what: str):
                # polled from here: the page's Content-Security-Policy forbids the eval
                # Playwright's wait_for_function needs
                until(lambda: page.evaluate(expr), what)

            page.goto(view.url)
            # the status and the alarm, first on the page
            page.wait_for_selector("#alarms [data-alarm='pings.stopped']", timeout=ms)
            assert "CRITICAL" in page.inner_text("#alarms")
            assert page.inner_text("#conn").startswith("live")
            page.wait_for_selector("#glance table", timeout=ms)
            glance = page.inner_text("#glance")
            assert RUN in glance and "recording" in glance and "(gps)" in glance
            assert "ALARMS (1):" in page.inner_text("#status-text")
            # live: the next status replaces this one (the daemon's time moves on)
            first = page.inner_text("#glance")
            until(lambda: page.inner_text("#glance") != first, "a status update")
            js_until("document.getElementById('map').complete && "
                     "document.getElementById('map').naturalWidth > 0", "the map drawn")
            page.screenshot(path=str(screens / "1_status_and_alarm.png"), full_page=True)
            # the worker writes a tile: it appears in the list, on the map, in the contacts
            write_synthetic_tile(view.tiles / RUN, 0, RUN)
            page.wait_for_selector("#tiles [data-tile='tile_0000'] img", timeout=ms)
            page.wait_for_selector("#map-regions polygon[data-tile='tile_0000']",
                                   timeout=ms)
            js_until("[...document.querySelectorAll('#contacts td')].some("
                     "td => td.textContent == 'tile_0000.h5')", "tile_0000's contacts")
            js_until("[...document.querySelectorAll('#map, #tiles img')].every("
                     "i => i.complete && i.naturalWidth > 0)", "the map and quicklooks")
            page.screenshot(path=str(screens / "2_tile_landed.png"), full_page=True)
            # a tile opened (clicked on the map): its MIPs and depth slices, its contacts
            page.click("#map-regions polygon[data-tile='tile_0000']")
            page.wait_for_selector("#tile-view:not([hidden])", timeout=ms)
            js_until("document.getElementById('tile-img').complete && "
                     "document.getElementById('tile-img').naturalWidth > 0",
                     "the tile's quicklook")
            assert "tile_0000" in page.inner_text("#tile-title")
            assert "tile_0000.h5" in page.inner_text("#tile-contacts")
            page.screenshot(path=str(screens / "3_tile_opened.png"))
            page.keyboard.press("Escape")
            # the stream goes quiet (a run over, a daemon stopped): the page says so, and
            # goes live again with the next status
            view.feed.paused.set()
            try:
                page.wait_for_selector("#conn.quiet", timeout=ms)
                assert "no status" in page.inner_text("#conn")
                page.screenshot(path=str(screens / "4_stream_quiet.png"))
            finally:
                view.feed.paused.clear()
            page.wait_for_selector("#conn.live", timeout=ms)
            assert not errors, errors
        finally:
            browser.close()
    assert requests
    assert not outside, f"requests leaving the machine: {outside}"
    assert {urlsplit(u).hostname for u in requests} == {"127.0.0.1"}, requests
    SCREENS_COPY.mkdir(parents=True, exist_ok=True)
    for f in screens.iterdir():
        shutil.copy(f, SCREENS_COPY / f.name)
