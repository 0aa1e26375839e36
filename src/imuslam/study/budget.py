"""What a free-INS study cell's error is made of: the cell re-run with one error source kept at a time.

An ``ins`` cell (``study/pipeline.py``) simulates the IMU, calibrates it (per its IMU condition), aligns
it on position fixes, subtracts the alignment's bias estimates and navigates freely from the true
position and velocity and the aligned attitude. Its position error then has three sources: the
alignment's attitude error, the residual error of the corrected IMU (its mean over the run: what the
calibration and the alignment's bias estimates left), and the IMU's noise (the rest). Each is measured
alone, the others replaced by the truth, as the RMS of the position error over the run (m):

- ``cell``: everything as the cell has it;
- ``attitude_only``: a perfect IMU from the aligned attitude;
- ``residual_only``: a perfect IMU plus the corrected log's mean residual error, from the true attitude;
- ``noise_only``: the corrected log minus its mean residual error, from the true attitude;
- ``no_alignment_bias``: the calibrated log without the alignment's bias estimates, true attitude (what
  the calibration alone leaves);
- ``perfect``: a perfect IMU from the true attitude (the integrator's own error: about 1 mm).

Also ``heading_err_deg`` / ``tilt_err_deg`` of the aligned attitude and ``gyro_z_bias_err_deg_h``, the
alignment's z-gyro bias estimate minus the truth (deg/h).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from imuslam.geometry import exp as so3_exp
from imuslam.geometry import log as so3_log
from imuslam.ins.align import Aiding, run_alignment
from imuslam.ins.kf import KfNoise
from imuslam.ins.strapdown import integrate
from imuslam.interfaces import NavState
from imuslam.study.cells import Cell
from imuslam.study.conditions import sensor_spec

FloatArray = NDArray[np.float64]


def ins_error_budget(cell: Cell) -> dict[str, float]:
    """The error sources of one ``ins`` cell with an aligning filter (see the module docstring)."""
    from imuslam.study.pipeline import G, calibration_need, calibration_task, scene, simulate_scene

    if cell.estimator.name != "ins" or cell.alignment == "none":
        raise ValueError("an error budget is for an ins cell with an alignment (kf, stkf, rwnn)")
    traj, _, rate = scene(cell.scenario.name)
    a = cell.align
    spec = sensor_spec(cell.imu, cell.drift, a.duration_s + cell.scenario.duration_s)
    raw, truth = simulate_scene(cell, traj, rate)
    need = calibration_need(cell)
    cal = None if need is None else calibration_task(cell.drift.model_dump(), *need)
    if isinstance(cal, str):
        raise RuntimeError(cal)
    log = raw if cal is None else cal.correct(raw)
    # the alignment exactly as the cell runs it (pipeline._run)
    rng_a = cell.world_rng("align")
    att_err = np.deg2rad(np.asarray(a.init_attitude_err_deg)) * rng_a.normal(size=3)
    t_fix = np.arange(1.0, a.duration_s * a.fix_rate_hz + 1e-9) / a.fix_rate_hz
    fixes = traj.state(t_fix).p_w + rng_a.normal(size=(len(t_fix), 3)) * a.fix_std_m
    k0 = int(np.searchsorted(log.t_s, a.duration_s))
    init = NavState(truth.p_w[0], truth.vel_w[0], so3_exp(att_err) @ truth.R_w_i[0])
    noise = KfNoise(spec.accel_density, spec.gyro_density, 1e-4, 1e-5)
    res = run_alignment(log.slice(0, k0 + 1), Aiding(t_fix, "position", fixes, a.fix_std_m), init,
                        cell.alignment, noise, g=G)  # type: ignore[arg-type]  # fmt: skip
    k = int(np.searchsorted(log.t_s, res.t_s[-1]))
    R0, R_true = res.final.R_n_b, truth.R_w_i[k]
    run_log = res.corrected(log).slice(k, len(log))
    cal_log = log.slice(k, len(log))
    t = run_log.t_s
    f_true, w_true = truth.accel_i[k:], truth.omega_i[k:]

    def ate(accel: FloatArray, gyro: FloatArray, R: FloatArray) -> float:
        start = NavState(truth.p_w[k].copy(), truth.vel_w[k].copy(), R)
        p, _, _ = integrate(t, accel, gyro, start, G)
        return float(np.sqrt(np.mean(np.sum((p - truth.p_w[k:]) ** 2, axis=1))))

    mean_a = np.mean(run_log.accel - f_true, axis=0)
    mean_g = np.mean(run_log.gyro - w_true, axis=0)
    dR = so3_log(R_true.T @ R0)
    return {
        "cell": ate(run_log.accel, run_log.gyro, R0),
        "attitude_only": ate(f_true, w_true, R0),
        "residual_only": ate(f_true + mean_a, w_true + mean_g, R_true),
        "noise_only": ate(run_log.accel - mean_a, run_log.gyro - mean_g, R_true),
        "no_alignment_bias": ate(cal_log.accel, cal_log.gyro, R_true),
        "perfect": ate(f_true, w_true, R_true),
        "heading_err_deg": float(np.rad2deg(dR[2])),
        "tilt_err_deg": float(np.rad2deg(np.hypot(dR[0], dR[1]))),
        "gyro_z_bias_err_deg_h": float(
            np.rad2deg(res.gyro_bias[-1][2] - truth.gyro_bias[k][2]) * 3600
        ),
    }
