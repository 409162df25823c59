"""``svss view``: the operator's web page, served over HTTP on loopback.

Two feeds, each read by one thread into :class:`ViewState`:

- the acquisition daemon's status stream (:class:`svss_daq.status.StatusSubscriber`,
  the subscription ``svss status --follow`` uses: it waits for a daemon and survives
  runs starting and ending); the live poses make the track;
- the tile worker's output folder, polled: ``OUT/RUN_ID/tile_NNNN.h5`` and their
  quicklooks (or tiles directly in the folder, as ``svss process`` writes them). The run
  shown is the status's run when its folder exists, else the folder with the newest
  tile. A tile is read once it has its final name (the worker's commit point); the run's
  contacts are recomputed (:func:`svss_proc.products.run_products.run_contacts`) as
  tiles land.

The page (``static/``: HTML, CSS and a small script, no third-party code, nothing
fetched from elsewhere) listens to ``/events`` (Server-Sent Events: ``status`` and
``tiles`` messages) and shows the alarms first, the status, the survey map
(``/map.png``, drawn server-side with matplotlib: :mod:`.render`) and the tiles; a tile
opened shows the worker's quicklook of it (its MIPs and depth slices with the contacts
marked) and its contacts.

The HTTP server is the standard library's (:class:`http.server.ThreadingHTTPServer`):
one thread per connection, enough for the few browsers of a boat, nothing to install.
"""

from __future__ import annotations

import json
import logging
import mimetypes
import sys
import threading
import time
from collections import deque
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import numpy as np

from svss.summary import seabed_line
from svss_daq.endpoints import check_endpoint
from svss_daq.status import StatusSubscriber, format_status
from svss_proc.products.run_products import TileView, run_contacts, survey_origin
from svss_proc.run_folder import run_folder_name
from svss_proc.tiles import (QUICKLOOK_SUFFIX, TILE_SUFFIX, TileFileError,
                             finished_tile_paths, read_tile_views)

log = logging.getLogger(__name__)

#: seconds without a status message before the page says the stream is quiet
QUIET_S = 3.0
#: seconds between looks at the output folder
POLL_S = 0.5
#: live poses kept for the track
TRACK_POSES = 20000
#: the map is redrawn for a moved boat at most this often, s
MAP_TRACK_EVERY_S = 5.0
#: seconds between keep-alive comments on an idle event stream
KEEPALIVE_S = 10.0
STATIC = "static"


def http_address(address: str, port: int) -> tuple[str, int]:
    """(host, port) to bind, checked as the ZeroMQ endpoints are
    (:func:`~svss_daq.endpoints.check_endpoint`: a malformed address or port is an
    error naming it; an address that is not loopback is logged as a warning)."""
    host = f"[{address}]" if ":" in address and not address.startswith("[") else address
    check_endpoint(f"tcp://{host}:{port or '*'}", bind=True)   # 0: a free port
    return address.strip("[]"), int(port)


class ViewState:
    """What the page shows, shared by the feeding threads and the HTTP handlers; every
    change bumps :attr:`version` and wakes the event streams."""

    def __init__(self, endpoint: str | None, tiles_dir: Path | None):
        self.endpoint = endpoint
        self.tiles_dir = tiles_dir
        self.cond = threading.Condition()
        self.version = 0
        self.status: dict | None = None
        self.status_at = 0.0              # time.monotonic() of the last status
        self.status_seq = 0               # bumped by each status, and once when quiet
        self._quiet_said = False
        self.track: deque = deque(maxlen=TRACK_POSES)
        self.track_run: str | None = None
        self.track_version = 0            # bumped at most every MAP_TRACK_EVERY_S
        self._track_bumped = 0.0
        self.run_folder: Path | None = None
        self.views: dict[Path, tuple[float, TileView]] = {}
        self.contacts: list[dict] = []
        self.contacts_note = ""
        self.tiles_seq = 0
        self._render_lock = threading.Lock()
        self._map_cache: tuple[tuple, bytes, list] | None = None

    # ---------------------------------------------------------------- feeds

    def _changed(self) -> None:
        self.version += 1
        self.cond.notify_all()

    def on_status(self, s: dict) -> None:
        pose = (s.get("navigation") or {}).get("pose") or {}
        with self.cond:
            self.status, self.status_at = s, time.monotonic()
            self.status_seq += 1
            self._quiet_said = False
            run = s.get("run_id")
            if run != self.track_run:
                self.track.clear()
                self.track_run = run
            n, e = pose.get("north_m"), pose.get("east_m")
            if isinstance(n, (int, float)) and isinstance(e, (int, float)):
                if not self.track or self.track[-1] != (n, e):
                    self.track.append((float(n), float(e)))
                    now = time.monotonic()
                    if now - self._track_bumped >= MAP_TRACK_EVERY_S:
                        self.track_version += 1
                        self._track_bumped = now
            self._changed()

    def set_tiles(self, folder: Path | None, views: dict, contacts: list[dict],
                  note: str) -> None:
        with self.cond:
            self.run_folder, self.views = folder, views
            self.contacts, self.contacts_note = contacts, note
            self.tiles_seq += 1
            self._changed()

    # ---------------------------------------------------------------- snapshots

    def status_message(self) -> dict:
        """The status for the page: the last message, its age, whether the stream is
        quiet, and the text ``svss status`` prints."""
        with self.cond:
            s, at = self.status, self.status_at
        age = None if s is None else round(time.monotonic() - at, 1)
        return {"endpoint": self.endpoint, "status": s, "received_age_s": age,
                "quiet": s is None or age > QUIET_S,
                "text": None if s is None else format_status(s)}

    def origin(self) -> tuple[float, float, float] | None:
        """The survey origin: from a tile's geodetic reference, else from the live
        pose's latitude/longitude and north/east."""
        with self.cond:
            views = [v for _, v in self.views.values()]
            pose = ((self.status or {}).get("navigation") or {}).get("pose") or {}
        for v in views:
            ref = v.data["attrs"].get("geodetic_ref")
            if ref is not None and np.all(np.isfinite(ref)):
                return survey_origin(tuple(ref))
        keys = ("latitude_deg", "longitude_deg", "north_m", "east_m", "down_m")
        if all(isinstance(pose.get(k), (int, float)) for k in keys):
            return survey_origin(tuple(float(pose[k]) for k in keys))
        return None

    def tiles_message(self) -> dict:
        with self.cond:
            folder, views = self.run_folder, dict(self.views)
            contacts, note = list(self.contacts), self.contacts_note
            seq, tver = self.tiles_seq, self.track_version
        tiles = []
        for path, (mtime, v) in sorted(views.items()):
            det = v.data["detections"]
            png = path.with_name(path.stem + QUICKLOOK_SUFFIX)
            tiles.append({"name": path.stem, "mtime": mtime,
                          "pings": int(v.data["ping_sequence"].size),
                          "imaging_method": v.data.get("imaging_method"),
                          "detections": int(len(det)),
                          "quicklook": f"/files/{path.stem}{QUICKLOOK_SUFFIX}?m={mtime}"
                          if png.is_file() else None})
        return {"folder": None if folder is None else str(folder),
                "run": None if folder is None else folder.name, "tiles": tiles,
                "contacts": contacts, "contacts_note": note,
                "map": f"/map.png?v={seq}.{tver}"}

    def map_png(self) -> tuple[bytes, list]:
        from .render import survey_map_png
        with self.cond:
            key = (self.tiles_seq, self.track_version)
            views = [v for _, (_, v) in sorted(self.views.items())]
            contacts = list(self.contacts)
            track = np.array(self.track, dtype=float).reshape(-1, 2)
            pose = ((self.status or {}).get("navigation") or {}).get("pose")
            folder = self.run_folder
        with self._render_lock:
            if self._map_cache is not None and self._map_cache[0] == key:
                return self._map_cache[1], self._map_cache[2]
            title = (f"run {folder.name}: " if folder is not None else "") + \
                f"{len(views)} tile(s), {len(contacts)} contact(s)"
            png, regions = survey_map_png(views, contacts, track, pose, self.origin(),
                                          title)
            self._map_cache = (key, png, regions)
            return png, regions


# ------------------------------------------------------------------------ feeders


def follow_status(state: ViewState, stop: threading.Event, curve=None) -> None:
    """Feed ``state`` from the status stream until ``stop``."""
    with StatusSubscriber(state.endpoint, curve=curve) as sub:
        while not stop.is_set():
            s = sub.next(0.5)
            if s is not None:
                state.on_status(s)
                continue
            with state.cond:             # the page learns the stream went quiet
                if state.status is not None and not state._quiet_said \
                        and time.monotonic() - state.status_at > QUIET_S:
                    state._quiet_said = True
                    state.status_seq += 1
                    state._changed()


def _run_folder(root: Path, run_id: str | None) -> Path | None:
    """The folder whose tiles are shown: the status's run, else the folder holding the
    newest tile (``root`` itself for tiles written directly into it)."""
    if run_id:
        d = root / run_folder_name(run_id)
        if d.is_dir():
            return d
    best, best_t = None, -1.0
    for d in [root, *(p for p in root.iterdir() if p.is_dir())]:
        for t in finished_tile_paths(d):
            try:
                mt = t.stat().st_mtime
            except OSError:
                continue
            if mt > best_t:
                best, best_t = d, mt
    return best


def watch_tiles(state: ViewState, stop: threading.Event) -> None:
    """Feed ``state`` from the output folder until ``stop``: each finished tile read
    once (again when rewritten), the contacts recomputed when the tiles change."""
    root = state.tiles_dir
    views: dict[Path, tuple[float, TileView]] = {}
    folder = None
    bad: dict[Path, float] = {}
    while not stop.is_set():
        try:
            with state.cond:
                run_id = (state.status or {}).get("run_id")
            now_folder = _run_folder(root, run_id) if root.is_dir() else None
            changed = now_folder != folder
            if changed:
                folder, views = now_folder, {}
            seen = {}
            for p in (finished_tile_paths(folder) if folder is not None else []):
                try:
                    seen[p] = p.stat().st_mtime
                except OSError:
                    continue
            for p in list(views):
                if p not in seen:
                    del views[p]
                    changed = True
            for p, mt in seen.items():
                if (p in views and views[p][0] == mt) or bad.get(p) == mt:
                    continue
                try:
                    views[p] = (mt, TileView(p, read_tile_views(p)))
                    changed = True
                except TileFileError as exc:
                    log.warning("%s", exc)
                    bad[p] = mt
            if changed:
                contacts, note = [], ""
                if views:
                    try:
                        contacts, _ = run_contacts([v for _, (_, v) in sorted(views.items())])
                    except TileFileError as exc:       # tiles without products
                        note = str(exc)
                    except Exception as exc:       # the tiles are shown all the same
                        log.exception("%s: the run's contacts failed", folder)
                        note = f"the run's contacts could not be computed: {exc}"
                contacts = [{k: (None if isinstance(v, float) and not np.isfinite(v)
                                 else v) for k, v in c.items()} for c in contacts]
                state.set_tiles(folder, dict(views), contacts, note)
        except OSError as exc:
            log.warning("%s: %s", root, exc)
        except Exception:                  # never leave the page without its tiles feed
            log.exception("%s: reading the tiles failed; trying again", root)
        stop.wait(POLL_S)


# ------------------------------------------------------------------------ HTTP


class Handler(BaseHTTPRequestHandler):
    server_version = "svss-view"
    state: ViewState       # set on the subclass the server makes

    def log_message(self, fmt, *args) -> None:      # into logging, not stderr
        log.debug("%s %s", self.address_string(), fmt % args)

    def _send(self, body: bytes, ctype: str, status=HTTPStatus.OK, cache: bool = False):
        self.send_response(status)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "max-age=3600" if cache else "no-store")
        # the page may load nothing from elsewhere (the boat has no internet)
        self.send_header("Content-Security-Policy", "default-src 'self'; img-src 'self' "
                         "data:; connect-src 'self'")
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    def _json(self, obj) -> None:
        self._send(json.dumps(obj).encode(), "application/json")

    def _not_found(self) -> None:
        self._send(b"not found\n", "text/plain", HTTPStatus.NOT_FOUND)

    def do_HEAD(self) -> None:
        self.do_GET()

    def do_GET(self) -> None:
        if self.server.loopback and not _loopback_host(self.headers.get("Host", "")):
            # served on loopback, asked for under another name: a web page elsewhere
            # rebinding its name to this machine (DNS rebinding) is refused
            return self._send(b"forbidden host\n", "text/plain", HTTPStatus.FORBIDDEN)
        url = urlsplit(self.path)
        path = url.path
        if path in ("/", "/index.html"):
            return self._static("index.html")
        if path.startswith("/static/"):
            return self._static(path.removeprefix("/static/"))
        if path == "/api/status":
            return self._json(self.state.status_message())
        if path == "/api/tiles":
            return self._json(self.state.tiles_message())
        if path == "/api/map":
            return self._json({"regions": self.state.map_png()[1]})
        if path == "/map.png":
            return self._send(self.state.map_png()[0], "image/png")
        if path.startswith("/files/"):
            return self._file(path.removeprefix("/files/"))
        if path.startswith("/api/tile/"):
            return self._tile(path.removeprefix("/api/tile/"))
        if path == "/events":
            return self._events(parse_qs(url.query))
        return self._not_found()

    def _static(self, name: str) -> None:
        if "/" in name or name.startswith("."):
            return self._not_found()
        res = resources.files(__package__) / STATIC / name
        if not res.is_file():
            return self._not_found()
        ctype = mimetypes.guess_type(name)[0] or "application/octet-stream"
        if ctype.startswith("text/") or ctype.endswith("javascript"):
            ctype += "; charset=utf-8"
        self._send(res.read_bytes(), ctype)

    def _tile_path(self, name: str) -> Path | None:
        """A file of the shown run's folder by its plain name, or None."""
        folder = self.state.run_folder
        if folder is None or "/" in name or name.startswith(".") or "\\" in name:
            return None
        p = folder / name
        return p if p.is_file() else None

    def _file(self, name: str) -> None:
        p = self._tile_path(name)
        if p is None or not name.endswith(QUICKLOOK_SUFFIX):
            return self._not_found()
        self._send(p.read_bytes(), "image/png", cache=True)

    def _tile(self, stem: str) -> None:
        with self.state.cond:
            hit = [(p, v) for p, (_, v) in self.state.views.items() if p.stem == stem]
            contacts = [c for c in self.state.contacts
                        if c.get("tile") == stem + TILE_SUFFIX]
        if not hit:
            return self._not_found()
        p, v = hit[0]
        d, a = v.data, v.data["attrs"]
        det = [{k: float(row[k]) for k in ("along_m", "cross_m", "depth_m", "excess_db")}
               for row in d["detections"]]
        png = p.with_name(p.stem + QUICKLOOK_SUFFIX)
        self._json({"name": p.stem, "pings": int(d["ping_sequence"].size),
                    "poses": d.get("poses"), "run_id": _text(a.get("run_id")),
                    "imaging_method": d.get("imaging_method"),
                    "sediment": seabed_line(d["seabed"]) if d.get("seabed") else None,
                    "created_utc": _text(a.get("creation_time_utc")),
                    "quicklook": (f"/files/{png.name}?m={png.stat().st_mtime}"
                                  if png.is_file() else None),
                    "detections": det, "contacts": contacts})

    def _events(self, query) -> None:
        """Server-Sent Events: ``status`` whenever a status arrives (or the stream goes
        quiet), ``tiles`` whenever the tiles change (the map's new address with them),
        ``map`` when the boat has moved (at most every MAP_TRACK_EVERY_S); a comment
        every KEEPALIVE_S."""
        self.send_response(HTTPStatus.OK)
        self.send_header("Content-Type", "text/event-stream")
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        st = self.state
        seen_status, seen_tiles, seen_track = -1, -1, -1
        try:
            while not self.server.stopping.is_set():
                with st.cond:
                    st.cond.wait_for(lambda: st.status_seq != seen_status
                                     or st.tiles_seq != seen_tiles
                                     or st.track_version != seen_track
                                     or self.server.stopping.is_set(),
                                     timeout=KEEPALIVE_S)
                    status_seq, tiles_seq = st.status_seq, st.tiles_seq
                    track = st.track_version
                out = []
                if status_seq != seen_status:
                    out.append(("status", st.status_message()))
                if tiles_seq != seen_tiles:
                    out.append(("tiles", st.tiles_message()))
                elif track != seen_track:           # the boat moved: the map redrawn
                    out.append(("map", {"map": st.tiles_message()["map"]}))
                seen_status, seen_tiles, seen_track = status_seq, tiles_seq, track
                chunk = "".join(f"event: {k}\ndata: {json.dumps(v)}\n\n" for k, v in out)
                self.wfile.write((chunk or ": keep-alive\n\n").encode())
                self.wfile.flush()
                if not out:
                    continue
                # at most a few updates a second per browser
                self.server.stopping.wait(0.2)
        except (BrokenPipeError, ConnectionResetError):
            pass


def _loopback_host(host: str) -> bool:
    """Whether an HTTP Host header names this machine's loopback."""
    name = urlsplit(f"//{host}").hostname or ""
    return name in ("localhost", "127.0.0.1", "::1") or name.startswith("127.")


def _text(v):
    return v.decode(errors="replace") if isinstance(v, bytes) else (
        None if v is None else str(v))


class ViewServer(ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = True

    def handle_error(self, request, client_address) -> None:
        exc = sys.exc_info()[1]
        if isinstance(exc, (BrokenPipeError, ConnectionResetError)):
            # a browser that left, or dropped an image it no longer wants (a newer map)
            log.debug("%s went away: %s", client_address, exc)
            return
        log.exception("svss view: a request from %s failed", client_address[0])


def serve(endpoint: str | None, tiles_dir: Path | None, address: str, port: int, *,
          curve=None, ready=None) -> None:
    """Serve the page until KeyboardInterrupt (SIGINT/SIGTERM). ``ready(url)`` is called
    once the server listens."""
    host, port = http_address(address, port)
    if endpoint is not None:
        check_endpoint(endpoint, bind=False)       # an error now, not in a thread
    state = ViewState(endpoint, tiles_dir)
    handler = type("BoundHandler", (Handler,), {"state": state})
    try:
        httpd = ViewServer((host, port), handler)
    except OSError as exc:
        raise OSError(f"svss view: cannot serve on {host}:{port}: {exc.strerror or exc}"
                      ) from None
    httpd.stopping = threading.Event()
    httpd.loopback = _loopback_host(host if ":" not in host else f"[{host}]")
    threads = []
    if endpoint is not None:
        threads.append(threading.Thread(target=follow_status, name="view-status",
                                        args=(state, httpd.stopping, curve), daemon=True))
    if tiles_dir is not None:
        threads.append(threading.Thread(target=watch_tiles, name="view-tiles",
                                        args=(state, httpd.stopping), daemon=True))
    for t in threads:
        t.start()
    h, p = httpd.server_address[:2]
    url = f"http://{f'[{h}]' if ':' in h else h}:{p}/"
    log.info("svss view: serving %s (status %s, tiles %s)", url, endpoint, tiles_dir)
    if ready is not None:
        ready(url)
    try:
        httpd.serve_forever(poll_interval=0.2)
    finally:
        httpd.stopping.set()
        with state.cond:
            state.cond.notify_all()
        httpd.server_close()
