"""MATLAB v7.3 (HDF5) IMU buffers: ``accelBuffer`` / ``gyroBuffer`` arrays of 4 x N rows (t, x, y, z).

This is the layout of the MPU6050 logs of the sensor-fusion data sets (accelerometer in g, gyro in
deg/s, time in s). The two buffers share their stamps.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from imuslam.errors import InputError
from imuslam.interfaces.imu import AccelUnit, GyroUnit, ImuLog
from imuslam.io.timestamps import check_and_repair


def _buffer(path: Path, key: str) -> np.ndarray:
    import h5py

    try:
        with h5py.File(path, "r") as h:
            if key not in h:
                raise InputError(f"{path}: no variable '{key}' (found {', '.join(h.keys())})")
            d = np.asarray(h[key], dtype=float)
    except OSError as exc:
        raise InputError(f"{path}: not a MATLAB v7.3 (HDF5) file: {exc}") from exc
    if d.ndim != 2 or 4 not in d.shape:
        raise InputError(f"{path}: '{key}' must be 4 x N (t, x, y, z); got {d.shape}")
    return d if d.shape[0] == 4 else d.T


def read_mat_buffers(
    acc_path: str | Path,
    gyro_path: str | Path,
    accel_unit: AccelUnit = "g",
    gyro_unit: GyroUnit = "deg/s",
) -> ImuLog:
    """Read ``accelBuffer`` and ``gyroBuffer`` from two v7.3 .mat files into one log."""
    a = _buffer(Path(acc_path), "accelBuffer")
    g = _buffer(Path(gyro_path), "gyroBuffer")
    src = f"{acc_path} + {gyro_path}"
    n = min(a.shape[1], g.shape[1])
    if not np.allclose(a[0, :n], g[0, :n]):
        raise InputError(
            f"{src}: the accelerometer and gyro buffers do not share their time stamps"
        )
    t_ns = np.round((a[0, :n] - a[0, 0]) * 1e9).astype(np.int64)
    tc = check_and_repair(t_ns, src)
    return ImuLog(tc.t_ns, a[1:, :n].T, g[1:, :n].T, accel_unit, gyro_unit, src, list(tc.warnings))
