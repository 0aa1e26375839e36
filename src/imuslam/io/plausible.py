"""Is a log that was read what it says it is? Units and stamps checked against what the platform can do.

A value in the wrong unit passes every reader (200 deg/s is a valid float), and the estimators then
turn it into a confident wrong answer (a gyro in deg/s read as rad/s turns a car's trajectory by tens
of degrees a second). These checks refuse such a log, naming the unit, before any estimate is made.
They are the tests ``imuslam calibrate`` and ``correct`` apply (``ImuCalibration.check_magnitudes``:
the median |accel| near g and the 99th percentile of |omega| below a bound), with the bound of the
platform instead of a gyro's full range.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.interfaces.imu import ImuLog

G0 = 9.80665
#: The angular rate, rad/s, that 1 % of a navigation log's samples may exceed at most: 8 rad/s is
#: 460 deg/s, beyond any car, robot, drone in normal flight or person carrying a sensor (the real logs
#: here: a Husky 0.41, a backpack 0.65, EuRoC's drone 0.73-1.6 rad/s). The same log in deg/s read as
#: rad/s shows 23-94 "rad/s".
NAV_MAX_RATE_RAD_S = 8.0
#: The largest mean rate, rad/s, a gyro at rest reads (its bias and the earth's rate): 0.5 rad/s is
#: 29 deg/s, beyond the zero-rate tolerance of any MEMS gyro (the MPU6050's +-20 deg/s is among the
#: widest); a gyro in deg/s read as rad/s with a bias over 0.5 deg/s exceeds it.
MAX_REST_RATE_RAD_S = 0.5
#: The largest white-noise density, rad/s/sqrt(Hz), of any MEMS gyro (0.2 deg/s/sqrt(Hz): about 4x the
#: noisiest datasheet, 20-40x a consumer part's 0.005-0.01); a gyro in deg/s read as rad/s shows
#: 57x its density in rad/s.
MAX_GYRO_WHITE_RAD_S_RTHZ = float(np.deg2rad(0.2))


def _si_gyro(log: ImuLog) -> NDArray[np.float64]:
    return np.asarray(log.gyro) * (np.pi / 180.0 if log.gyro_unit == "deg/s" else 1.0)


def check_units(
    log: ImuLog,
    platform: str = "a vehicle, robot, drone or person",
    max_rate_rad_s: float = NAV_MAX_RATE_RAD_S,
    hint: str = "",
) -> None:
    """InputError when the log cannot be in its declared units: the median |accel| is not near g
    (0.5 to 2 g: still, driving or walking), or 1 % of the angular rates exceed what ``platform`` can
    turn at (``max_rate_rad_s``). Raw counts are not checked (any scale). ``hint`` ends the message
    (the option or field that sets the unit)."""
    if len(log) == 0:
        return
    tail = f"; {hint}" if hint else ""
    if log.accel_unit != "counts":
        a = np.asarray(log.accel) * (G0 if log.accel_unit == "g" else 1.0)
        na = float(np.median(np.linalg.norm(a, axis=1)))
        if not 0.5 * G0 <= na <= 2.0 * G0:
            like = " (it looks like g)" if 0.5 <= na <= 2.0 else ""
            raise InputError(
                f"{log.source}: the accelerations have a median magnitude of {na:.4g} m/s^2 where "
                f"gravity is {G0:g}: the accelerometer is not in {log.accel_unit}{like}{tail}"
            )
    if log.gyro_unit != "counts":
        ng = float(np.quantile(np.linalg.norm(_si_gyro(log), axis=1), 0.99))
        if not ng <= max_rate_rad_s:
            like = " (it looks like deg/s)" if log.gyro_unit == "rad/s" else ""
            raise InputError(
                f"{log.source}: 1 % of the angular rates exceed {ng:.4g} rad/s ({np.rad2deg(ng):.0f} "
                f"deg/s), more than {platform} turns at ({max_rate_rad_s:g} rad/s): the gyro is not "
                f"in {log.gyro_unit}{like}{tail}"
            )


def check_at_rest(log: ImuLog, t_still_s: float, hint: str = "") -> None:
    """InputError when the gyro's mean over the first ``t_still_s`` (the IMU at rest) exceeds
    :data:`MAX_REST_RATE_RAD_S` in its declared unit: a gyro in deg/s read as rad/s, or an IMU
    that was not still."""
    if log.gyro_unit == "counts" or len(log) == 0:
        return
    k = int(np.searchsorted(log.t_ns, log.t_ns[0] + int(t_still_s * 1e9), side="right"))
    mean = float(np.linalg.norm(_si_gyro(log)[: max(k, 1)].mean(axis=0)))
    if not mean <= MAX_REST_RATE_RAD_S:
        like = " (it looks like deg/s)" if log.gyro_unit == "rad/s" else ""
        raise InputError(
            f"{log.source}: over the still start ({t_still_s:g} s) the gyro reads {mean:.4g} rad/s "
            f"({np.rad2deg(mean):.0f} deg/s) on average, more than any gyro at rest "
            f"({MAX_REST_RATE_RAD_S:g} rad/s of bias): the gyro is not in {log.gyro_unit}{like}, "
            "or the IMU was not still" + (f"; {hint}" if hint else "")
        )


def check_gyro_noise(white_rad_s_rthz: float, source: str, gyro_unit: str, hint: str = "") -> None:
    """InputError when a gyro's white-noise density (Allan deviation at 1 s), converted to rad/s
    from ``gyro_unit``, exceeds any MEMS gyro's (:data:`MAX_GYRO_WHITE_RAD_S_RTHZ`): a still log in
    deg/s read as rad/s."""
    if gyro_unit == "counts" or not white_rad_s_rthz > MAX_GYRO_WHITE_RAD_S_RTHZ:
        return
    like = " (it looks like deg/s)" if gyro_unit == "rad/s" else ""
    raise InputError(
        f"{source}: the gyro's white noise comes out {white_rad_s_rthz:.3g} rad/s/sqrt(Hz) "
        f"({np.rad2deg(white_rad_s_rthz):.3g} deg/s/sqrt(Hz)), more than any MEMS gyro's "
        f"({MAX_GYRO_WHITE_RAD_S_RTHZ:.3g}): the gyro is not in {gyro_unit}{like}"
        + (f"; {hint}" if hint else "")
    )


def check_stamps(
    t_ns: NDArray[np.int64], what: str, source: str, max_fraction: float = 0.1
) -> None:
    """InputError when ``what`` (e.g. "scans") share their stamps: all one time, or more than
    ``max_fraction`` of them stamped as the one before (a log whose time field was not recorded;
    every duration, speed and rate computed from it would be wrong)."""
    t = np.asarray(t_ns, dtype=np.int64)
    if len(t) < 2:
        return
    same = np.flatnonzero(np.diff(t) == 0)
    if t.max() == t.min() or same.size > max_fraction * len(t):
        raise InputError(
            f"{source}: {same.size} of {len(t)} {what} carry the same stamp as the one before "
            f"(first: {what.rstrip('s')} {int(same[0]) + 1}, t = {t[same[0]] * 1e-9:.3f} s); "
            f"expected a time per {what.rstrip('s')}"
        )
