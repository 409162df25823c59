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
from ..survey_index import INDEX_NAME, write_survey_index
from ..worker import _atomic_json, remove_temporaries, run_folder_name
from .plan import TilePlan, group_runs, plan_run
from .task import image_tile, tile_paths

log = logging.getLogger(__name__)

STATE = "batch_state.json"
STATE_SCHEMA = "svss.batch_state"
INSTALL_HINT = ('svss batch needs dask.distributed: install the "distributed" extra '
                '(pip install "svss[distributed]", or pip install "dask[distributed]")')


class BatchError(RuntimeError):
    """Tiles that could not be made (each named with its error)."""


def require_dask():
    """The ``distributed`` module, or ImportError naming the extra to install."""
    try:
        import distributed
    except ImportError as exc:
        raise ImportError(f"{INSTALL_HINT} ({exc})") from None
    return distributed


def prepare_batch_dir(out: Path, runs: dict[str, list[Path]],
                      processing: Loaded[ProcessingConfig], force: bool) -> None:
    """Make ``out``; refuse one a batch with another processing configuration wrote
    (unless ``force``, which removes its run folders and index); remove temporaries."""
    out.mkdir(parents=True, exist_ok=True)
    state_path = out / STATE
    if state_path.is_file():
        try:
            state = json.loads(state_path.read_text())
            old = state["processing_config_id"]
            old_runs = dict(state.get("runs", {}))
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
    remove_temporaries(out)
    for run_id in runs:
        d = out / run_folder_name(run_id)
        if d.is_dir():
            remove_temporaries(d)


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


def run_batch(paths: list[str | Path], out: str | Path,
              processing: Loaded[ProcessingConfig], *, scheduler: str | None = None,
              workers: int | None = None, force: bool = False, client=None,
              kernel_threads: int | None = None,
              task: Callable[..., dict] = image_tile,
              renavigate: bool | None = None) -> dict:
    """Reprocess the raw runs ``paths`` into ``out``; return the summary (also in
    ``out/batch_state.json``). ``scheduler``: a Dask scheduler's address (default: a
    LocalCluster of ``workers`` processes); ``client``: an existing
    ``distributed.Client`` instead of either; ``kernel_threads``: numba threads of each
    task's imaging kernel (default: with a local cluster, the cores shared out among its
    workers; otherwise the workers' own setting, e.g. ``NUMBA_NUM_THREADS``);
    ``task``: the tile function (the default :func:`~.task.image_tile`; tests wrap
    it); ``renavigate``: pose each run as :func:`svss_proc.worker.run_poses` decides
    (default: re-navigated from its instrument records where it has them; the
    summary's runs say which). Raises :class:`BatchError` naming every
    tile that failed (the others are kept: a rerun makes only the missing ones)."""
    t0 = time.perf_counter()
    out = Path(out).absolute()              # the tasks may run in another folder
    runs = group_runs(paths)
    prepare_batch_dir(out, runs, processing, force)
    plans = [plan_run(run_id, run_folder_name(run_id), ps, processing, renavigate)
             for run_id, ps in runs.items()]
    t_plan = time.perf_counter() - t0
    tiles = [t for p in plans for t in p.tiles]
    todo = [t for t in tiles if not tile_paths(out, t)[0].is_file()]
    log.info("batch: %d run(s), %d tile(s) planned in %.2f s; %d to image, %d done already",
             len(plans), len(tiles), t_plan, len(todo), len(tiles) - len(todo))
    state = {"schema": STATE_SCHEMA, "version": 1, "processing_config_id": processing.id,
             "processing_source": processing.source,
             "runs": {p.run_id: {"folder": p.folder, "files": [str(f) for f in p.paths],
                                 "pings": p.n_pings, "tiles": len(p.tiles),
                                 "refused": p.refused, "late_pings": p.late_pings,
                                 "poses": p.poses}
                      for p in plans}}
    _atomic_json(out / STATE, {**state, "complete": False})
    results, errors = [], []
    t_cluster0 = time.perf_counter()
    n_workers, t_run = 0, 0.0
    if todo:
        own = client is None
        cluster = None
        if own:
            client, cluster = _client(scheduler, workers)
            if cluster is not None and kernel_threads is None:
                n = len(cluster.workers)
                kernel_threads = max(1, (os.cpu_count() or 1) // n)
                log.info("batch: %d kernel thread(s) per worker", kernel_threads)
        try:
            t_run0 = time.perf_counter()
            results, errors, n_workers = _dispatch(client, todo, out, processing, task,
                                                   kernel_threads)
            t_run = time.perf_counter() - t_run0
        finally:
            if own:
                client.close()
                if cluster is not None:
                    cluster.close()
    t_cluster = time.perf_counter() - t_cluster0 - t_run
    imaged = len(results)
    skipped = len(tiles) - len(todo)
    # the run products (contacts, mosaic) of every run whose tiles are all there, as the
    # streaming worker writes them at a run's end: when this batch made some of them, or
    # when an earlier one was stopped before writing them
    touched = {r["folder"] for r in results}
    for p in plans:
        if p.tiles and all(tile_paths(out, t)[0].is_file() for t in p.tiles) and (
                p.folder in touched or not (out / p.folder / MOSAIC_H5).is_file()):
            run_products_at_end(out / p.folder)
    index_tiles = [(t.run_id, tile_paths(out, t)[0]) for t in tiles
                   if tile_paths(out, t)[0].is_file()]
    index, rows = write_survey_index(out, index_tiles)
    dets = sum(r["n_detections"] for r in rows)
    summary = {
        "runs": len(plans), "tiles": len(tiles), "imaged": imaged,
        "skipped": skipped, "failed": len(errors),
        # tasks run again after their worker died that found their tile committed
        "found_committed": sum(r["skipped"] for r in results),
        "pings": sum(p.n_pings for p in plans),
        # run_s: from the first task submitted to the last result; cluster_s: starting,
        # connecting and closing (0 with a client given)
        "detections": dets, "plan_s": round(t_plan, 4), "run_s": round(t_run, 4),
        "cluster_s": round(t_cluster, 4),
        "total_s": round(time.perf_counter() - t0, 4),
        "compute_s": round(sum(r["compute_s"] for r in results), 4),
        "workers": n_workers, "index": str(index),
        "task_pids": sorted({r["pid"] for r in results}),
        "results": sorted(results, key=lambda r: r["key"]),
    }
    _atomic_json(out / STATE, {**state, "complete": not errors, "summary": summary})
    if errors:
        raise BatchError(f"{len(errors)} of {len(todo)} tile(s) failed (the {imaged} "
                         "made are kept; a rerun makes the rest): " + "; ".join(errors))
    log.info("batch: %d tile(s) (%d imaged, %d skipped), %d detection(s), %.1f s",
             len(tiles), imaged, skipped, dets, summary["total_s"])
    return summary


def _dispatch(client, todo: list[TilePlan], out: Path, processing, task,
              kernel_threads: int | None) -> tuple[list[dict], list[str], int]:
    """Submit one task per tile and wait for all; (results, errors, workers seen)."""
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
            files = sorted({r[0] for r in t.ranges})
            errors.append(f"run {t.run_id} tile {t.index} ({', '.join(files)}): "
                          f"{type(exc).__name__}: {exc}")
            log.error("batch: %s", errors[-1])
        progress.update()
        fut.release()
    return results, errors, n_workers


def format_summary(s: dict) -> str:
    """The summary's lines for the terminal."""
    return (f"svss batch: {s['tiles']} tile(s) of {s['runs']} run(s) ({s['imaged']} imaged, "
            f"{s['skipped']} already done), {s['pings']} pings, {s['detections']} "
            f"detection(s), {s['total_s']:.1f} s (plan {s['plan_s']:.1f} s, tiles "
            f"{s['run_s']:.1f} s on {s['workers']} worker(s), cluster start and stop "
            f"{s['cluster_s']:.1f} s)\nindex: {s['index']}")
