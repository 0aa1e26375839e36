"""The accelerometer bias drift within imu_tk's t265 session: per static pose of the score, its time, its
gravity direction and its gravity-norm error under the default joint fit with a constant bias
(``accel_bias_drift: false``) and under imu_tk's published parameters, poses grouped by direction.

A bias that drifts along x shows as +x poses' error falling in time while the -x poses' rises.
Run: OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python bench/calibrate_drift.py  (a few seconds of CPU)
"""

from __future__ import annotations

import time

import numpy as np
from rich.console import Console
from rich.table import Table

from calibrate_cv import DATA, IMUTK, LOGS
from imuslam.imu.calibrate import CalibrationConfig, calibrate
from imuslam.imu.score import detect_poses, pose_errors
from imuslam.io.load import load_imu
from imuslam.threads import configure_process


def main() -> None:
    t0, c0 = time.perf_counter(), time.process_time()
    fa, fg = LOGS["t265"]
    log = load_imu(DATA / fa, DATA / fg)
    ref = IMUTK["t265"]
    poses = detect_poses(log)
    cfg = CalibrationConfig(g=ref.g, bias_sign="minus", accel_bias_drift=False)
    cal = calibrate(log, cfg).calibration
    ours = pose_errors(log, cal, poses, ref.g).norm_error
    theirs = pose_errors(log, ref, poses, ref.g).norm_error
    raw = np.stack([log.accel[s:e].mean(axis=0) for s, e in poses])
    u = cal.correct_accel(raw)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    axis = np.argmax(np.abs(u), axis=1)
    label = np.array([("+" if u[k, a] > 0 else "-") + "xyz"[a] for k, a in enumerate(axis)])
    t_mid = log.t_s[(poses[:, 0] + poses[:, 1]) // 2]
    table = Table(title="t265: gravity-norm error per pose (mm/s^2), poses grouped by direction")
    for c in ("direction", "time (s): joint constant bias / imu_tk"):
        table.add_column(c)
    for d in ("+x", "-x", "+y", "-y", "+z", "-z"):
        ks = np.flatnonzero(label == d)
        table.add_row(
            d, "  ".join(f"{t_mid[k]:.0f}: {1e3 * ours[k]:+.1f}/{1e3 * theirs[k]:+.1f}" for k in ks)
        )
    Console(width=220).print(table)
    print(f"CPU {time.process_time() - c0:.1f} s, wall {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    configure_process()  # the command line's thread defaults, before numba's first parallel kernel
    main()
