"""The online calibration in a recording, on the robot's clock (timeline ``sensor_time``): every event
of the calibrator ``online/events`` (a text log: session starts, calibrations, rejections, drift
alarms); per published calibration its model's bias terms ``b`` (raw units: m/s^2 and rad/s for a log in SI, as
the history table prints them) ``online/calibration/accel_bias``, ``online/calibration/gyro_bias`` and
the residual ``online/calibration/rms``; per
drift alarm the gravity-norm error and the still gyro rate with their 1-sigma ``online/drift/...``."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from imuslam.viz.recording import set_time

if TYPE_CHECKING:
    from imuslam.imu.history import CalibrationHistory
    from imuslam.imu.online_pipeline import OnlineOutput


def log_online(rec: Any, output: OnlineOutput, history: CalibrationHistory) -> None:
    """Every event of ``output`` and the calibrations of ``history`` it published (see the module)."""
    import rerun as rr

    versions = set(history.versions())
    for e in output.events:
        if e.kind == "command":
            continue
        set_time(rec, e.t_ns)
        level = "WARN" if e.kind in ("drift", "rejected") else "INFO"
        text = ", ".join(
            f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in e.detail.items()
        )
        rec.log("online/events", rr.TextLog(f"{e.kind}: {text}", level=level))
        d = e.detail
        if e.kind == "calibrated" and d.get("version") in versions:
            cal = history.load(int(d["version"]))
            rec.log("online/calibration/accel_bias", rr.Scalars(cal.accel.b))
            rec.log("online/calibration/gyro_bias", rr.Scalars(cal.gyro.b))
            if d.get("rms_new") is not None:
                rec.log("online/calibration/rms", rr.Scalars(float(d["rms_new"])))
        elif e.kind == "drift":
            for key in ("norm_error", "norm_sigma", "gyro_rate", "gyro_sigma"):
                if isinstance(d.get(key), int | float):
                    rec.log(f"online/drift/{key}", rr.Scalars(float(d[key])))
