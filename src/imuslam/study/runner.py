"""Running a study: serially, on an in-process Dask ``LocalCluster``, or on an existing Dask scheduler.

The task graph: one calibration task per (age of the IMU errors, gimbal seed), one task per piece of
work an estimator's cells share (``EstimatorEntry.prepare``, e.g. a VO front end over the same images),
and one task per distinct cell, which takes their results (so the cells of one seed share one
calibration, wherever they run). Every cell is deterministic (seeded from hashes, ``cells.py``), so the numbers do not depend
on where or in which order cells run: a Dask run equals a serial one. Each finished cell is written at
once to ``OUT/cells/<key>.json``; a study run again into the same folder takes those and runs only the
rest (resume after an interruption, or extend a study with more seeds). A failing cell is a row with
status 'error' and its error's line. Tables and the report are written only when every cell has a row.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd
from tqdm import tqdm

from imuslam.errors import InputError
from imuslam.io.atomic import write_atomic
from imuslam.study.cells import Cell, expand
from imuslam.study.config import StudyConfig
from imuslam.study.estimators import check_study
from imuslam.study.pipeline import (
    calibration_need,
    calibration_task,
    run_cell,
    shared_need,
    shared_task,
)

log = logging.getLogger(__name__)


@dataclass
class StudyRun:
    """The results table (one row per cell, in the study's order) and where it was written."""

    table: pd.DataFrame
    out_dir: Path | None
    n_cached: int
    n_run: int
    backend: str


def plan(study: StudyConfig, source: str = "<study>") -> list[Cell]:
    """The study's cells, after checking every estimator, option and scenario (InputError otherwise)."""
    check_study(study, source)
    cells = expand(study)
    if not cells:
        raise InputError(f"{source}: the study has no cells")
    return cells


@contextmanager
def dask_client(scheduler: str | None, workers: int | None) -> Iterator[Any]:
    """A client of ``scheduler`` (an address), or of a new in-process LocalCluster of ``workers``
    single-threaded worker processes (default: one per core)."""
    from distributed import Client, LocalCluster

    for name in (
        "distributed",
        "tornado",
        "bokeh",
    ):  # the scheduler's chatter is not the user's news
        logging.getLogger(name).setLevel(logging.ERROR)
    if scheduler:
        try:
            client = Client(scheduler, timeout="5s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise InputError(
                f"--scheduler {scheduler}: cannot reach the Dask scheduler ({type(exc).__name__})"
            ) from None
        try:
            yield client
        finally:
            client.close()
        return
    n = workers or os.cpu_count() or 1
    # one worker = one core (dask sets OMP / BLAS threads to 1 in its workers; numba's threading layer
    # reads NUMBA_NUM_THREADS at import, before a Nanny's env would apply, so it is left alone)
    with LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                      silence_logs=logging.ERROR) as cluster, Client(cluster) as client:  # fmt: skip
        yield client


def _cache_path(out: Path, key: str) -> Path:
    return out / "cells" / f"{key}.json"


def _load_cached(out: Path | None, cell: Cell) -> dict[str, Any] | None:
    if out is None:
        return None
    p = _cache_path(out, cell.key)
    try:
        d = json.loads(p.read_text())
    except (OSError, ValueError):
        return None
    if d.get("content") != cell.content() or d.get("row", {}).get("status") != "ok":
        return None  # another cell with the same short hash, or a failure: run it again
    row: dict[str, Any] = d["row"]
    return row


def _store(out: Path | None, cell: Cell, row: dict[str, Any]) -> None:
    if out is not None and row.get("status") == "ok":
        write_atomic(
            _cache_path(out, cell.key), json.dumps({"content": cell.content(), "row": row})
        )


def execute(
    cells: list[Cell],
    out: Path | None = None,
    scheduler: str | None = None,
    workers: int | None = None,
    serial: bool = False,
    progress: bool = True,
) -> tuple[dict[str, dict[str, Any]], int, str]:
    """Rows by cell key for every distinct cell (from the cache or run); the number taken from the
    cache; the backend used."""
    unique: dict[str, Cell] = {}
    for c in cells:
        unique.setdefault(c.key, c)
    rows: dict[str, dict[str, Any]] = {}
    for k, c in unique.items():
        r = _load_cached(out, c)
        if r is not None:
            rows[k] = r
    n_cached = len(rows)
    pending = [c for k, c in unique.items() if k not in rows]
    if not pending:
        return rows, n_cached, "cache"
    if serial:
        bar = tqdm(total=len(pending), unit="cell", desc="study", disable=not progress)
        backend = "serial"
        cals: dict[tuple[float, int], Any] = {}
        shared: dict[str, Any] = {}
        for c in pending:
            need = calibration_need(c)
            if need is not None and need not in cals:
                cals[need] = calibration_task(c.drift.model_dump(), *need)
            sh = shared_need(c)
            if sh is not None and sh[0] not in shared:
                shared.clear()  # keep one at a time: cells that share work are adjacent in the study
                shared[sh[0]] = shared_task(sh[1], *sh[2])
            rows[c.key] = run_cell(c, None if need is None else cals[need],
                                   None if sh is None else shared[sh[0]])  # fmt: skip
            _store(out, c, rows[c.key])
            bar.update()
        bar.close()
        return rows, n_cached, backend
    with dask_client(scheduler, workers) as client:
        from distributed import as_completed

        n_workers = len(client.scheduler_info()["workers"])
        backend = f"dask {scheduler if scheduler else 'LocalCluster'} ({n_workers} workers)"
        bar = tqdm(total=len(pending), unit="cell", desc="study", disable=not progress)
        cal_futures: dict[tuple[float, int], Any] = {}
        shared_futures: dict[str, Any] = {}
        futures = {}
        for c in pending:
            need = calibration_need(c)
            if need is not None and need not in cal_futures:
                cal_futures[need] = client.submit(
                    calibration_task, c.drift.model_dump(), *need,
                    key=f"calibration-{need[1]:x}-{need[0]:g}h-{c.key}",
                )  # fmt: skip
            sh = shared_need(c)
            if sh is not None and sh[0] not in shared_futures:
                shared_futures[sh[0]] = client.submit(
                    shared_task, sh[1], *sh[2], key=f"shared-{sh[0]}"
                )
            fut = client.submit(run_cell, c.model_dump(mode="json"),
                                None if need is None else cal_futures[need],
                                None if sh is None else shared_futures[sh[0]], key=f"cell-{c.key}")  # fmt: skip
            futures[fut] = c
        for fut in as_completed(list(futures)):
            c = futures[fut]
            try:
                row = fut.result()
            except Exception as exc:  # a worker died, a task was lost: record it, go on
                row = {"key": c.key, **c.label, "status": "error",
                       "error": f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"[:500]}  # fmt: skip
            rows[c.key] = row
            _store(out, c, row)
            bar.update()
            fut.release()
        bar.close()
    return rows, n_cached, backend


def table(cells: list[Cell], rows: dict[str, dict[str, Any]]) -> pd.DataFrame:
    """One row per cell in the study's order (a cell shared by two claims appears under each)."""
    return pd.DataFrame([{**rows[c.key], **c.label} for c in cells])


def run_study(
    study: StudyConfig,
    out_dir: str | Path | None,
    scheduler: str | None = None,
    workers: int | None = None,
    serial: bool = False,
    progress: bool = True,
    source: str = "<study>",
) -> StudyRun:
    """Plan, run (see the module docstring) and, with ``out_dir``, write results.parquet, results.csv,
    report.html, report.md and study.yaml there."""
    cells = plan(study, source)
    out = Path(out_dir) if out_dir is not None else None
    if out is not None and out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: exists and is not a folder")
    rows, n_cached, backend = execute(cells, out, scheduler, workers, serial, progress)
    df = table(cells, rows)
    if out is not None:
        from imuslam.study.report import write_outputs

        write_outputs(study, df, out, backend)
    return StudyRun(df, out, n_cached, len(rows) - n_cached, backend)
