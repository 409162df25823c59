"""``svss batch``: reprocess whole surveys (many raw runs) into tiles on Dask distributed.

The runs' tiles are planned here from the files' ping and navigation tables
(:mod:`.plan`); each tile is then one independent task (:func:`.task.image_tile`) that
gets file paths and ping index ranges, never pings, and reads its pings from the files
itself, so the raw files must lie on a path every worker sees (docs/batch.md). Tiles go
to ``OUT/RUN/tile_NNNN.h5`` (``RUN``: the run's id made a folder name, as the stream
worker names its run folders), with the run products (contacts, mosaic:
:mod:`svss_proc.products.run_products`) once a run's tiles are all there, the index of
every tile to ``OUT/survey_index.csv`` and the batch's settings and last summary to
``OUT/batch_state.json``.

Resume: a tile whose committed ``.h5`` is there is not imaged again; temporaries left by
a killed writer are removed first. A worker process that dies mid-task is replaced by
its nanny and the scheduler runs its tasks again elsewhere.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import secrets
import shutil
import time
from collections.abc import Callable
from pathlib import Path

from svss_daq.config import Loaded, ProcessingConfig
from svss_daq.progress import Progress

from ..products.run_products import MOSAIC_H5, run_products_at_end
from ..survey_index import INDEX_NAME, find_tiles, write_survey_index
from ..run_folder import atomic_json, remove_temporaries, run_folder_name
from ..imaging.imager import seam_planes
from .plan import RunPlan, TilePlan, group_runs, plan_run
from .task import (PingsRefused, before_from_file, head_planes, image_tile, prefix_head,
                   result_of, save_formed, tile_paths)

log = logging.getLogger(__name__)

STATE = "batch_state.json"
STATE_SCHEMA = "svss.batch_state"
INSTALL_HINT = ('svss batch needs dask.distributed: install the "distributed" extra '
                '(pip install "svss[distributed]", or pip install "dask[distributed]")')


class BatchError(RuntimeError):
    """Tiles that could not be made (each named with its error)."""


class NeighbourFailed(RuntimeError):
    """A tile not made because a neighbour it takes planes or contacts from across a
    seam failed (``cause``: that tile's error)."""

    def __init__(self, index: int, cause: BaseException):
        self.index, self.cause = index, cause
        super().__init__(f"needs tile {index} across a seam, which failed: "
                         f"{type(cause).__name__}: {cause}")


def require_dask():
    """The ``distributed`` module, or ImportError naming the extra to install."""
    try:
        import distributed
    except ImportError as exc:
        raise ImportError(f"{INSTALL_HINT} ({exc})") from None
    return distributed


def prepare_batch_dir(out: Path, runs: dict[str, list[Path]],
                      processing: Loaded[ProcessingConfig], force: bool) -> dict:
    """Make ``out``; refuse one a batch with another processing configuration wrote
    (unless ``force``, which removes its run folders and index); remove temporaries.
    Returns the runs an earlier batch with this configuration recorded there
    (``batch_state.json``'s ``runs``; empty when none): a batch over some of them keeps
    the others in its state and index."""
    out.mkdir(parents=True, exist_ok=True)
    state_path = out / STATE
    old_runs: dict = {}
    if state_path.is_file():
        try:
            state = json.loads(state_path.read_text())
            old = state["processing_config_id"]
            old_runs = dict(state.get("runs", {}))
            for info in old_runs.values():
                if not isinstance(info, dict) or not isinstance(info.get("folder"), str):
                    raise TypeError("a run without its folder")
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{state_path}: not a batch state file ({exc}); choose "
                             "another --out or remove it") from None
        if old != processing.id:
            if not force:
                raise FileExistsError(
                    f"{out}: holds tiles made with processing configuration {old}, not "
                    f"{processing.id} ({processing.source}); choose another --out or pass "
                    "--force to replace them")
            for folder in old_runs.values():
                shutil.rmtree(out / folder["folder"], ignore_errors=True)
            (out / INDEX_NAME).unlink(missing_ok=True)
            log.warning("%s: removed the tiles of %d run(s) made with processing %s "
                        "(--force)", out, len(old_runs), old)
            old_runs = {}
    remove_temporaries(out)
    for run_id in runs:
        d = out / run_folder_name(run_id)
        if d.is_dir():
            remove_temporaries(d)
    return old_runs


def _exclusions(earlier: dict | None, paths: list[Path]) -> dict[tuple[str, int], str]:
    """The pings an earlier batch found refused for their samples in these files:
    (raw file, index) -> reason."""
    names = {str(p) for p in paths}
    out = {}
    for e in (earlier or {}).get("excluded_pings", []):
        try:
            if e["file"] in names:
                out[(e["file"], int(e["index"]))] = str(e["reason"])
        except (KeyError, TypeError, ValueError):
            continue
    return out


#: task failures that a rerun may not meet again (a worker process lost, the disk or
#: the network); any other is the input's or the code's and recurs on every rerun
def _transient(exc: BaseException) -> bool:
    if isinstance(exc, NeighbourFailed):
        return _transient(exc.cause)
    if isinstance(exc, (OSError, MemoryError)):       # also TimeoutError, disk full
        return True
    names = {c.__name__ for c in type(exc).__mro__}
    return bool(names & {"KilledWorker", "CommClosedError", "FutureCancelledError"})


def _signature(t: TilePlan) -> tuple:
    """What a tile's content depends on in its plan."""
    return (t.sequences, t.ranges, t.span, t.line, t.pose_source)


def _signatures(run: RunPlan, seams: bool) -> dict[int, str]:
    """Per tile of ``run``, what its file depends on in the run's plan: its own plan
    and, with products across the seams, the next tile's (its first planes) and the
    previous tile's signature (its last planes and contacts, which depend on the tile
    before it, and so on)."""
    own = {t.index: repr(_signature(t)) for t in run.tiles}
    out: dict[int, str] = {}
    for t in sorted(run.tiles, key=lambda t: t.order):
        parts = [own[t.index]]
        if seams:
            parts += [repr((t.before, t.after_pings, t.after_final)),
                      own.get(t.index + 1, "") if t.after_pings is not None else "",
                      out.get(t.index - 1, "") if t.before else ""]
        out[t.index] = hashlib.sha256("\n".join(parts).encode()).hexdigest()
    return out


def _client(scheduler: str | None, workers: int | None):
    """(client, cluster or None): a client of ``scheduler``, or of a new LocalCluster of
    ``workers`` single-threaded worker processes on the loopback interface."""
    distributed = require_dask()
    if not log.isEnabledFor(logging.DEBUG):     # Dask's own INFO lines only with -v
        logging.getLogger("distributed").setLevel(logging.WARNING)
    if scheduler:
        log.info("batch: connecting to the Dask scheduler at %s", scheduler)
        return distributed.Client(scheduler, timeout=30), None
    n = workers or os.cpu_count() or 1
    cluster = distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                       host="127.0.0.1", dashboard_address=None)
    log.info("batch: local cluster of %d worker process(es) at %s", n,
             cluster.scheduler_address)
    return distributed.Client(cluster), cluster


class ExpectedFailureFilter(logging.Filter):
    """Drops Dask's "Compute Failed" error (with its traceback) for a tile that found
    pings refused for their samples (:class:`~.task.PingsRefused`, or a neighbour's
    across a seam): the batch plans the run again without them and says so once per
    run; it is not a failure (one such error a tile, with a traceback, where the batch
    succeeded)."""

    def filter(self, record: logging.LogRecord) -> bool:
        msg = record.msg if isinstance(record.msg, str) else ""
        if not msg.startswith("Compute Failed"):
            return True
        text = " ".join(str(a) for a in (record.args or ()))
        return "PingsRefused(" not in text


def _install_expected_failure_filter(dask_worker=None) -> None:
    """In a worker (``client.run``) or here: :class:`ExpectedFailureFilter` on Dask's
    worker logger, once."""
    lg = logging.getLogger("distributed.worker")
    if not any(isinstance(f, ExpectedFailureFilter) for f in lg.filters):
        lg.addFilter(ExpectedFailureFilter())


def _quiet_expected_failures(client) -> None:
    """:func:`_install_expected_failure_filter` in every worker of ``client`` (and in
    this process, where threads may compute)."""
    _install_expected_failure_filter()
    try:
        client.run(_install_expected_failure_filter)
    except Exception as exc:                      # noqa: BLE001 - logging only
        log.debug("batch: the workers' log filter was not installed (%s)", exc)


def _stop_heartbeat(dask_worker) -> None:
    """In a worker: stop its heartbeats to the scheduler (the batch is over)."""
    pc = dask_worker.periodic_callbacks.get("heartbeat")
    if pc is not None:
        pc.stop()


def _close_client(client, cluster) -> None:
    """Close a client and the LocalCluster made for it. With a cluster, the workers'
    heartbeats stop first: a worker process the machine's load holds up while the
    cluster closes would otherwise wake into a heartbeat to the scheduler just closed
    and log it with a traceback (one per worker, after a successful batch)."""
    if cluster is not None:
        try:
            client.run(_stop_heartbeat)
        except Exception as exc:                  # noqa: BLE001 - closing regardless
            log.debug("batch: the workers' heartbeats were not stopped (%s)", exc)
    client.close()
    if cluster is not None:
        cluster.close()


def run_batch(paths: list[str | Path], out: str | Path,
              processing: Loaded[ProcessingConfig], *, scheduler: str | None = None,
              workers: int | None = None, force: bool = False, client=None,
              kernel_threads: int | None = None,
              task: Callable[..., dict] = image_tile,
              renavigate: bool | None = None, micronav: bool | None = None,
              autofocus: bool | None = None, sediment_speed: str | None = None) -> dict:
    """Reprocess the raw runs ``paths`` into ``out``; return the summary (also in
    ``out/batch_state.json``). ``scheduler``: a Dask scheduler's address (default: a
    LocalCluster of ``workers`` processes); ``client``: an existing
    ``distributed.Client`` instead of either; ``kernel_threads``: numba threads of each
    task's imaging kernel (default: with a local cluster, the cores shared out among its
    workers; otherwise the workers' own setting, e.g. ``NUMBA_NUM_THREADS``);
    ``task``: the tile function (the default :func:`~.task.image_tile`; tests wrap
    it; with products across the seams it is called with ``save=False`` and the tile
    is saved by :func:`~.task.save_formed`: docs/batch.md, *Products across the
    seams*); ``renavigate``: pose each run as :func:`svss_proc.run_worker.run_poses` decides
    (default: re-navigated from its instrument records where it has them; the
    summary's runs say which); ``micronav``: the re-navigated poses fused with the
    echoes' increments (None: as the processing configuration's ``[micronav]`` says);
    ``autofocus``: each run's poses corrected by the autofocus stage (None: as its
    ``[autofocus] enabled`` says; the state's runs' ``autofocus`` say what it did);
    ``sediment_speed``: 'estimate' / 'configured' (None: ``[seabed] speed``), each
    run's sediment speed from its echoes (the state's runs' ``seabed``).

    A ping a task finds refused for its samples (:class:`~.task.PingsRefused`) is left
    out of its run's plan, which is made again (tiles whose plan changed are imaged
    again) and recorded in the state (``excluded_pings``), as ``svss process`` refuses
    it. Runs of an earlier batch into ``out`` that this one does not name stay in the
    state and the survey index. Raises :class:`BatchError` naming every tile that
    failed and whether a rerun can make it (the others are kept)."""
    t0 = time.perf_counter()
    out = Path(out).absolute()              # the tasks may run in another folder
    runs = group_runs(paths)
    seams = seam_planes(processing.value) > 0     # products without seams
    earlier = prepare_batch_dir(out, runs, processing, force)
    excluded = {run_id: _exclusions(earlier.get(run_id), ps) for run_id, ps in runs.items()}
    plans = {run_id: plan_run(run_id, run_folder_name(run_id), ps, processing, renavigate,
                              excluded[run_id], micronav, autofocus, sediment_speed)
             for run_id, ps in runs.items()}
    t_plan = time.perf_counter() - t0
    tiles = [t for p in plans.values() for t in p.tiles]
    todo = [t for t in tiles if not tile_paths(out, t)[0].is_file()]
    n_todo = len(todo)
    log.info("batch: %d run(s), %d tile(s) planned in %.2f s; %d to image, %d done already",
             len(plans), len(tiles), t_plan, len(todo), len(tiles) - len(todo))

    def state_of() -> dict:
        mine = {p.run_id: {"folder": p.folder, "files": [str(f) for f in p.paths],
                           "pings": p.n_pings, "tiles": len(p.tiles),
                           "refused": p.refused, "late_pings": p.late_pings,
                           "poses": p.poses, "autofocus": p.autofocus,
                           "seabed": p.seabed,
                           "excluded_pings": [
                               {"file": f, "index": i, "reason": why}
                               for (f, i), why in sorted(excluded[p.run_id].items())]}
                for p in plans.values()}
        kept = {r: info for r, info in earlier.items()
                if r not in mine and (out / info["folder"]).is_dir()}
        return {"schema": STATE_SCHEMA, "version": 1,
                "processing_config_id": processing.id,
                "processing_source": processing.source, "runs": {**kept, **mine}}

    atomic_json(out / STATE, {**state_of(), "complete": False})
    results: list[dict] = []
    errors: list[tuple[TilePlan, BaseException]] = []
    t_cluster0 = time.perf_counter()
    n_workers, t_run = 0, 0.0
    own = client is None
    cluster = None
    try:
        while todo:
            if client is None:
                client, cluster = _client(scheduler, workers)
                if cluster is not None and kernel_threads is None:
                    n = len(cluster.workers)
                    kernel_threads = max(1, (os.cpu_count() or 1) // n)
                    log.info("batch: %d kernel thread(s) per worker", kernel_threads)
            _quiet_expected_failures(client)
            t_run0 = time.perf_counter()
            if seams:
                made, failed, n_workers = _dispatch_seams(client, todo, plans, out,
                                                          processing, task, kernel_threads)
            else:
                made, failed, n_workers = _dispatch(client, todo, out, processing, task,
                                                    kernel_threads)
            t_run += time.perf_counter() - t_run0
            results += made
            todo = []
            refused: dict[str, dict[tuple[str, int], str]] = {}
            for t, exc in failed:
                # a tile that failed only because its neighbour's pings were refused is
                # made with the run planned again
                cause = exc.cause if isinstance(exc, NeighbourFailed) else exc
                new = {} if not isinstance(cause, PingsRefused) else {
                    (f, int(i)): why for f, i, _seq, why in cause.pings
                    if (f, int(i)) not in excluded[t.run_id]}
                if new:
                    refused.setdefault(t.run_id, {}).update(new)
                else:                   # (refused again though planned out: a defect)
                    errors.append((t, exc))
            for run_id, new in refused.items():       # plan the run again without them
                excluded[run_id].update(new)
                log.warning("batch: run %s: %d ping(s) refused for their samples (e.g. %s "
                            "index %d: %s); planning the run again without them, as svss "
                            "process images it", run_id, len(new), *next(iter(new)),
                            next(iter(new.values())))
                old = plans[run_id]
                plans[run_id] = plan_run(run_id, old.folder, old.paths, processing,
                                         renavigate, excluded[run_id], micronav,
                                         autofocus, sediment_speed)
                todo += _replanned(out, old, plans[run_id], seams)
            if todo:
                atomic_json(out / STATE, {**state_of(), "complete": False})
                n_todo += len(todo)
    finally:
        if own and client is not None:
            _close_client(client, cluster)
    tiles = [t for p in plans.values() for t in p.tiles]
    t_cluster = time.perf_counter() - t_cluster0 - t_run
    made = {r["key"] for r in results}          # (a tile imaged again counts once)
    imaged = len(made)
    skipped = sum(t.key not in made for t in tiles)
    # the run products (contacts, mosaic) of every run whose tiles are all there, as the
    # streaming worker writes them at a run's end: when this batch made some of them, or
    # when an earlier one was stopped before writing them
    touched = {r["folder"] for r in results}
    for p in plans.values():
        if p.tiles and all(tile_paths(out, t)[0].is_file() for t in p.tiles) and (
                p.folder in touched or not (out / p.folder / MOSAIC_H5).is_file()):
            run_products_at_end(out / p.folder)
    index_tiles = [(t.run_id, tile_paths(out, t)[0]) for t in tiles
                   if tile_paths(out, t)[0].is_file()]
    state = state_of()
    others = [(run_id, p) for run_id, info in state["runs"].items() if run_id not in plans
              for _, p in find_tiles(out / info["folder"])]
    index, rows = write_survey_index(out, index_tiles + others)
    dets = sum(r["n_detections"] for r in rows if r["run_id"] in plans)
    summary = {
        "runs": len(plans), "tiles": len(tiles), "imaged": imaged,
        "skipped": skipped, "failed": len(errors),
        # tasks run again after their worker died that found their tile committed
        "found_committed": sum(r["skipped"] for r in results),
        "pings": sum(p.n_pings for p in plans.values()),
        "excluded_pings": sum(len(v) for v in excluded.values()),
        # run_s: from the first task submitted to the last result; cluster_s: starting,
        # connecting and closing (0 with a client given)
        "detections": dets, "plan_s": round(t_plan, 4), "run_s": round(t_run, 4),
        "cluster_s": round(t_cluster, 4),
        "total_s": round(time.perf_counter() - t0, 4),
        "compute_s": round(sum(r["compute_s"] for r in results), 4),
        "workers": n_workers, "index": str(index),
        "index_runs": len({r["run_id"] for r in rows}),
        "task_pids": sorted({r["pid"] for r in results}),
        "results": sorted(results, key=lambda r: r["key"]),
    }
    atomic_json(out / STATE, {**state, "complete": not errors, "summary": summary})
    if errors:
        raise BatchError(_failure_report(errors, n_todo, imaged))
    log.info("batch: %d tile(s) (%d imaged, %d skipped), %d detection(s), %.1f s",
             len(tiles), imaged, skipped, dets, summary["total_s"])
    return summary


def _replanned(out: Path, old: RunPlan, new: RunPlan, seams: bool) -> list[TilePlan]:
    """The tiles of a run planned again (``new``) to image: those not on disk, and those
    on disk made under the old plan that changed (removed here; ``seams``: with products
    across the seams, also those whose neighbours changed)."""
    before = _signatures(old, seams)
    sig = _signatures(new, seams)
    now = {t.index for t in new.tiles}
    for t in old.tiles:                         # gone from the plan
        if t.index not in now:
            for f in tile_paths(out, t):
                f.unlink(missing_ok=True)
    todo = []
    for t in new.tiles:
        h5, png = tile_paths(out, t)
        if h5.is_file() and before.get(t.index) != sig[t.index]:
            h5.unlink()
            png.unlink(missing_ok=True)
            log.info("batch: %s was made with pings now refused: imaged again", h5)
        if not h5.is_file():
            todo.append(t)
    return todo


def _failure_report(errors: list[tuple[TilePlan, BaseException]], n_todo: int,
                    imaged: int) -> str:
    """The BatchError message: each failed tile with its error, and whether a rerun
    can make it."""
    def line(t: TilePlan, exc: BaseException) -> str:
        files = sorted({r[0] for r in t.ranges})
        return (f"run {t.run_id} tile {t.index} ({', '.join(files)}): "
                f"{type(exc).__name__}: {exc}")
    again = [line(t, e) for t, e in errors if _transient(e)]
    fixed = [line(t, e) for t, e in errors if not _transient(e)]
    parts = [f"{len(errors)} of {n_todo} tile(s) failed (the {imaged} made are kept)."]
    if fixed:
        parts.append(f"{len(fixed)} fail the same way on every rerun: the file or the "
                     "ping named is at fault (svss inspect FILE says more), or the "
                     "software: " + "; ".join(fixed) + ".")
    if again:
        parts.append(f"{len(again)} failed for a cause outside the input (a worker "
                     "process lost, the disk, the network): a rerun, once it is fixed, "
                     "makes only the missing tiles: " + "; ".join(again) + ".")
    return " ".join(parts)


def _dispatch(client, todo: list[TilePlan], out: Path, processing, task,
              kernel_threads: int | None
              ) -> tuple[list[dict], list[tuple[TilePlan, BaseException]], int]:
    """Submit one task per tile and wait for all; (results, failures (the tile, its
    exception), workers seen)."""
    distributed = require_dask()
    token = secrets.token_hex(4)
    n_workers = len(client.scheduler_info().get("workers", {}))
    futures = {client.submit(task, t, str(out), processing, kernel_threads,
                             key=f"{t.key}-{token}", pure=False): t for t in todo}
    progress = Progress("batch", len(todo), log, unit="tiles")
    results, errors = [], []
    for fut in distributed.as_completed(futures):
        t = futures[fut]
        try:
            results.append(fut.result())
        except Exception as exc:                  # noqa: BLE001 - reported per tile
            errors.append((t, exc))
            if not isinstance(exc, PingsRefused):     # (planned again: logged there)
                log.error("batch: run %s tile %d: %s: %s", t.run_id, t.index,
                          type(exc).__name__, exc)
        progress.update()
        fut.release()
    return results, errors, n_workers


def _dispatch_seams(client, todo: list[TilePlan], plans: dict, out: Path, processing,
                    task, kernel_threads: int | None
                    ) -> tuple[list[dict], list[tuple[TilePlan, BaseException]], int]:
    """:func:`_dispatch` for products without seams: per tile, a task images it
    (``task(..., save=False)``: the tile stays in its worker's memory), and another
    saves it with its products once what ``svss process`` gives it across the seams is
    there: the next tile's first planes (taken from that tile imaged, or from its file,
    or imaged again from the pings it had then: :func:`~.task.prefix_head`) and the
    previous tile's last planes and contacts (from its save, or from its file). The
    saves of a run's tiles follow one another in ``svss process``'s order; the
    imaging runs in parallel. The client keeps no future of the heavy results (tiles,
    planes): Dask frees each once its dependents have run."""
    distributed = require_dask()
    token = secrets.token_hex(4)
    n = seam_planes(processing.value)
    n_workers = len(client.scheduler_info().get("workers", {}))
    sout = str(out)
    by_run = {run_id: {t.index: t for t in p.tiles} for run_id, p in plans.items()}
    formed = {(t.run_id, t.index): client.submit(
        task, t, sout, processing, kernel_threads, save=False,
        key=f"form-{t.key}-{token}", pure=False) for t in todo}
    # whether each tile's imaging failed (without holding the tile)
    imaged = {k: client.submit(_nothing, f, key=f"imaged-{k[0]}-{k[1]}-{token}",
                               pure=False) for k, f in formed.items()}
    saved, summaries, prefixes = {}, {}, {}
    for t in sorted(todo, key=lambda t: (t.run_id, t.order)):
        me, run_tiles = (t.run_id, t.index), by_run[t.run_id]
        after = before = None
        if t.after_pings is not None:
            nxt = run_tiles[t.index + 1]
            if t.after_final:
                after = client.submit(head_planes, formed.get((t.run_id, nxt.index)), nxt,
                                      sout, n, key=f"head-{nxt.key}-{token}", pure=False)
            else:
                after = prefixes[me] = client.submit(
                    prefix_head, nxt, t.after_pings, processing, n, kernel_threads,
                    key=f"prefix-{nxt.key}-{token}", pure=False)
        if t.before:
            prev = run_tiles[t.index - 1]
            before = saved.get((t.run_id, prev.index))
            if before is None:                  # done before: from its file
                before = client.submit(before_from_file, prev, sout, n,
                                       key=f"before-{prev.key}-{token}", pure=False)
        saved[me] = client.submit(save_formed, formed[me], t, sout, processing, before,
                                  after, kernel_threads, key=f"save-{t.key}-{token}",
                                  pure=False)
        summaries[me] = client.submit(result_of, saved[me], key=f"{t.key}-{token}",
                                      pure=False)
    del formed, saved, after, before
    progress = Progress("batch", len(todo), log, unit="tiles")
    results, failed = [], []
    tiles = {f: me for me, f in summaries.items()}
    plan_of = {(t.run_id, t.index): t for t in todo}
    for fut in distributed.as_completed(list(summaries.values())):
        try:
            results.append(fut.result())
        except Exception as exc:                  # noqa: BLE001 - reported per tile
            failed.append((tiles[fut], exc))
        progress.update()
    distributed.wait(list(imaged.values()))
    errors, known = [], {}
    # in tile order: a tile's error that names its failed predecessor carries that
    # tile's own error, not whichever of its inputs' errors Dask reported first
    for me, exc in sorted(failed, key=lambda f: (f[0][0], plan_of[f[0]].index)):
        t = plan_of[me]
        own = known[me] = _own_error(t, imaged, prefixes.get(me), summaries, exc, known)
        errors.append((t, own))
        if not isinstance(own, PingsRefused) and not (
                isinstance(own, NeighbourFailed) and isinstance(own.cause, PingsRefused)):
            log.error("batch: run %s tile %d: %s: %s", t.run_id, t.index,
                      type(own).__name__, own)
    for f in [*imaged.values(), *summaries.values(), *prefixes.values()]:
        f.release()
    return results, errors, n_workers


def _nothing(_) -> None:
    return None


def _own_error(t: TilePlan, imaged: dict, prefix, summaries: dict,
               exc: BaseException, known: dict | None = None) -> BaseException:
    """A tile's error: its own imaging's, else that of the neighbour it waited for
    across a seam (:class:`NeighbourFailed`; for the previous tile, its own error from
    ``known`` where given: its save's failure may be its imaging's or its own
    predecessor's, whichever came first), else its own save's (``exc``)."""
    run = t.run_id
    mine = imaged[(run, t.index)]
    if mine.status == "error":
        return mine.exception()
    nxt = prefix if prefix is not None else imaged.get((run, t.index + 1))
    prev = summaries.get((run, t.index - 1))
    for index, fut, used in ((t.index + 1, nxt, t.after_pings is not None),
                             (t.index - 1, prev, t.before)):
        if used and fut is not None and fut.status == "error":
            cause = (known or {}).get((run, index)) if index < t.index else None
            cause = fut.exception() if cause is None else cause
            return cause if isinstance(cause, NeighbourFailed) else \
                NeighbourFailed(index, cause)
    return exc


def format_summary(s: dict) -> str:
    """The summary's lines for the terminal."""
    return (f"svss batch: {s['tiles']} tile(s) of {s['runs']} run(s) ({s['imaged']} imaged, "
            f"{s['skipped']} already done), {s['pings']} pings, {s['detections']} "
            f"detection(s), {s['total_s']:.1f} s (plan {s['plan_s']:.1f} s, tiles "
            f"{s['run_s']:.1f} s on {s['workers']} worker(s), cluster start and stop "
            f"{s['cluster_s']:.1f} s)\nindex: {s['index']}")
