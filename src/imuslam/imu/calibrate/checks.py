"""Checks of the calibration's input and output: the log, the declared units, the covariance and the
observability verdict."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.imu.model import ACCEL_PARAM_NAMES, GYRO_PARAM_NAMES
from imuslam.interfaces.imu import ImuLog

FloatArray = NDArray[np.float64]


def check_log(log_: ImuLog) -> None:
    n = len(log_)
    if n == 0:
        raise InputError(f"{log_.source}: the log is empty")
    for name, x in (("accel", log_.accel), ("gyro", log_.gyro)):
        bad = ~np.isfinite(x).all(axis=1)
        if bad.any():
            raise InputError(f"{log_.source}: {name} sample {int(np.argmax(bad))} is not finite")
    dt = np.diff(log_.t_ns)
    if np.any(dt <= 0):
        i = int(np.argmax(dt <= 0))
        raise InputError(f"{log_.source}: time is not strictly increasing at sample {i + 1}")
    # Saturation: a clipped axis sits exactly at its extreme value for many samples.
    for name, x in (("accel", log_.accel), ("gyro", log_.gyro)):
        for j, ax in enumerate("xyz"):
            col = x[:, j]
            for extreme in (col.max(), col.min()):
                hits = int(np.count_nonzero(col == extreme))
                if hits > max(10, n // 200):
                    raise InputError(
                        f"{log_.source}: {name} {ax} axis is saturated ({hits} samples at {extreme:g}): "
                        "the sensor's range was exceeded, those poses cannot be used"
                    )


#: SI per unit: a calibrated scale K (SI per raw unit) of a log in one of these is near its value.
_UNIT_SI = {"m/s^2": 1.0, "g": 9.80665, "rad/s": 1.0, "deg/s": np.pi / 180.0}


def check_units(K: FloatArray, sensor: str, unit: str, option: str, source: str) -> None:
    """InputError when the fitted scale says the log is not in its declared unit: a gyro in deg/s
    declared rad/s fits K = 0.0175 (pi/180), which would otherwise be reported as a scale error of
    98 %. Low-cost MEMS scale errors are a few percent; [0.7, 1.4] x the unit's factor is accepted."""
    if unit not in _UNIT_SI:
        return  # raw counts: any scale
    k = float(np.mean(K))
    ratio = k / _UNIT_SI[unit]
    if 0.7 <= ratio <= 1.4:
        return
    si, candidates = (
        ("m/s^2", ("m/s^2", "g")) if sensor == "accelerometer" else ("rad/s", ("rad/s", "deg/s"))
    )
    like = [u for u in candidates if u != unit and 0.7 <= k / _UNIT_SI[u] <= 1.4]
    hint = (
        f"the data look like {like[0]} (give {option} {like[0]})"
        if like
        else (f"the data look like raw counts (give {option} counts)")
    )
    raise InputError(
        f"{source}: the {sensor} scale came out {k:.4g} {si} per {unit}, {ratio:.3g} x the expected "
        f"{_UNIT_SI[unit]:.4g}: the {sensor} is not in {unit}; {hint}"
    )


def std_or_inf(var: np.ndarray) -> np.ndarray:
    """Standard deviations from variances; a non-positive variance (undetermined) gives inf."""
    var = np.asarray(var, dtype=np.float64)
    return np.where(var > 0.0, np.sqrt(np.where(var > 0.0, var, 1.0)), np.inf)


def verdict(
    std_a: FloatArray, std_g: FloatArray, theta_a: FloatArray, theta_g: FloatArray, n_poses: int
) -> list[str]:
    """Names of poorly determined parameters: angles worse than 1 mrad (accel) / 2 mrad (gyro),
    scale worse than 0.1 % (accel) / 0.5 % (gyro), accel bias worse than 0.02 m/s^2."""
    poor: list[str] = []
    lim_a = np.concatenate(
        [np.full(3, 1e-3), np.abs(theta_a[3:6]) * 1e-3, 0.02 / np.abs(theta_a[3:6])]
    )
    lim_g = np.concatenate([np.full(6, 2e-3), np.abs(theta_g[6:9]) * 5e-3])
    poor += [nm for nm, s, lim in zip(ACCEL_PARAM_NAMES, std_a, lim_a, strict=True) if not s <= lim]
    poor += [nm for nm, s, lim in zip(GYRO_PARAM_NAMES, std_g, lim_g, strict=True) if not s <= lim]
    return poor


def residual_covariance(J: FloatArray, r: FloatArray, dof: int) -> FloatArray:
    s2 = float(r @ r) / max(dof, 1)
    try:
        return np.asarray(s2 * np.linalg.inv(J.T @ J), dtype=np.float64)
    except np.linalg.LinAlgError:
        return np.full((J.shape[1], J.shape[1]), np.inf)
