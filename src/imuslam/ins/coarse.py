"""Coarse alignment on a static base: levelling from the mean specific force, heading by gyrocompassing
where the gyro can see the earth's rate, or from a given heading source.

With R_n_b = Rz(yaw) Ry(pitch) Rx(roll) and f_b = R_n_b^T [0, 0, g] at rest:
roll = atan2(f_y, f_z), pitch = atan2(-f_x, sqrt(f_y^2 + f_z^2)) (Titterton & Weston, eq. 10.3). The
levelled rate is Rz(yaw)^T Omega [0, cos L, sin L], so yaw = atan2(w_x, w_y) of the levelled rate
(gyrocompassing, eq. 10.7). Its error is about (gyro bias + noise) / (Omega cos L): a MEMS gyro with
0.1 deg/s of bias sees 15 deg/h of earth rate as noise 24 times larger, so heading is unobservable.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.geometry.euler import euler_to_matrix
from imuslam.ins.strapdown import EARTH_RATE

FloatArray = NDArray[np.float64]


@dataclass
class CoarseAlignment:
    """roll, pitch, yaw (rad; yaw None when unobservable), their 1-sigma, R_n_b and the reason."""

    roll: float
    pitch: float
    yaw: float | None
    roll_pitch_std: float
    yaw_std: float | None
    heading_observable: bool
    reason: str
    R_n_b: FloatArray


def coarse_align(
    accel_b: FloatArray,
    gyro_b: FloatArray,
    rate_hz: float,
    lat_rad: float | None = None,
    gyro_bias_std: float = np.deg2rad(0.1),
    accel_bias_std: float = 0.05,
    heading_rad: float | None = None,
    max_yaw_std: float = np.deg2rad(5.0),
) -> CoarseAlignment:
    """Static-base alignment from N samples (accel m/s^2, gyro rad/s, body frame).

    gyro_bias_std / accel_bias_std: the sensors' bias uncertainty, which limits the result:
    roll/pitch to about accel_bias / g, yaw to about gyro_bias / (Omega cos L).
    """
    f = np.asarray(accel_b, float)
    w = np.asarray(gyro_b, float)
    n = len(f)
    if n < 10:
        raise InputError(
            f"{n} samples: coarse alignment needs a still period of at least 10 samples"
        )
    fm = f.mean(axis=0)
    wm = w.mean(axis=0)
    g = float(np.linalg.norm(fm))
    if np.max(np.std(f, axis=0)) > 0.5 or not 5.0 < g < 15.0:
        raise InputError("the base is not still: specific force varies or its norm is not near g")
    roll = float(np.arctan2(fm[1], fm[2]))
    pitch = float(np.arctan2(-fm[0], np.hypot(fm[1], fm[2])))
    rp_std = float(np.hypot(accel_bias_std, np.std(f) / np.sqrt(n)) / g)
    yaw: float | None = None
    yaw_std: float | None = None
    observable = False
    if heading_rad is not None:
        yaw, yaw_std, observable, reason = (
            float(heading_rad),
            0.0,
            True,
            "heading from the given source",
        )
    elif lat_rad is not None:
        horiz = EARTH_RATE * np.cos(lat_rad)
        yaw_std = float(np.hypot(gyro_bias_std, np.mean(np.std(w, axis=0)) / np.sqrt(n)) / horiz)
        Rl = euler_to_matrix(np.array([[roll, pitch, 0.0]]))[0]
        wl = Rl @ wm
        if yaw_std <= max_yaw_std:
            yaw, observable = float(np.arctan2(wl[0], wl[1])), True
            reason = f"gyrocompassing at latitude {np.rad2deg(lat_rad):.1f} deg"
        else:
            reason = (
                f"heading unobservable: the gyro's bias uncertainty ({np.rad2deg(gyro_bias_std) * 3600:.0f} deg/h) "
                f"swamps the horizontal earth rate ({np.rad2deg(horiz) * 3600:.1f} deg/h); give a heading source"
            )
    else:
        reason = "heading unobservable: no latitude for gyrocompassing and no heading source"
    R = euler_to_matrix(np.array([[roll, pitch, yaw if yaw is not None else 0.0]]))[0]
    return CoarseAlignment(roll, pitch, yaw, rp_std, yaw_std, observable, reason, R)


def level_rotation(f_b: FloatArray) -> FloatArray:
    """R_w_b (3, 3) with zero yaw whose z axis is along the mean specific force ``f_b`` (3,), or of the
    mean of (N, 3) samples: static levelling, roll and pitch from the accelerometers (Titterton & Weston,
    eq. 10.3), R = Ry(pitch) Rx(roll). The one levelling of every estimator's initial attitude."""
    f = np.asarray(f_b, float)
    if f.ndim == 2:
        f = f.mean(axis=0)
    f = f / np.linalg.norm(f)
    roll = np.arctan2(f[1], f[2])
    pitch = np.arctan2(-f[0], np.hypot(f[1], f[2]))
    cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return Ry @ Rx
