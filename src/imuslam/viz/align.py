"""The alignment in a recording, on the IMU's clock (timeline ``sensor_time``): the log the filter ran
on ``imu/raw/{accel,gyro}`` and with the final biases removed ``imu/corrected/...``; the bias estimates
``align/bias/{accel,gyro}`` with their 1-sigma ``align/bias/{accel,gyro}_1sigma`` (and the truth's
``..._truth`` when given), the attitude (roll, pitch, yaw, deg, Z-Y-X) ``align/attitude_deg``, and
the filter's pose ``world/body`` with its path ``world/trajectory`` (static)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from imuslam.viz.recording import time_column

if TYPE_CHECKING:
    from imuslam.ins.pipeline import AlignOutput


def _series(rr: Any, rec: Any, path: str, t_ns: Any, v: Any, names: list[str]) -> None:
    rec.log(path, rr.SeriesLines(names=names), static=True)
    rec.send_columns(path, indexes=[time_column(rr, t_ns)],
                     columns=rr.Scalars.columns(scalars=np.asarray(v, np.float64)))  # fmt: skip


def log_alignment(rec: Any, out: AlignOutput) -> None:
    """Everything the alignment estimated (see the module's description) into ``rec``."""
    import rerun as rr

    from imuslam.geometry.euler import matrix_to_euler
    from imuslam.viz.lio import log_imu

    log_imu(rec, out.imu, "imu/raw")
    res = out.alignment
    if res is None:  # the coarse method: one attitude from the still start
        return
    log_imu(rec, res.corrected(out.imu), "imu/corrected")
    t = out.imu.t_ns[0] + np.round(res.t_s * 1e9).astype(np.int64)
    xyz = ["x", "y", "z"]
    for name, b, s, tb in (("accel", res.accel_bias, res.accel_bias_std, out.truth_accel_bias),
                           ("gyro", res.gyro_bias, res.gyro_bias_std, out.truth_gyro_bias)):  # fmt: skip
        _series(rr, rec, f"align/bias/{name}", t, b, xyz)
        _series(rr, rec, f"align/bias/{name}_1sigma", t, s, xyz)
        if tb is not None:
            _series(rr, rec, f"align/bias/{name}_truth", t, tb, xyz)
    rpy = np.rad2deg(matrix_to_euler(res.R_n_b))
    _series(rr, rec, "align/attitude_deg", t, rpy, ["roll", "pitch", "yaw"])
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rec.log("world/trajectory", rr.LineStrips3D([res.p_n], colors=[255, 140, 0]), static=True)
    rec.send_columns("world/body", indexes=[time_column(rr, t)],
                     columns=rr.Transform3D.columns(translation=res.p_n, mat3x3=res.R_n_b))  # fmt: skip
