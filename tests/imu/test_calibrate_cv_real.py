"""The default calibration against imu_tk's published parameters on imu_tk's two real logs, by the score
of poses it did not fit (5-fold cross-validation) and the score of imu_tk's parameters on all poses."""

from pathlib import Path

import numpy as np
import pytest

from imuslam.imu.calibrate import CalibrationConfig, calibrate
from imuslam.imu.crossval import cross_validate
from imuslam.imu.model import ImuCalibration, TriadModel
from imuslam.imu.score import detect_poses, pose_errors, rms
from imuslam.io.load import load_imu

# ../shared/data/README.md: imu_tk's result on each log (model T K (X - B)).
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
FILES = {
    "xsens": ("imu_tk_xsens/xsens_acc.mat", "imu_tk_xsens/xsens_gyro.mat"),
    "t265": ("imu_tk_t265/t265_acc.mat", "imu_tk_t265/t265_gyr.mat"),
}


@pytest.mark.slow
@pytest.mark.parametrize("name", ["xsens", "t265"])
def test_default_predicts_unseen_poses_better_than_imutk(shared_data: Path, name: str) -> None:
    """Issue 12's target: the held-out gravity-direction error at least 20 % below that of imu_tk's
    parameters on all poses, and the gravity-norm error of the calibration fitted on all poses no higher
    than that of imu_tk's (fitted on all poses too: like for like, both scored on the same poses). The
    held-out norm error on t265 is higher (README: the accelerometer bias drifts there), reported as
    missed in the README."""
    log = load_imu(shared_data / FILES[name][0], shared_data / FILES[name][1])
    ref = IMUTK[name]
    poses = detect_poses(log)
    imutk = pose_errors(log, ref, poses, ref.g)
    cfg = CalibrationConfig(g=ref.g, bias_sign="minus")
    res = calibrate(log, cfg)
    cv = cross_validate(log, cfg, res.intervals)
    assert np.all(np.isfinite(cv.norm_error))
    assert cv.direction_rms_deg <= 0.8 * rms(imutk.direction_error_deg)
    own = pose_errors(log, res.calibration, poses, ref.g)
    assert rms(own.norm_error) <= rms(imutk.norm_error)
