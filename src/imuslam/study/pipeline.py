"""One cell, end to end: simulate -> calibrate -> align -> estimate -> evaluate -> a row.

Timeline: the simulated drive lasts ``align.duration_s + scenario.duration_s``. Over the alignment window
the IMU gets position fixes (``align.fix_rate_hz``, ``align.fix_std_m``); the aligning filter (KF, STKF or
RWNN, ``ins/align.py``) starts from the true position and velocity and an attitude off by a seeded
draw of ``align.init_attitude_err_deg`` (what coarse levelling and a rough heading leave). The run
starts where the alignment ends, from the true position and velocity and the aligned attitude, with
the estimated biases removed from the IMU. Without alignment (``none``) it starts with the initial
attitude error and no bias estimate (LINS in seed 001). The estimator runs over the rest; its poses are
evaluated against the truth (APE/RPE, ``eval/metrics.py``).
"""

from __future__ import annotations

import copy
import time
from collections import OrderedDict
from typing import Any

import numpy as np

from imuslam.errors import EstimatorError, raise_if_interrupted
from imuslam.eval.metrics import evaluate
from imuslam.geometry import exp as so3_exp
from imuslam.geometry import log as so3_log
from imuslam.imu.model import ImuCalibration
from imuslam.ins.align import Aiding, run_alignment
from imuslam.ins.kf import KfNoise
from imuslam.interfaces import NavState, Trajectory
from imuslam.sim.imu import simulate_imu
from imuslam.sim.trajectory import (
    EulerTrajectory,
)
from imuslam.study.cells import Cell, digest
from imuslam.study.conditions import calibration_age_h, gimbal_calibration, sensor_spec
from imuslam.study.config import DriftSpec
from imuslam.study.estimators import CellInput, get_estimator
from imuslam.study.scenes import scene

G = 9.80665
METRICS = ("ape_rmse_m", "ape_max_m", "ape_rot_rmse_deg", "rpe_trans_rmse_m", "rpe_rot_rmse_deg",
           "final_err_m", "path_length_m", "align_att_err_deg", "align_heading_err_deg")  # fmt: skip
STAGES = ("simulate", "calibrate", "align", "estimate", "evaluate")


# (raw IMU log, truth) of the scenes this process simulated last, by content hash: the cells that
# differ only after the simulation (alignment method, estimator variant) simulate their scene once
_SCENE_CACHE: OrderedDict[str, Any] = OrderedDict()
_SCENE_CACHE_SIZE = 8


def scene_key(cell: Cell) -> str:
    """Content hash of everything that decides a cell's simulated IMU log and truth."""
    c = cell.content()
    return digest(["imu-scene", cell.world_seed(), c["scenario"], c["align"]["duration_s"],
                   cell.imu, c.get("drift")])  # fmt: skip


def simulate_scene(cell: Cell, traj: EulerTrajectory, rate_hz: float) -> tuple[Any, Any]:
    """The cell's raw IMU log and truth over the alignment window and the run (kept per process by
    :func:`scene_key`; a copy is returned, so an estimator cannot change what the next cell gets)."""
    key = scene_key(cell)
    hit = _SCENE_CACHE.get(key)
    if hit is None:
        total = cell.align.duration_s + cell.scenario.duration_s
        spec = sensor_spec(cell.imu, cell.drift, total)
        hit = simulate_imu(traj, total, cell.world_rng("imu"), spec, rate_hz, g=G)
        _SCENE_CACHE[key] = hit
        while len(_SCENE_CACHE) > _SCENE_CACHE_SIZE:
            _SCENE_CACHE.popitem(last=False)
    else:
        _SCENE_CACHE.move_to_end(key)
    return copy.deepcopy(hit)


def cell_cost(cell: Cell) -> float:
    """Expected CPU seconds of a cell (for scheduling the longest first), from the estimator's
    measured cost per simulated second (``EstimatorEntry.cpu_per_s``) and the alignment filter's."""
    entry = get_estimator(cell.estimator.name)
    align_s = 0.0 if cell.alignment == "none" or entry.own_alignment else cell.align.duration_s
    return 0.05 + ALIGN_CPU_PER_S * align_s + entry.cpu_per_s * cell.scenario.duration_s


ALIGN_CPU_PER_S = 0.004  # KF / STKF / RWNN alignment at 100-200 Hz, CPU s per second of log
CALIBRATION_CPU_S = 2.0  # one 40-pose gimbal calibration


def calibration_need(cell: Cell) -> tuple[float, int] | None:
    """(age of the errors, gimbal-log seed) of the calibration the cell's IMU condition uses, or None."""
    age = calibration_age_h(cell.imu, cell.drift)
    return None if age is None else (age, cell.calibration_seed(age))


def calibration_task(drift: dict[str, Any], age_h: float, seed: int) -> ImuCalibration | str:
    """The gimbal calibration (a task of its own: the cells of one seed share it), or its error line."""
    try:
        return gimbal_calibration(DriftSpec.model_validate(drift), age_h, seed)
    except Exception as exc:
        raise_if_interrupted(exc)
        return f"calibration failed: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"


def shared_need(cell: Cell) -> tuple[str, Any, tuple[Any, ...]] | None:
    """(key, fn, args) of the estimator's shared work for this cell, or None."""
    entry = get_estimator(cell.estimator.name)
    return entry.prepare(cell) if entry.prepare is not None else None


def shared_task(fn: Any, *args: Any) -> Any:
    """Run shared work; an error becomes its line (a str), recorded by each cell that needed it."""
    try:
        return fn(*args)
    except Exception as exc:
        raise_if_interrupted(exc)
        return SharedError(f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}")


class SharedError(str):
    """The error line of failed shared work."""


def _run(
    cell: Cell, calibration: ImuCalibration | str | None, shared: Any = None
) -> tuple[dict[str, float], dict[str, float]]:
    timings: dict[str, float] = {}
    clock = [time.perf_counter()]

    def lap(stage: str) -> None:
        now = time.perf_counter()
        timings[stage] = now - clock[0]
        clock[0] = now

    entry = get_estimator(cell.estimator.name)
    assert entry.run is not None
    if shared is None and entry.prepare is not None:
        sh = entry.prepare(cell)
        shared = None if sh is None else shared_task(sh[1], *sh[2])
    if isinstance(shared, SharedError):
        raise EstimatorError(f"shared step failed ({shared})")
    options = entry.options.model_validate(cell.estimator.options)
    traj, world, rate = scene(cell.scenario.name)
    a = cell.align
    spec = sensor_spec(cell.imu, cell.drift, a.duration_s + cell.scenario.duration_s)
    raw, truth = simulate_scene(cell, traj, rate)
    lap("simulate")

    need = calibration_need(cell)
    if need is not None and calibration is None:
        calibration = calibration_task(cell.drift.model_dump(), *need)
    if isinstance(calibration, str):
        raise EstimatorError(calibration)
    log = raw if need is None or calibration is None else calibration.correct(raw)
    lap("calibrate")

    rng_a = cell.world_rng("align")
    att_err = np.deg2rad(np.asarray(a.init_attitude_err_deg)) * rng_a.normal(size=3)
    t_fix = np.arange(1.0, a.duration_s * a.fix_rate_hz + 1e-9) / a.fix_rate_hz
    fixes = traj.state(t_fix).p_w + rng_a.normal(size=(len(t_fix), 3)) * a.fix_std_m
    t = log.t_s
    k0 = int(np.searchsorted(t, a.duration_s))
    if cell.alignment == "none" or entry.own_alignment:
        k_start, R0 = k0, so3_exp(att_err) @ truth.R_w_i[k0]
    else:
        init = NavState(truth.p_w[0], truth.vel_w[0], so3_exp(att_err) @ truth.R_w_i[0])
        noise = KfNoise(spec.accel_density, spec.gyro_density, 1e-4, 1e-5)
        method = cell.alignment.removesuffix("_attitude")
        res = run_alignment(log.slice(0, k0 + 1), Aiding(t_fix, "position", fixes, a.fix_std_m), init,
                            method, noise, g=G)  # type: ignore[arg-type]  # fmt: skip
        k_start = int(np.searchsorted(t, res.t_s[-1]))
        R0 = res.final.R_n_b
        if method == cell.alignment:  # kf_attitude keeps the calibration's biases
            log = res.corrected(log)
    dR = so3_log(truth.R_w_i[k_start].T @ R0)
    lap("align")

    run_log = log.slice(k_start, len(log))
    inp = CellInput(
        cell, options, traj, world, run_log, truth, k_start, float(t[k_start]), float(t[-1]),
        NavState(truth.p_w[k_start].copy(), truth.vel_w[k_start].copy(), R0), G,
        np.random.default_rng(cell.estimator_seed()), shared,
    )  # fmt: skip
    est = entry.run(inp)
    lap("estimate")

    st = traj.state(est.traj.t_ns * 1e-9)
    ref = Trajectory(est.traj.t_ns, st.p_w, st.R_w_b, "truth")
    rate_est = (len(est.traj) - 1) / max((est.traj.t_ns[-1] - est.traj.t_ns[0]) * 1e-9, 1e-9)
    ev = evaluate(ref, est.traj, cell.eval_align, rpe_delta=max(1.0, round(rate_est)),  # type: ignore[arg-type]
                        rpe_unit="frames", by_index=True)  # fmt: skip
    r, e = ev.reference, ev.estimate_aligned
    assert r is not None and e is not None
    metrics = {
        "ape_rmse_m": ev.ape_trans.rmse,
        "ape_max_m": ev.ape_trans.max,
        "ape_rot_rmse_deg": ev.ape_rot_deg.rmse,
        "rpe_trans_rmse_m": ev.rpe_trans.rmse,
        "rpe_rot_rmse_deg": ev.rpe_rot_deg.rmse,
        "final_err_m": float(np.linalg.norm(e.p_w[-1] - r.p_w[-1])),
        "path_length_m": ev.path_length_m,
        "align_att_err_deg": float(np.rad2deg(np.linalg.norm(dR))),
        "align_heading_err_deg": float(np.rad2deg(abs(dR[2]))),
    }
    for k, v in est.metrics.items():
        metrics[k] = float(v)
    bad = [k for k, v in metrics.items() if not np.isfinite(v)]
    if bad:
        raise EstimatorError(f"metric {bad[0]} is not finite")  # never a silent NaN in the table
    lap("evaluate")
    return metrics, timings


def run_cell(
    cell: Cell | dict[str, Any], calibration: ImuCalibration | str | None = None, shared: Any = None
) -> dict[str, Any]:
    """The row of one cell: its factors, key, status ('ok' or 'error' with the error's one line),
    metrics and stage timings (s). Never raises for a failure of the cell itself.

    calibration: the result of :func:`calibration_task` for :func:`calibration_need` (computed here when
    not given); shared: the result of the estimator's shared work (:func:`shared_need`), likewise."""
    c = cell if isinstance(cell, Cell) else Cell.model_validate(cell)
    row: dict[str, Any] = {"key": c.key, **c.label, "status": "ok", "error": ""}
    t0, cpu0 = time.perf_counter(), time.process_time()
    try:
        metrics, timings = _run(c, calibration, shared)
    except Exception as exc:  # a failing cell is a result, not the end of the study
        raise_if_interrupted(exc)
        msg = str(exc).splitlines()[0] if str(exc) else ""
        row.update(status="error", error=f"{type(exc).__name__}: {msg}"[:500])
        metrics, timings = {m: float("nan") for m in METRICS}, {}
    row.update(metrics)
    for s in STAGES:
        row[f"t_{s}_s"] = timings.get(s, float("nan"))
    row["t_total_s"] = time.perf_counter() - t0
    row["t_cpu_s"] = time.process_time() - cpu0
    return row
