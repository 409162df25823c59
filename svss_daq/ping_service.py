"""The catch-up ping service: recorded pings served by sequence number, so that a tile
worker that lost pings on the best-effort stream (:mod:`.publisher`) gets every one.

Recording happens before publishing, so when ping m is published every ping < m that
will ever exist is already recorded: the recording answers definitively whether a
sequence exists. (A recording on disk answers for what is flushed; the service says so,
``pending``, for sequences past its last flushed ping of a run still being recorded.)

Protocol (docs/catchup.md): a ROUTER socket (:class:`PingService`) answers JSON requests,
never pickle, from DEALER clients (:class:`PingFetcher`):

- ``{"schema": "svss.fetch", "version": 1, "run_id": R, "first": a, "last": b}``
  (optionally ``"max_pings": m``, the most pings the client takes in one reply): every
  recorded ping of run R in [a, b], each a message framed exactly like the ping stream
  (:func:`svss_daq.messages.encode_ping`), then one single-frame JSON
  ``{"schema": "svss.fetched", "version": 1, "run_id", "first", "last", "found": n,
  "missing": [[a0, b0], ...], "next": s or null, "pending": bool}``. ``missing`` lists the
  ranges of sequences definitively absent (never recorded), up to the reply's end; a
  reply holds at most ``max_pings_per_reply`` (and ``m``) pings and ``next`` says where
  to continue (null: [a, b] is answered); ``pending`` says ``next`` is past the run's
  last recorded ping and the run is still being recorded (ask again later).
- ``{"schema": "svss.runs", "version": 1}``: ``{"schema": "svss.runs", "version": 1,
  "runs": [RunInfo as an object, ...]}``, oldest first.
- anything else: ``{"schema": "svss.error", "version": 1, "error": "..."}``, counted in
  :attr:`PingService.errors`; the serving thread never stops on a request. A fetch
  while ``max_clients`` replies are being sent is answered ``{"schema": "svss.error",
  "version": 1, "busy": true, "error": "..."}``: ask again.

The service's memory and time per client are bounded and a client that does not read
blocks nothing (:class:`PingService`); the client keeps ``missing`` as ranges. The
stores a service serves from (raw-run files, a replay, a daemon's recording) are in
:mod:`svss_daq.catchup_stores`.
"""

from __future__ import annotations

import collections
import dataclasses
import json
import logging
import re
import threading
import time
from dataclasses import asdict, dataclass
from typing import Iterable, Iterator, Protocol

import zmq

from . import messages
from .endpoints import check_endpoint
from .ping import Ping

log = logging.getLogger(__name__)

VERSION = 1
# defaults of daq.toml's [service] for a service or client made without a configuration
#: pings in one reply when the service is not told otherwise
MAX_PINGS_PER_REPLY = 64
#: clients served at once (a reply being sent), and stalled clients remembered
MAX_CLIENTS = 8
#: messages ZeroMQ queues per client, each way (a ping is one message)
CLIENT_QUEUE = 16
#: a reply that could send nothing to its client for this long is abandoned, s
STALL_S = 10.0
#: with every reply slot taken, a reply that could send nothing for this long (or
#: stall_s, if shorter) gives its slot to a client that asks: a client that does not
#: read locks no one out for stall_s, s
PREEMPT_S = 1.0
#: a client's first pause before asking a busy service again (doubling to 1 s), s
POLL_BUSY_S = 0.05
#: workers whose progress (svss.progress) the service keeps at most
MAX_WORKERS = 16
#: a worker whose progress has not come for this long is forgotten, s
WORKER_SILENCE_S = 30.0
#: how often a worker says where it is (a fraction of the silence above), s
PROGRESS_INTERVAL_S = 1.0
_CLIENT_ID = re.compile(r"[A-Za-z0-9._:-]{1,64}")
# protocol limits (docs/catchup.md)
_MAX_REQUEST_BYTES = 4096
_MAX_RUN_FILES = 10000           # a run's raw-run files in a runs reply, at most
_MAX_FRAME_BYTES = 65536     # a client's larger frame: ZeroMQ drops its connection
_MAX_SPAN = 10**9            # sequences one fetch may ask about
_INT = (0, 2**63 - 1)


def _log_count(n: int, level: int, msg: str, *args) -> None:
    """Log the ``n``-th occurrence of something counted only when ``n`` is 1, 10, 100,
    ...: a flood is counted in full, never logged in full."""
    if n > 0 and str(n).rstrip("0") == "1":
        log.log(level, msg + " (%d in all%s)", *args, n,
                "" if n == 1 else "; logged at every power of 10")

@dataclass(frozen=True)
class RunInfo:
    """A recorded run: its id, the first and last sequence numbers recorded so far, how
    many pings, whether the run has ended (no more pings will be recorded) and its
    raw-run files as the service's machine names them (a worker on that machine falls
    back to them when the service is gone; empty where not said)."""
    run_id: str
    first: int
    last: int
    n_pings: int
    ended: bool
    files: tuple[str, ...] = ()

    def to_dict(self) -> dict:
        d = asdict(self)
        d["files"] = list(self.files)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> RunInfo:
        if not isinstance(d, dict):
            raise ValueError(f"run: expected a JSON object, got {type(d).__name__}")
        try:
            info = cls(d["run_id"], d["first"], d["last"], d["n_pings"], d["ended"])
        except KeyError as exc:
            raise ValueError(f"run: field {exc.args[0]!r} missing") from None
        if not (isinstance(info.run_id, str) and isinstance(info.ended, bool)
                and all(type(v) is int for v in (info.first, info.last, info.n_pings))):
            raise ValueError(f"run: mistyped fields in {str(d)[:200]}")
        files = d.get("files", [])
        if not (isinstance(files, list) and len(files) <= _MAX_RUN_FILES
                and all(isinstance(f, str) and 0 < len(f) <= 4096 for f in files)):
            raise ValueError(f"run: field 'files' expected a list of at most "
                             f"{_MAX_RUN_FILES} paths, got {str(files)[:200]}")
        return dataclasses.replace(info, files=tuple(files))


class PingStore(Protocol):
    """Where a :class:`PingService` finds recorded pings."""

    def runs(self) -> list[RunInfo]:
        """The runs recorded so far, oldest first."""

    def sequences(self, run_id: str, first: int, last: int) -> list[int]:
        """The recorded sequences of ``run_id`` within [first, last], ascending
        (KeyError for an unknown run)."""

    def read(self, run_id: str, sequence: int) -> Ping | None:
        """The recorded ping, or None when it was never recorded."""


# --------------------------------------------------------------------------- service


def _absent(first: int, last: int, present: list[int]) -> list[list[int]]:
    """Ranges of [first, last] not in ``present`` (ascending, within [first, last])."""
    out, at = [], first
    for q in present:
        if q > at:
            out.append([at, q - 1])
        at = q + 1
    if at <= last:
        out.append([at, last])
    return out


class RequestError(ValueError):
    """A request the service cannot answer."""


def _int_field(req: dict, name: str) -> int:
    v = req.get(name)
    if type(v) is not int or not _INT[0] <= v <= _INT[1]:
        raise RequestError(f"field '{name}' expected an integer in 0..2**63-1, got "
                           f"{messages._show(v)}")
    return v


@dataclass
class _Progress:
    """A worker's latest progress message: its run, the first sequence it lacks,
    whether it needs nothing more, when it came (monotonic), and what else it said of
    itself (:data:`PROGRESS_EXTRAS`)."""
    run_id: str
    next: int
    done: bool
    at: float
    extras: dict = dataclasses.field(default_factory=dict)


#: optional fields of a worker's progress message, each a number >= 0 or null: its open
#: tiles, the most its memory bound (limits.memory_gib) allows, and how long ago it
#: last reached that bound (closed a tile early or refused a ping for it); and the
#: imaging method it runs (one of :data:`IMAGING_METHODS`)
PROGRESS_EXTRAS = ("open_tiles", "max_open_tiles", "memory_bound_age_s", "imaging_method")
#: the words a worker may give for its imaging method (docs/imaging.md)
IMAGING_METHODS = ("exact", "factorised")


@dataclass
class _Reply:
    """A fetch reply being sent to one client: its messages (made as they are sent),
    the one that found the client's queue full, and when a message last went out."""
    ident: bytes
    messages: Iterator[list]
    since: float
    head: list | None = None


class PingService:
    """Serves a :class:`PingStore` on ``endpoint`` (a ROUTER socket bound now, checked by
    :func:`~svss_daq.endpoints.check_endpoint`; ``tcp://127.0.0.1:*`` picks a free port,
    :attr:`endpoint` says which) from a thread, until :meth:`close`. ``curve``: a
    :class:`~svss_daq.config.CurveConfig` (None or disabled: plain). Malformed
    requests are answered with ``svss.error``, logged and counted (:attr:`errors`).

    Nothing a client does blocks the serving thread or grows the service without bound
    (docs/catchup.md, "Catch-up service limits"): every send is non-blocking; ZeroMQ
    queues at most ``client_queue`` messages to each client (each way); a fetch reply
    is sent as the client's queue takes it, at most ``max_clients`` replies at once
    (beyond: ``svss.error`` with ``"busy": true``, counted in :attr:`busy`, unless the
    reply that has sent nothing longest has done so for ``preempt_s``
    (:data:`PREEMPT_S`, or ``stall_s`` if shorter): it gives its slot up); a reply that could send nothing for ``stall_s`` is abandoned
    (:attr:`stalled`) and that
    client's later requests are refused unanswered (:attr:`refused`, the last
    ``max_clients`` such clients remembered); :attr:`replies` counts replies sent
    whole (what keeps a daemon lingering)."""

    def __init__(self, endpoint: str, store: PingStore, *, curve=None,
                 max_pings_per_reply: int = MAX_PINGS_PER_REPLY,
                 max_clients: int = MAX_CLIENTS, client_queue: int = CLIENT_QUEUE,
                 stall_s: float = STALL_S, max_workers: int = MAX_WORKERS,
                 worker_silence_s: float = WORKER_SILENCE_S,
                 preempt_s: float = PREEMPT_S, ctx: zmq.Context | None = None):
        check_endpoint(endpoint, bind=True)
        if type(max_workers) is not int or max_workers < 1 or not worker_silence_s > 0:
            raise ValueError(f"max_workers {max_workers!r}, worker_silence_s "
                             f"{worker_silence_s!r}: expected an integer >= 1 and seconds "
                             "> 0")
        self.max_workers, self.worker_silence_s = max_workers, float(worker_silence_s)
        # worker id -> its latest progress (svss.progress); at most max_workers
        self._workers: collections.OrderedDict[str, _Progress] = collections.OrderedDict()
        self._workers_lock = threading.Lock()
        self.progress = 0           # progress messages taken
        self.progress_refused = 0   # ... refused (malformed, or max_workers tracked)
        for name, v in (("max_pings_per_reply", max_pings_per_reply),
                        ("max_clients", max_clients), ("client_queue", client_queue)):
            if type(v) is not int or v < 1:
                raise ValueError(f"{name}: expected an integer >= 1, got {v!r}")
        if not stall_s > 0 or not preempt_s > 0:
            raise ValueError(f"stall_s {stall_s!r}, preempt_s {preempt_s!r}: expected "
                             "seconds > 0")
        self.preempt_s = min(float(preempt_s), float(stall_s))
        self.store = store
        self.max_pings = max_pings_per_reply
        self.max_clients = max_clients
        self.stall_s = float(stall_s)
        self.ctx = ctx or zmq.Context.instance()
        self.sock = self.ctx.socket(zmq.ROUTER)
        try:
            from .security import secure_server
            secure_server(self.sock, curve)
            self.sock.setsockopt(zmq.ROUTER_MANDATORY, 1)   # a full queue says so (EAGAIN)
            self.sock.setsockopt(zmq.SNDHWM, client_queue)
            self.sock.setsockopt(zmq.RCVHWM, client_queue)
            self.sock.setsockopt(zmq.MAXMSGSIZE, _MAX_FRAME_BYTES)
            self.sock.setsockopt(zmq.LINGER, 0)
            self.sock.bind(endpoint)
        except zmq.ZMQError as exc:
            self.sock.close(linger=0)
            raise OSError(f"cannot bind the catch-up service to {endpoint}: {exc}") from None
        except BaseException:
            self.sock.close(linger=0)
            raise
        self.endpoint = self.sock.getsockopt_string(zmq.LAST_ENDPOINT)
        self.requests = 0
        self.replies = 0            # replies sent whole
        self.errors = 0
        self.pings_served = 0
        self.busy = 0               # fetches refused: max_clients replies being sent
        self.stalled = 0            # replies abandoned: nothing sent for stall_s
        self.refused = 0            # requests of a stalled client, or during its reply
        self.dropped = 0            # short replies (errors, runs) to a full client queue
        self.gone = 0               # replies to clients that disconnected
        self._replies: dict[bytes, _Reply] = {}
        self._stalled: collections.OrderedDict[bytes, None] = collections.OrderedDict()
        self._refusals: collections.Counter = collections.Counter()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="ping-service", daemon=True)
        self._thread.start()
        log.info("catch-up service on %s (at most %d pings per reply, %d clients at once, "
                 "%d messages queued per client)", self.endpoint, self.max_pings,
                 self.max_clients, client_queue)

    @property
    def clients(self) -> int:
        """Clients a reply is being sent to."""
        return len(self._replies)

    def _serve(self) -> None:
        wait_ms = 100
        try:
            while not self._stop.is_set():
                busy = False
                if self.sock.poll(wait_ms, zmq.POLLIN):
                    try:
                        frames = self.sock.recv_multipart(zmq.NOBLOCK)
                    except zmq.Again:
                        frames = None
                    if frames:
                        busy = True
                        try:
                            self._handle(frames[0], frames[1:])
                        except Exception:                 # never lose the service
                            self.errors += 1
                            log.exception("catch-up service: request failed")
                            self._send_short(frames[0], {
                                "schema": "svss.error", "version": VERSION,
                                "error": "internal error (logged)"})
                busy |= self._send_replies()
                # while replies wait for room in their clients' queues, look again soon
                # (sooner after something was sent)
                wait_ms = (0 if busy else min(max(2 * wait_ms, 1), 50) if self._replies
                           else 100)
        finally:
            self.sock.close(linger=0)

    # -- sending ---------------------------------------------------------------------

    def _send_short(self, ident: bytes, body: dict) -> bool:
        """One JSON message, never waiting: dropped (counted) when the client's queue is
        full (the client is then taken as stalled) or the client is gone."""
        try:
            self.sock.send_multipart([ident, json.dumps(body).encode()], zmq.NOBLOCK)
            return True
        except zmq.ZMQError as exc:
            self.dropped += 1
            _log_count(self.dropped, logging.WARNING, "catch-up service: a reply was "
                       "dropped: the client's queue is full or it is gone (%s)", exc)
            if isinstance(exc, zmq.Again):
                self._remember_stalled(ident)
            return False

    def _send_replies(self) -> bool:
        """Send what each reply's client queue takes now, one client after the other;
        abandon stalled replies. Whether anything was sent."""
        sent_any = False
        now = time.monotonic()
        for ident, rep in list(self._replies.items()):
            try:
                while True:
                    if rep.head is None:
                        rep.head = next(rep.messages, None)
                        if rep.head is None:             # the closing JSON went out
                            del self._replies[ident]
                            self.replies += 1
                            break
                    self.sock.send_multipart([ident, *rep.head], zmq.NOBLOCK, copy=False)
                    if len(rep.head) > 1:
                        self.pings_served += 1
                    rep.head, rep.since, sent_any = None, now, True
            except zmq.Again:                            # the client's queue is full
                if now - rep.since > self.stall_s:
                    self._abandon(ident, f"nothing could be sent to it for "
                                  f"{now - rep.since:.1f} s (it does not read)")
            except zmq.ZMQError as exc:                  # the client disconnected
                del self._replies[ident]
                self.gone += 1
                _log_count(self.gone, logging.INFO, "catch-up service: a client left "
                           "during its reply (%s)", exc)
            except Exception:                            # reading the store failed
                del self._replies[ident]
                self.errors += 1
                log.exception("catch-up service: a reply failed part-way")
                self._send_short(ident, {"schema": "svss.error", "version": VERSION,
                                         "error": "internal error (logged)"})
        return sent_any

    def _abandon(self, ident: bytes, why: str) -> None:
        del self._replies[ident]
        self.stalled += 1
        self._remember_stalled(ident)
        _log_count(self.stalled, logging.WARNING, "catch-up service: reply abandoned, "
                   "%s; that client's requests are refused from now on", why)

    def _remember_stalled(self, ident: bytes) -> None:
        self._stalled[ident] = None
        while len(self._stalled) > self.max_clients:
            self._stalled.popitem(last=False)

    def _error(self, ident: bytes, msg: str) -> None:
        self.errors += 1
        log.warning("catch-up service: refused a request: %s", msg)
        self._send_short(ident, {"schema": "svss.error", "version": VERSION, "error": msg})

    # -- requests --------------------------------------------------------------------

    def _handle(self, ident: bytes, body: list) -> None:
        self.requests += 1
        if ident in self._stalled or ident in self._replies:
            why = ("its client stalled a reply" if ident in self._stalled
                   else "a reply to its client is still being sent")
            self.refused += 1
            self._refusals[why] += 1
            _log_count(self._refusals[why], logging.WARNING, "catch-up service: request "
                       "refused unanswered: %s", why)
            return
        if len(body) != 1:
            return self._error(ident, f"request has {len(body)} frames; expected one JSON "
                               "frame")
        raw = body[0]
        if len(raw) > _MAX_REQUEST_BYTES:
            return self._error(ident, f"request of {len(raw)} bytes; expected at most "
                               f"{_MAX_REQUEST_BYTES}")
        try:
            req = json.loads(raw.decode())
        except (UnicodeDecodeError, ValueError, RecursionError) as exc:
            return self._error(ident, f"request is not UTF-8 JSON ({type(exc).__name__})")
        if not isinstance(req, dict):
            return self._error(ident, f"request must be a JSON object, got "
                               f"{type(req).__name__}")
        schema = req.get("schema")
        version = req.get("version", VERSION)
        if not (type(version) is int and version == VERSION):
            return self._error(ident, f"field 'version' is {messages._show(version)}; this "
                               f"service speaks version {VERSION}")
        try:
            if schema == "svss.runs":
                runs = self.store.runs()
                if self._send_short(ident, {"schema": "svss.runs", "version": VERSION,
                                            "runs": [r.to_dict() for r in runs],
                                            "progress": True}):
                    self.replies += 1
                return
            if schema == "svss.fetch":
                return self._fetch(ident, req)
            if schema == "svss.progress":
                return self._progress(req)
        except RequestError as exc:
            return self._error(ident, str(exc))
        return self._error(ident, f"field 'schema' is {messages._show(schema)}; expected "
                           "'svss.fetch' or 'svss.runs' (or a worker's 'svss.progress')")

    def _progress(self, req: dict) -> None:
        """A worker says where it is in a run (never answered): ``client`` (its id),
        ``run_id``, ``next`` (the first sequence it still lacks) and ``done`` (it needs
        nothing more of that run). Kept for at most ``max_workers`` workers; one not
        heard from for ``worker_silence_s`` is silent (still kept: :meth:`workers`), and
        the longest-silent one makes room for a new worker; a new worker beyond them
        with none silent, or a malformed message, is refused (counted, logged at every
        power of 10)."""
        client, run_id, done = req.get("client"), req.get("run_id"), req.get("done")
        try:
            nxt = _int_field(req, "next")
            if not (isinstance(client, str) and _CLIENT_ID.fullmatch(client)
                    and isinstance(run_id, str) and isinstance(done, bool)):
                raise RequestError("expected 'client' (1 to 64 of A-Z a-z 0-9 . _ : -), "
                                   "'run_id' (a string) and 'done' (true or false)")
            extras = {k: req[k] for k in PROGRESS_EXTRAS if k in req}
            method = extras.get("imaging_method")
            if method is not None and method not in IMAGING_METHODS:
                raise RequestError(f"field 'imaging_method' expected one of "
                                   f"{list(IMAGING_METHODS)}, got {messages._show(method)}")
            for k, v in extras.items():
                if k == "imaging_method":
                    continue
                if v is not None and not (isinstance(v, (int, float))
                                          and not isinstance(v, bool) and 0 <= v < 1e12):
                    raise RequestError(f"field '{k}' expected a number >= 0 or null, got "
                                       f"{messages._show(v)}")
        except RequestError as exc:
            self.progress_refused += 1
            _log_count(self.progress_refused, logging.WARNING, "catch-up service: a "
                       "progress message refused: %s", exc)
            return
        now = time.monotonic()
        with self._workers_lock:
            known = client in self._workers
            if not known:
                # room for a new worker: the longest-silent one goes (a silent worker is
                # otherwise kept, and said to be silent, until the service closes)
                silent = [k for k, w in self._workers.items()
                          if now - w.at > self.worker_silence_s]
                if len(self._workers) >= self.max_workers and silent:
                    del self._workers[min(silent, key=lambda k: self._workers[k].at)]
                if len(self._workers) >= self.max_workers:
                    self.progress_refused += 1
                    _log_count(self.progress_refused, logging.WARNING, "catch-up "
                               "service: worker %s not tracked: %d are (daq.toml "
                               "service.max_workers)", client, len(self._workers))
                    return
            self._workers[client] = _Progress(run_id, nxt, done, now, extras)
            self._workers.move_to_end(client)
        self.progress += 1
        if not known:
            log.info("catch-up service: worker %s is imaging run %s (at ping %d)", client,
                     run_id, nxt)

    def waiting(self, run_id: str) -> dict[str, str]:
        """The workers that have not said they are done with run ``run_id``: those that
        still lack pings of it, and those still on an earlier run (they come to this one
        next), silent ones too (stopped, or hung: they may come back; the daemon's
        ``catch_up.max_linger_s`` bounds the wait): {worker id: "RUN at ping N"
        (", silent for S s")}."""
        now = time.monotonic()
        with self._workers_lock:
            return {k: f"{w.run_id} at ping {w.next}" + (
                f", silent for {now - w.at:.0f} s" if now - w.at > self.worker_silence_s
                else "") for k, w in self._workers.items()
                if not (w.run_id == run_id and w.done)}

    def workers(self) -> list[dict]:
        """The workers that told their progress: ``client``, ``run_id``, ``next`` (the
        first sequence it lacks), ``done``, ``heard_s`` (since its latest progress
        message), ``silent`` (not heard for ``worker_silence_s``: kept, so that the
        alarm stays raised) and what else it said (:data:`PROGRESS_EXTRAS`)."""
        now = time.monotonic()
        with self._workers_lock:
            return [{"client": k, "run_id": w.run_id, "next": w.next, "done": w.done,
                     "heard_s": round(now - w.at, 3),
                     "silent": now - w.at > self.worker_silence_s, **w.extras}
                    for k, w in self._workers.items()]

    def _fetch(self, ident: bytes, req: dict) -> None:
        run_id = req.get("run_id")
        if not isinstance(run_id, str):
            raise RequestError(f"field 'run_id' expected a string, got "
                               f"{messages._show(run_id)}")
        first, last = _int_field(req, "first"), _int_field(req, "last")
        if last < first or last - first > _MAX_SPAN:
            raise RequestError(f"fields 'first' {first} and 'last' {last}: expected first <= "
                               f"last and at most {_MAX_SPAN} sequences")
        cap = self.max_pings
        if "max_pings" in req:
            cap = min(cap, _int_field(req, "max_pings"))
            if cap < 1:
                raise RequestError("field 'max_pings' expected an integer >= 1, got 0")
        if len(self._replies) >= self.max_clients:
            now = time.monotonic()
            idle, rep = min(self._replies.items(), key=lambda kv: kv[1].since)
            if now - rep.since > self.preempt_s:
                self._abandon(idle, f"nothing could be sent to it for {now - rep.since:.1f}"
                              " s while another client asked (it does not read)")
        if len(self._replies) >= self.max_clients:
            self.busy += 1
            _log_count(self.busy, logging.WARNING, "catch-up service: busy, %d clients "
                       "being served (daq.toml service.max_clients); a fetch refused",
                       len(self._replies))
            self._send_short(ident, {"schema": "svss.error", "version": VERSION,
                                     "busy": True, "error": f"busy: {len(self._replies)} "
                                     "clients being served; ask again"})
            return
        info = {r.run_id: r for r in self.store.runs()}.get(run_id)
        if info is None:
            raise RequestError(f"unknown run {messages._show(run_id)}")
        present = self.store.sequences(run_id, first, last)
        pending = False
        if len(present) > cap:
            nxt = present[cap]
            upto = nxt - 1
            present = present[:cap]
        elif not info.ended and last > info.last:
            nxt = max(first, info.last + 1)
            upto = nxt - 1
            pending = True
        else:
            nxt, upto = None, last
        head = {"schema": "svss.fetched", "version": VERSION, "run_id": run_id,
                "first": first, "last": last}
        tail = {"next": nxt, "pending": pending}

        def replies() -> Iterator[list]:
            sent = []
            for q in present:
                ping = self.store.read(run_id, q)
                if ping is None:             # vanished between the two calls: say missing
                    continue
                yield messages.encode_ping(ping)
                sent.append(q)
            missing = _absent(first, upto, sent) if upto >= first else []
            yield [json.dumps({**head, "found": len(sent), "missing": missing,
                               **tail}).encode()]

        self._replies[ident] = _Reply(ident, replies(), time.monotonic())
        self._send_replies()

    def close(self) -> None:
        """Stop the serving thread and close the socket."""
        self._stop.set()
        self._thread.join(timeout=10)
        if self.requests:
            log.info("catch-up service %s: %d request(s), %d ping(s) served, %d refused "
                     "as malformed, %d busy, %d reply(ies) abandoned to stalled clients, "
                     "%d request(s) of such clients refused, %d short reply(ies) dropped",
                     self.endpoint, self.requests, self.pings_served, self.errors,
                     self.busy, self.stalled, self.refused, self.dropped)

    def __enter__(self) -> PingService:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def service_options(cfg) -> dict:
    """:class:`PingService` keyword arguments from daq.toml's ``[service]`` table (a
    :class:`~svss_daq.config.ServiceConfig`; None: the defaults)."""
    if cfg is None:
        return {}
    return {"max_pings_per_reply": cfg.max_pings_per_reply,
            "max_clients": cfg.max_clients, "client_queue": cfg.client_queue,
            "stall_s": cfg.stall_s, "max_workers": cfg.max_workers,
            "worker_silence_s": cfg.worker_silence_s}


# --------------------------------------------------------------------------- client


@dataclass
class Fetched:
    """One reply: the pings (ascending), the ranges of sequences definitively missing
    ((first, last) pairs, ascending, disjoint), where to continue (None: the request is
    answered) and whether ``next`` waits on a run still being recorded."""
    pings: list[Ping]
    missing: list[tuple[int, int]]
    next: int | None
    pending: bool


def count_missing(ranges: Iterable[tuple[int, int]]) -> int:
    """How many sequences ``(first, last)`` ranges hold."""
    return sum(b - a + 1 for a, b in ranges)


class ServiceError(RuntimeError):
    """The catch-up service refused a request or answered something unreadable."""


class PingFetcher:
    """A DEALER client of a :class:`PingService` at ``endpoint``. Every wait for a
    reply message is at most ``timeout_s``; a timeout raises TimeoutError naming the
    endpoint (the socket is then replaced, so a late reply cannot be taken for the next
    one's). A reply holds at most ``max_pings_per_reply`` pings (asked of the service;
    more is a :class:`ServiceError`), ZeroMQ queues at most that many messages for it,
    and a busy service is asked again until ``timeout_s`` has passed."""

    def __init__(self, endpoint: str, *, curve=None, timeout_s: float = 10.0,
                 max_pings_per_reply: int = MAX_PINGS_PER_REPLY,
                 ctx: zmq.Context | None = None):
        check_endpoint(endpoint, bind=False)
        if type(max_pings_per_reply) is not int or max_pings_per_reply < 1:
            raise ValueError(f"max_pings_per_reply: expected an integer >= 1, got "
                             f"{max_pings_per_reply!r}")
        self.endpoint = endpoint
        self.curve = curve
        self.timeout_s = float(timeout_s)
        self.max_pings = max_pings_per_reply
        self.ctx = ctx or zmq.Context.instance()
        self.sock: zmq.Socket | None = None
        self.requests = 0
        self.busy = 0                  # busy answers asked again
        #: the service takes progress messages (:meth:`progress`; said in svss.runs)
        self.takes_progress = False
        self._connect()

    def _connect(self) -> None:
        sock = self.ctx.socket(zmq.DEALER)
        try:
            from .security import secure_client
            secure_client(sock, self.curve)
            sock.setsockopt(zmq.LINGER, 0)
            sock.setsockopt(zmq.RCVHWM, self.max_pings + 1)     # one reply
            sock.connect(self.endpoint)
        except zmq.ZMQError as exc:
            sock.close(linger=0)
            raise OSError(f"cannot connect to the catch-up service {self.endpoint}: "
                          f"{exc}") from None
        except BaseException:
            sock.close(linger=0)
            raise
        self.sock = sock

    def _recv(self) -> list:
        if not self.sock.poll(int(self.timeout_s * 1000)):
            self.sock.close(linger=0)
            self._connect()
            raise TimeoutError(f"catch-up service {self.endpoint}: no reply within "
                               f"{self.timeout_s:g} s")
        return self.sock.recv_multipart(copy=False)

    def _request(self, req: dict) -> tuple[list[Ping], dict]:
        deadline = time.monotonic() + self.timeout_s
        pause = POLL_BUSY_S
        while True:
            self.requests += 1
            self.sock.send(json.dumps({**req, "version": VERSION}).encode())
            try:
                pings, reply = self._reply()
            except ServiceError:
                # the rest of a reply that failed part-way would be taken for the next one's
                self.sock.close(linger=0)
                self._connect()
                raise
            if not (reply.get("schema") == "svss.error" and reply.get("busy") is True):
                if reply.get("schema") == "svss.error":
                    raise ServiceError(f"catch-up service {self.endpoint}: "
                                       f"{reply.get('error')}")
                return pings, reply
            self.busy += 1
            if time.monotonic() + pause > deadline:
                raise ServiceError(f"catch-up service {self.endpoint}: still busy after "
                                   f"{self.timeout_s:g} s ({reply.get('error')})")
            time.sleep(pause)
            pause = min(2 * pause, 1.0)

    def _reply(self) -> tuple[list[Ping], dict]:
        pings = []
        while True:
            frames = self._recv()
            if len(frames) == 1:
                try:
                    reply = json.loads(frames[0].bytes.decode())
                except (UnicodeDecodeError, ValueError) as exc:
                    raise ServiceError(f"catch-up service {self.endpoint}: unreadable reply "
                                       f"({exc})") from None
                if not isinstance(reply, dict):
                    raise ServiceError(f"catch-up service {self.endpoint}: reply is not a "
                                       "JSON object")
                return pings, reply
            if len(pings) >= self.max_pings:
                raise ServiceError(f"catch-up service {self.endpoint}: more than "
                                   f"{self.max_pings} pings in one reply")
            try:
                msg = messages.decode(frames)
            except messages.MessageError as exc:
                raise ServiceError(f"catch-up service {self.endpoint}: {exc}") from None
            if not isinstance(msg, Ping):
                raise ServiceError(f"catch-up service {self.endpoint}: unexpected "
                                   f"{type(msg).__name__} in a reply")
            pings.append(msg)

    def runs(self) -> list[RunInfo]:
        """The runs the service knows, oldest first."""
        _, reply = self._request({"schema": "svss.runs"})
        if reply.get("schema") != "svss.runs" or not isinstance(reply.get("runs"), list):
            raise ServiceError(f"catch-up service {self.endpoint}: expected svss.runs, got "
                               f"{str(reply)[:200]}")
        self.takes_progress = reply.get("progress") is True
        try:
            return [RunInfo.from_dict(r) for r in reply["runs"]]
        except ValueError as exc:
            raise ServiceError(f"catch-up service {self.endpoint}: {exc}") from None

    def progress(self, client: str, run_id: str, next_seq: int, done: bool,
                 extras: dict | None = None) -> bool:
        """Tell the service where this worker is in run ``run_id`` (``next_seq``: the
        first sequence it still lacks; ``done``: it needs nothing more of the run), so
        that a daemon keeps its service up while the worker lacks pings. Never waits and
        never answered; sent only to a service that said it takes them (:meth:`runs`).
        ``extras``: what else the worker says of itself (:data:`PROGRESS_EXTRAS`).
        Whether it was sent."""
        if not self.takes_progress or self.sock is None:
            return False
        try:
            self.sock.send(json.dumps({
                "schema": "svss.progress", "version": VERSION, "client": client,
                "run_id": run_id, "next": int(next_seq), "done": bool(done),
                **{k: v for k, v in (extras or {}).items() if k in PROGRESS_EXTRAS}}
                ).encode(),
                zmq.NOBLOCK)
        except zmq.ZMQError:             # the queue to a gone service is full
            return False
        return True

    def fetch_once(self, run_id: str, first: int, last: int) -> Fetched:
        """One request: at most ``max_pings_per_reply`` pings of [first, last] (and of
        the service's own cap). The missing sequences stay ranges: the work is that of
        the reply's length, never of the numbers in it."""
        pings, reply = self._request({"schema": "svss.fetch", "run_id": run_id,
                                      "first": int(first), "last": int(last),
                                      "max_pings": self.max_pings})
        if reply.get("schema") != "svss.fetched" or reply.get("found") != len(pings):
            raise ServiceError(f"catch-up service {self.endpoint}: reply to fetch "
                               f"{run_id} {first}..{last} announced "
                               f"{reply.get('found')!r} pings, {len(pings)} arrived")
        missing: list[tuple[int, int]] = []
        try:
            at = first
            for a, b in reply["missing"]:
                if not (type(a) is int and type(b) is int and at <= a <= b <= last):
                    raise ValueError
                missing.append((a, b))
                at = b + 1
            nxt = reply["next"]
            if nxt is not None and not (type(nxt) is int and first <= nxt <= last + 1):
                raise ValueError
        except (KeyError, TypeError, ValueError):
            raise ServiceError(f"catch-up service {self.endpoint}: malformed reply "
                               f"{str(reply)[:200]}") from None
        return Fetched(pings, missing, nxt, bool(reply.get("pending")))

    def fetch(self, run_id: str, first: int, last: int
              ) -> tuple[list[Ping], list[tuple[int, int]]]:
        """Every recorded ping of ``run_id`` in [first, last] (over as many capped replies
        as it takes) and the ranges of sequences definitively missing ((first, last)
        pairs, adjacent ones joined). Sequences in neither are not recorded yet (a run
        still being recorded)."""
        pings: list[Ping] = []
        missing: list[tuple[int, int]] = []
        while first <= last:
            got = self.fetch_once(run_id, first, last)
            pings += got.pings
            for a, b in got.missing:
                if missing and missing[-1][1] + 1 == a:
                    missing[-1] = (missing[-1][0], b)
                else:
                    missing.append((a, b))
            if got.next is None or got.pending or got.next <= first:
                break
            first = got.next
        return pings, missing

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close(linger=0)
            self.sock = None

    def __enter__(self) -> PingFetcher:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def wait_for_service(fetcher: PingFetcher, timeout_s: float) -> list[RunInfo]:
    """``fetcher.runs()``, retried until ``timeout_s`` has passed (a service starting)."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return fetcher.runs()
        except TimeoutError:
            if time.monotonic() >= deadline:
                raise
