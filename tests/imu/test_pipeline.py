"""CalibratePipeline on imu_tk's xsens log: the results folder holds what the calibration found (imu_tk's
published accelerometer to its printed precision), a config that reloads into the same settings, and
imu_tk's own files."""

import json
from pathlib import Path

import numpy as np
import yaml

from imuslam.config import load_config
from imuslam.imu.calibrate import CalibrationConfig
from imuslam.imu.model import ImuCalibration
from imuslam.imu.pipeline import CalibratePipeline
from imuslam.io.load import load_imu

IMUTK_ACC_K = np.array(
    [0.00241278, 0.00242712, 0.00241168]
)  # imu_tk on xsens (test_calibrate_real)
IMUTK_ACC_B = np.array([33124.2, 33275.2, 32364.4])
IMUTK_ACC_RMS = 0.00795  # m/s^2 per sample


def test_calibrate_pipeline_xsens_results_folder(shared_data: Path, tmp_path: Path) -> None:
    d = shared_data / "imu_tk_xsens"
    log = load_imu(
        d / "xsens_acc.mat", d / "xsens_gyro.mat", accel_unit="counts", gyro_unit="counts"
    )
    cfg = CalibrationConfig(g=9.81744, t_init_s=50.0, bias_sign="minus", method="tedaldi")
    pipeline = CalibratePipeline(log, cfg, cv_folds=0)
    out = pipeline.run()
    assert out.cv is None
    acc = out.result.calibration.accel
    np.testing.assert_allclose(acc.K, IMUTK_ACC_K, rtol=1e-5)  # imu_tk prints 6 digits
    np.testing.assert_allclose(acc.b, IMUTK_ACC_B, atol=0.05)
    pipeline.save(out, tmp_path / "calib", plots=False)
    folder = tmp_path / "calib"
    assert sorted(p.name for p in folder.iterdir()) == [
        ".imuslam-results.json", "acc.calib", "calibration.yaml", "config.yaml", "gyro.calib",
        "metrics.json",
    ]  # fmt: skip
    m = json.loads((folder / "metrics.json").read_text())
    assert m["accel_rms_m_s2"] <= IMUTK_ACC_RMS + 5e-6
    assert m["static_intervals"] == 38  # imu_tk's count at the chosen threshold
    got = [m["accel"][n]["value"] for n in ("s_ax", "s_ay", "s_az")]
    np.testing.assert_allclose(got, IMUTK_ACC_K, rtol=1e-5)
    assert load_config(folder / "config.yaml", CalibrationConfig) == cfg
    assert yaml.safe_load((folder / "config.yaml").read_text())["method"] == "tedaldi"
    back = ImuCalibration.load_yaml(folder / "calibration.yaml")
    np.testing.assert_allclose(back.accel_params, out.result.calibration.accel_params, rtol=1e-12)
