"""Running a study: serially, on an in-process Dask ``LocalCluster``, or on an existing Dask scheduler.

The task graph: one calibration task per (age of the IMU errors, gimbal seed), one task per piece of
work an estimator's cells share (``EstimatorEntry.prepare``, e.g. a VO front end over the same images),
and one task per distinct cell, which takes their results (so the cells of one seed share one
calibration, wherever they run). Every cell is deterministic (seeded from hashes, ``cells.py``), so the numbers do not depend
on where or in which order cells run: a Dask run equals a serial one. Each finished cell is written at
once to ``OUT/cells/<key>.json``; a study run again into the same folder takes those and runs only the
rest (resume after an interruption, or extend a study with more seeds). A failing cell is a row with
status 'error' and its error's line. Tables and the report are written only when every cell has a row.

Seeds are added in batches (``study/sequential.py``): the first look runs every claim's first seeds;
after each look, a claim with a pair still unresolved and seeds left in its budget gets its next batch,
and the claims that need more run together in the next round (on the same cluster), until none does.
"""

from __future__ import annotations

import json
import logging
import os
import time
import warnings
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager, nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd
from tqdm import tqdm

from imuslam.errors import InputError, raise_if_interrupted
from imuslam.io.atomic import write_atomic
from imuslam.study.cells import Cell, expand
from imuslam.study.config import StudyConfig
from imuslam.study.estimators import check_study
from imuslam.study.pipeline import (
    CALIBRATION_CPU_S,
    METRICS,
    calibration_need,
    calibration_task,
    cell_cost,
    run_cell,
    shared_need,
    shared_task,
)
from imuslam.threads import WORKER_ENV

log = logging.getLogger(__name__)

#: The metrics an estimator adds to every cell's row beside the evaluation's (``pipeline.METRICS``), as
#: its adapter in ``estimators.py`` returns them (a name ending in '*' is a prefix: vio's gating counts).
ESTIMATOR_METRICS: dict[str, tuple[str, ...]] = {
    "map2d": (
        "map_far_pct",
        "map_wall_thickness_cm",
        "map_hit_rms_cm",
        "map_hit_wall_width_cm",
        "loop_error_m",
        "loop_error_deg",
    ),
    "vio": ("gate_rejected_*",),
    "lio": ("lio_scans_per_s",),
}


def check_estimator_configs(study: StudyConfig, source: str = "<study>") -> None:
    """An estimator's ``options.config`` (further fields of its own configuration model) is validated
    when the study is loaded, not in every cell (where a bad field would fail them all)."""
    from pydantic import BaseModel, ValidationError

    from imuslam.config import describe_validation_error

    def model(name: str) -> type[BaseModel] | None:
        if name == "lio":
            from imuslam.lio.config import LioConfig

            return LioConfig
        if name == "vio":
            from imuslam.vio.config import VioConfig

            return VioConfig
        if name == "map2d":
            from imuslam.slam2d.config import Slam2dConfig

            return Slam2dConfig
        return None

    for k, c in enumerate(study.claims):
        for i, e in enumerate(c.estimators):
            m, cfg = model(e.name), e.options.get("config")
            if m is None or not isinstance(cfg, dict):
                continue
            try:
                m.model_validate(cfg)
            except ValidationError as exc:
                raise InputError(
                    f"{source}: claims[{k}] ({c.name}).estimators[{i}] ({e.name}).options.config: "
                    f"{describe_validation_error(exc)}"
                ) from None


def check_metrics(study: StudyConfig, source: str = "<study>") -> None:
    """Every claim's metric is one its cells report (else the claim could never be resolved)."""
    for k, c in enumerate(study.claims):
        known = list(METRICS)
        for e in c.estimators:
            known += ESTIMATOR_METRICS.get(e.name, ())
        if not any(
            c.metric == m or (m.endswith("*") and c.metric.startswith(m[:-1])) for m in known
        ):
            raise InputError(
                f"{source}: claims[{k}] ({c.name}).metric: unknown metric '{c.metric}'; expected one of "
                f"{', '.join(dict.fromkeys(known))}"
            )


@dataclass
class StudyRun:
    """The results table (one row per cell, in the study's order) and where it was written."""

    table: pd.DataFrame
    out_dir: Path | None
    n_cached: int
    n_run: int
    backend: str
    worker_cpu_s: dict[str, float] = field(default_factory=dict)
    """CPU seconds each Dask worker process used (start-up included); this process's for --serial."""


def plan(study: StudyConfig, source: str = "<study>") -> list[Cell]:
    """The study's cells, after checking every estimator, option, scenario and metric (InputError
    otherwise)."""
    check_study(study, source)
    check_metrics(study, source)
    check_estimator_configs(study, source)
    cells = expand(study)
    if not cells:
        raise ValueError(f"{source}: the study has no cells")
    return cells


@contextmanager
def dask_client(scheduler: str | None, workers: int | None) -> Iterator[Any]:
    """A client of ``scheduler`` (an address), or of a new in-process LocalCluster of ``workers``
    single-threaded worker processes (default: one per core), with :data:`WORKER_ENV`."""
    import dask
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
    # the Nanny takes its pre-spawn environment from this process's os.environ where a variable is set
    # there (a user's OMP_NUM_THREADS=8 would win): set ours here while the workers are spawned, then
    # give this process its own environment back
    pre = {**dask.config.get("distributed.nanny.pre-spawn-environ", default={}), **WORKER_ENV}
    saved = {k: os.environ.get(k) for k in pre}
    os.environ.update(WORKER_ENV)
    try:
        with (
            dask.config.set({"distributed.nanny.pre-spawn-environ": pre}),
            warnings.catch_warnings(),
        ):
            # the scheduler's HTTP server (no dashboard) moves to a free port when 8787 is taken
            warnings.filterwarnings("ignore", message="Port .* is already in use")
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                   dashboard_address=None, silence_logs=logging.CRITICAL)  # fmt: skip
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    with cluster, Client(cluster) as client:
        client.run(_ignore_sigint)
        yield client


def _ignore_sigint() -> bool:
    """In a local worker process: leave Ctrl-C (sent to the whole process group) to the study's own
    process, which cancels the cells and closes the cluster; the workers then end without a traceback."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        return False
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    return True


def worker_cpu_s(client: Any) -> dict[str, float]:
    """CPU seconds (user + system) each worker process has used since it started."""

    def cpu() -> float:
        import resource

        r = resource.getrusage(resource.RUSAGE_SELF)
        return r.ru_utime + r.ru_stime

    return {str(k): float(v) for k, v in client.run(cpu).items()}


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
    client_factory: Callable[[], Any] | None = None,
) -> tuple[dict[str, dict[str, Any]], int, str, dict[str, float]]:
    """Rows by cell key for every distinct cell (from the cache or run); the number taken from the
    cache; the backend used; CPU seconds by worker (see :attr:`StudyRun.worker_cpu_s`).
    ``client_factory``: returns the Dask client to use (one kept open over several calls); default: a
    client of ``scheduler`` or of a new local cluster, closed on return."""
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
        return rows, n_cached, "cache", {}
    if serial:
        cpu0 = time.process_time()
        backend = "serial"
        cals: dict[tuple[float, int], Any] = {}
        shared: dict[str, Any] = {}
        # closed on any exit, so that an error or an interrupt is printed on a line of its own
        with tqdm(total=len(pending), unit="cell", desc="study", disable=not progress) as bar:
            for c in pending:
                need = calibration_need(c)
                if need is not None and need not in cals:
                    cals[need] = calibration_task(c.drift.model_dump(), *need)
                sh = shared_need(c)
                if sh is not None and sh[0] not in shared:
                    shared.clear()  # one at a time: cells that share work are adjacent in the study
                    shared[sh[0]] = shared_task(sh[1], *sh[2])
                rows[c.key] = run_cell(c, None if need is None else cals[need],
                                       None if sh is None else shared[sh[0]])  # fmt: skip
                _store(out, c, rows[c.key])
                bar.update()
        return rows, n_cached, backend, {"serial": time.process_time() - cpu0}
    ctx = nullcontext(client_factory()) if client_factory else dask_client(scheduler, workers)
    with ctx as client:
        from distributed import as_completed

        n_workers = len(client.scheduler_info()["workers"])
        backend = f"dask {scheduler if scheduler else 'LocalCluster'} ({n_workers} workers)"
        bar = tqdm(total=len(pending), unit="cell", desc="study", disable=not progress)
        # longest first: a cell's priority is its expected CPU time; calibrations and shared work
        # come before everything that waits for them (Dask runs the ready task of highest priority)
        cost = {c.key: cell_cost(c) for c in pending}
        top = 1.0 + sum(cost.values())
        cal_futures: dict[tuple[float, int], Any] = {}
        shared_futures: dict[str, Any] = {}
        futures = {}
        for c in sorted(pending, key=lambda c: -cost[c.key]):
            need = calibration_need(c)
            if need is not None and need not in cal_futures:
                cal_futures[need] = client.submit(
                    calibration_task, c.drift.model_dump(), *need, priority=top + CALIBRATION_CPU_S,
                    key=f"calibration-{need[1]:x}-{need[0]:g}h-{c.key}",
                )  # fmt: skip
            sh = shared_need(c)
            if sh is not None and sh[0] not in shared_futures:
                shared_futures[sh[0]] = client.submit(
                    shared_task, sh[1], *sh[2], key=f"shared-{sh[0]}", priority=top + cost[c.key]
                )
            fut = client.submit(run_cell, c.model_dump(mode="json"),
                                None if need is None else cal_futures[need],
                                None if sh is None else shared_futures[sh[0]], key=f"cell-{c.key}",
                                priority=cost[c.key])  # fmt: skip
            futures[fut] = c
        try:
            for fut in as_completed(list(futures)):
                c = futures[fut]
                try:
                    row = fut.result()
                except Exception as exc:  # a worker died, a task was lost: record it, go on
                    raise_if_interrupted(exc)
                    row = {"key": c.key, **c.label, "status": "error",
                           "error": f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"[:500]}  # fmt: skip
                rows[c.key] = row
                _store(out, c, row)
                bar.update()
                fut.release()
        except (
            BaseException
        ):  # an interrupt: the cells done so far stay in the cache, the rest stop
            client.cancel([*futures, *cal_futures.values(), *shared_futures.values()])
            raise
        finally:
            bar.close()
        cpu = worker_cpu_s(client)
    return rows, n_cached, backend, cpu


def next_seeds(
    study: StudyConfig, df: pd.DataFrame, seeds: dict[str, list[int]]
) -> dict[str, list[int]]:
    """The claims that need another look (a pair not resolved, seeds left in the budget), each with its
    seeds for that look (the next batch of its schedule added)."""
    from imuslam.study.report import analyse, seed_plan
    from imuslam.study.sequential import FEW, OPEN

    more = {}
    for c in study.claims:
        have = seeds[c.name]
        if c.max_seeds is None or len(have) >= c.max_seeds:
            continue
        if any(p.verdict in (OPEN, FEW) for p in analyse(c, df, study.seeds).pairs):
            order, sizes = seed_plan(c, study.seeds)
            n = next(k for k in sizes if k > len(have))
            more[c.name] = order[:n]
    return more


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
    if out is not None:
        from imuslam.io.results import check_out_dir

        check_out_dir(out, "folder")
    rows: dict[str, dict[str, Any]] = {}
    n_cached, backend = 0, "cache"
    cpu: dict[str, float] = {}
    seeds = {c.name: c.first_seeds(study.seeds) for c in study.claims}
    with ExitStack() as stack:
        clients: list[Any] = []

        def client() -> Any:  # one cluster for every look, started when a cell first needs it
            if not clients:
                clients.append(stack.enter_context(dask_client(scheduler, workers)))
            return clients[0]

        while True:
            new = [c for c in cells if c.key not in rows]
            if new:
                got, n_c, be, cp = execute(new, out, scheduler, workers, serial, progress,
                                           None if serial else client)  # fmt: skip
                rows.update(got)
                n_cached += n_c
                backend = be if be != "cache" else backend
                # serial: this process's CPU per round; Dask: each worker's since it started
                cpu = {k: cpu.get(k, 0.0) + v for k, v in cp.items()} if serial else (cp or cpu)
            more = next_seeds(study, table(cells, rows), seeds)
            if not more:
                break
            for name, s in more.items():
                log.info("claim %s: unresolved after %d seeds, %d more", name, len(seeds[name]),
                         len(s) - len(seeds[name]))  # fmt: skip
            seeds.update(more)
            cells = expand(study, seeds)
    df = table(cells, rows)
    if out is not None:
        from imuslam.io.results import results_folder
        from imuslam.study.report import write_outputs

        with results_folder(out) as tmp:  # the report's files all at once, beside the cells/ cache
            write_outputs(study, df, tmp, backend)
    return StudyRun(df, out, n_cached, len(rows) - n_cached, backend, cpu)
