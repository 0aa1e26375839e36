"""Which calibration predicts unseen poses best: imu_tk's published parameters against imuslam's methods on
the two real multi-pose logs (imu_tk's xsens and t265), by the score of ``imuslam score`` (fixed static
detector, independent of every calibration) and by 5-fold cross-validation over those poses.

imu_tk's parameters are its published result on all poses (../shared/data/README.md), so their score is
in-sample; imuslam's methods are scored both in-sample (fit on all poses) and held out (cross-validated).
Run: OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python bench/calibrate_cv.py  (about 5 minutes on 2 cores)
"""

from __future__ import annotations

import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

from imuslam.imu.calibrate import CalibrationConfig, calibrate
from imuslam.imu.crossval import cross_validate
from imuslam.imu.model import ImuCalibration, TriadModel
from imuslam.imu.score import detect_poses, pose_errors, rms
from imuslam.io.load import load_imu
from imuslam.threads import configure_process

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"

IMUTK = {
    "xsens": ImuCalibration(
        TriadModel([[1, -0.0033593, -0.00890639], [0, 1, -0.0213341], [0, 0, 1]],
                   [0.00241278, 0.00242712, 0.00241168], [33124.2, 33275.2, 32364.4], "minus"),
        TriadModel([[1, 0.00593634, 0.00111101], [0.00808812, 1, -0.0535569],
                    [0.0253067, -0.0025513, 1]],
                   [0.000209295, 0.000209899, 0.000209483], [32777.1, 32459.8, 32511.8], "minus"),
        accel_unit="counts", gyro_unit="counts", g=9.81744,
    ),
    "t265": ImuCalibration(
        TriadModel([[1, 0.0194692, -0.0574956], [0, 1, -0.00366816], [0, 0, 1]],
                   [1.00773, 1.01848, 1.01499], [-0.19119, 0.57394, -0.231325], "minus"),
        TriadModel([[1, 0.0141865, -0.0365638], [-0.0195891, 1, -0.00691532],
                    [0.0386539, 0.0134009, 1]],
                   [1.00051, 0.999542, 0.99792], [0.00335198, -0.00136361, -0.00353717], "minus"),
        g=9.8016,
    ),
}  # fmt: skip
LOGS = {
    "xsens": ("imu_tk_xsens/xsens_acc.mat", "imu_tk_xsens/xsens_gyro.mat"),
    "t265": ("imu_tk_t265/t265_acc.mat", "imu_tk_t265/t265_gyr.mat"),
}
METHODS = {
    "imuslam tedaldi (imu_tk's method)": {"method": "tedaldi"},
    "imuslam joint, variance components (former default)": {
        "joint_weights": "variance_components",
        "g_sensitivity_test": False,
        "accel_bias_drift": False,
    },
    "imuslam joint, no g-sensitivity": {"method": "joint", "gyro_g_sensitivity": False},
    "imuslam joint, norm weight 1 (maximum likelihood; former default)": {"norm_weight": 1.0},
    "imuslam joint (default: measured-noise weights, G and drift if significant, norm weight auto)": {},
    "imuslam joint, measured-noise weights, constant bias": {"accel_bias_drift": False},
    "imuslam joint + accel bias drift": {"accel_bias_drift": True},
}


def main() -> None:
    table = Table(
        title="Score on the static poses of the real logs (5-fold CV: held-out poses and pairs)"
    )
    for c in ("log", "calibration", "norm RMS [m/s^2]", "direction RMS [deg]", "CV norm RMS [m/s^2]",
              "CV direction RMS [deg]", "CV direction vs imu_tk", "CV norm vs imu_tk",
              "CV norm, drift at pose time [m/s^2]",
              "CPU [s]", "wall [s]"):  # fmt: skip
        table.add_column(c, justify="right" if "[" in c or "vs" in c else "left")
    for name, (fa, fg) in LOGS.items():
        log = load_imu(DATA / fa, DATA / fg)
        ref = IMUTK[name]
        g = ref.g
        poses = detect_poses(log)
        pe = pose_errors(log, ref, poses, g)
        ref_dir = rms(pe.direction_error_deg)
        ref_norm = rms(pe.norm_error)
        table.add_row(name, "imu_tk published (in-sample)", f"{rms(pe.norm_error):.5f}",
                      f"{ref_dir:.3f}", "-", "-", "-", "-", "-", "-", "-")  # fmt: skip
        for label, kw in METHODS.items():
            cfg = CalibrationConfig(g=g, bias_sign="minus", **kw)
            t0, c0 = time.perf_counter(), time.process_time()
            res = calibrate(log, cfg)
            cv = cross_validate(log, cfg, res.intervals)
            dt, dc = time.perf_counter() - t0, time.process_time() - c0
            pe = pose_errors(log, res.calibration, poses, g)
            table.add_row(name, label, f"{rms(pe.norm_error):.5f}", f"{rms(pe.direction_error_deg):.3f}",
                          f"{cv.norm_rms:.5f}", f"{cv.direction_rms_deg:.3f}",
                          f"{100 * (cv.direction_rms_deg / ref_dir - 1):+.0f} %",
                          f"{100 * (cv.norm_rms / ref_norm - 1):+.0f} %", f"{cv.norm_rms_in_session:.5f}",
                          f"{dc:.0f}", f"{dt:.0f}")  # fmt: skip
    Console(width=260).print(table)


if __name__ == "__main__":
    configure_process()  # the command line's thread defaults, before numba's first parallel kernel
    main()
