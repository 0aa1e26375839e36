"""Target-free LiDAR-IMU calibration (``lio.extrinsic``, ``imuslam calibrate-lidar``) against the
simulator's truth: a rig waved in all axes for 20 s in a calibration room (VLP-16 with 900 columns, 200 Hz IMU with
seed 000's table-2 errors corrected by their true model, so noise and bias random walk stay), started
2 deg / 10 cm / 20 ms away from the truth; and a car that only yaws (the street loop)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from imuslam.cli import app
from imuslam.eval.metrics import evaluate
from imuslam.imu.model import ImuCalibration, TriadModel
from imuslam.interfaces import ImuLog, Trajectory
from imuslam.lio.config import ExtrinsicConfig, LioConfig
from imuslam.lio.extrinsic import LidarImuCalibration, calibrate_lidar_imu
from imuslam.sim import export
from imuslam.sim.drive import LidarImuRig, simulate_lidar_imu_rig
from imuslam.sim.imu_errors import SEED000_ACCEL, SEED000_GYRO
from imuslam.sim.lidar import Lidar3dConfig

RUNNER = CliRunner()
OFFSET_S = 0.02
SMALL = Lidar3dConfig(columns=900)


def true_T_i_l() -> np.ndarray:
    """A LiDAR turned 90 deg in yaw and a few degrees in roll / pitch, 19 cm from the IMU."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("ZYX", [90.0, -3.0, 5.0], degrees=True).as_matrix()
    T[:3, 3] = [0.1, -0.05, 0.15]
    return T


def calibrated(d: LidarImuRig) -> ImuLog:
    a, g = SEED000_ACCEL, SEED000_GYRO
    cal = ImuCalibration(
        TriadModel(a.T, a.K, a.b, a.bias_sign), TriadModel(g.T, g.K, g.b, g.bias_sign)
    )
    return cal.correct(d.imu)


def start_config(T: np.ndarray) -> LioConfig:
    """The truth moved by 2 deg about [1, 1, 1], 10 cm along [1, -1, 1] and the offset taken as zero."""
    dR = Rotation.from_rotvec(np.deg2rad(2.0) * np.ones(3) / np.sqrt(3)).as_matrix()
    x, y, z, w = Rotation.from_matrix(dR @ T[:3, :3]).as_quat()
    p = T[:3, 3] + 0.1 * np.array([1.0, -1.0, 1.0]) / np.sqrt(3)
    ext = ExtrinsicConfig(p_i_l=tuple(p), quat_wxyz_i_l=(w, x, y, z), time_offset_s=0.0)  # type: ignore[arg-type]
    return LioConfig(extrinsic=ext)


def errors(c: LidarImuCalibration, T: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Rotation error about the IMU axes, deg; lever-arm error, m; offset error, s."""
    rot = np.rad2deg(Rotation.from_matrix(c.R_i_l @ T[:3, :3].T).as_rotvec())
    return rot, c.p_i_l - T[:3, 3], c.time_offset_s - OFFSET_S


@pytest.fixture(scope="module")
def excited() -> tuple[LidarImuRig, LidarImuCalibration]:
    d = simulate_lidar_imu_rig("excited", 20.0, 1, true_T_i_l(), OFFSET_S, lidar=SMALL)
    return d, calibrate_lidar_imu(d.scans, calibrated(d), start_config(d.T_i_l))


def _check_excited(d: LidarImuRig, c: LidarImuCalibration) -> None:
    """The issue's bounds: rotation within 0.2 deg, lever arm within 2 cm on every (excited) axis,
    offset within 1 ms; every parameter reported observable; and the truth within 4 reported sigma
    (the sigma are the least squares' with the residuals' correlation time, not a loose bound)."""
    rot, dp, dt = errors(c, d.T_i_l)
    assert c.observable, c.unobservable
    assert np.linalg.norm(rot) < 0.2
    assert np.all(np.abs(dp) < 0.02)
    assert abs(dt) < 1e-3
    assert np.all(np.abs(rot) < 4 * c.sigma_rot_deg + 0.02)
    assert np.all(np.abs(dp) < 4 * c.sigma_p_m + 0.002)
    assert abs(dt) < 4 * c.sigma_time_offset_s + 2e-4


@pytest.mark.slow
def test_excited_rig_recovers_the_extrinsic_and_the_offset(
    excited: tuple[LidarImuRig, LidarImuCalibration],
) -> None:
    _check_excited(*excited)


@pytest.mark.slow
def test_no_starting_guess_is_needed(excited: tuple[LidarImuRig, LidarImuCalibration]) -> None:
    """From the default config (identity rotation, zero lever arm and offset: the LiDAR is 90 deg away
    in yaw) the coarse stage finds the rotation and offset and the estimate meets the same bounds."""
    d = excited[0]
    _check_excited(d, calibrate_lidar_imu(d.scans, calibrated(d), LioConfig()))


@pytest.mark.slow
@pytest.mark.parametrize("seed", [2, 3])
def test_excited_rig_on_more_seeds(seed: int) -> None:
    d = simulate_lidar_imu_rig("excited", 20.0, seed, true_T_i_l(), OFFSET_S, lidar=SMALL)
    _check_excited(d, calibrate_lidar_imu(d.scans, calibrated(d), start_config(d.T_i_l)))


@pytest.mark.slow
def test_yaw_only_drive_reports_the_vertical_lever_arm_unobservable() -> None:
    """A car on the street loop turns about its z axis only (roll / pitch of 0.6 deg): the lever arm
    along z changes no measurement (1-sigma from the data tens of centimetres, against centimetres
    along x and y), so it is reported unobservable and held at its start (10 cm / sqrt(3) off)
    instead of a confident wrong value; the rotation (the gyro and the car's accelerations) is still
    observed, right within 4 sigma."""
    d = simulate_lidar_imu_rig("street", 20.0, 4, true_T_i_l(), OFFSET_S, lidar=SMALL)
    cfg = start_config(d.T_i_l)
    c = calibrate_lidar_imu(d.scans, calibrated(d), cfg)
    assert not c.observable_p[2]
    assert c.sigma_p_m[2] > 0.1 and c.sigma_p_m[2] > 5 * c.sigma_p_m[:2].max()
    assert any("lever arm along IMU" in u and "+1.00]" in u for u in c.unobservable)
    assert abs(c.p_i_l[2] - cfg.extrinsic.p_i_l[2]) < 1e-3  # held at the start
    rot, dp, dt = errors(c, d.T_i_l)
    ok = c.observable_p
    assert np.all(np.abs(dp[ok]) < 4 * c.sigma_p_m[ok] + 0.002)
    assert c.observable_rot.all()
    assert np.all(np.abs(rot) < 4 * c.sigma_rot_deg + 0.02)


def _rig_bag(d: LidarImuRig, path: Path) -> Path:
    pc = [(s.t_ns, "/points", export.pointcloud_message(s)[1]) for s in d.scans]
    export.write_bag(path, [export.imu_messages(d.imu), iter(pc)])
    return path


@pytest.mark.slow
def test_lio_with_the_recovered_extrinsic_drifts_as_with_the_truth(
    excited: tuple[LidarImuRig, LidarImuCalibration],
) -> None:
    """``lio`` on the rig with the calibrated extrinsic and offset: ATE within 10 % of its ATE with the
    true values (and far below the ATE with the start's 2 deg / 10 cm / 20 ms error)."""
    from imuslam.io.lidarsets import MemoryDataset
    from imuslam.lio.pipeline import LioPipeline

    d, c = excited
    imu = calibrated(d)
    gt = Trajectory(d.gt_t_ns, d.gt_p_w, d.gt_R_w_b, "truth")
    x, y, z, w = Rotation.from_matrix(d.T_i_l[:3, :3]).as_quat()
    truth = ExtrinsicConfig(
        p_i_l=tuple(d.T_i_l[:3, 3]), quat_wxyz_i_l=(w, x, y, z), time_offset_s=OFFSET_S
    )  # type: ignore[arg-type]
    ate = {}
    for name, ext in (
        ("truth", truth),
        ("calibrated", c.extrinsic()),
        ("start", start_config(d.T_i_l).extrinsic),
    ):
        res = LioPipeline(
            MemoryDataset(d.scans, imu, "rig"), LioConfig(extrinsic=ext), progress=False
        ).run()
        ev = evaluate(gt, res.trajectory, "se3", 1.0, "frames", 0.02)
        ate[name] = ev.ape_trans.rmse
    assert ate["calibrated"] <= 1.1 * ate["truth"], ate


def test_calibrate_lidar_command_writes_a_config_that_lio_accepts(tmp_path: Path) -> None:
    """The command on a 12 s bag of the rig cut to its first 10 s (``--duration``): lio_config.yaml
    with the estimate (within looser bounds than the 20 s drives': half the data), metrics.json with
    values, sigma and the verdict, the table with units; then ``lio --config lio_config.yaml`` runs."""
    d = simulate_lidar_imu_rig("excited", 12.0, 5, true_T_i_l(), OFFSET_S, lidar=SMALL)
    bag = _rig_bag(d, tmp_path / "rig")
    start = tmp_path / "start.yaml"
    start.write_text(yaml.safe_dump(start_config(d.T_i_l).model_dump(mode="json")))
    a, g = SEED000_ACCEL, SEED000_GYRO
    cal = ImuCalibration(
        TriadModel(a.T, a.K, a.b, a.bias_sign), TriadModel(g.T, g.K, g.b, g.bias_sign)
    )
    cal.save_yaml(tmp_path / "calibration.yaml")
    out = tmp_path / "out"
    r = RUNNER.invoke(app, ["calibrate-lidar", str(bag), "--imu-topic", "/imu/data", "--points-topic", "/points",
                            "--config", str(start), "--calib", str(tmp_path / "calibration.yaml"),
                            "--duration", "10", "--out", str(out)])  # fmt: skip
    assert r.exit_code == 0, r.output
    assert {p.name for p in out.iterdir()} >= {"lio_config.yaml", "metrics.json", "config.yaml"}
    assert "deg" in r.output and "ms" in r.output and "1-sigma" in r.output
    m = json.loads((out / "metrics.json").read_text())
    assert m["observable"] is True and len(m["sigma_p_i_l_m"]) == 3 and m["n_scans"] <= 101
    ext = yaml.safe_load((out / "lio_config.yaml").read_text())["extrinsic"]
    assert np.all(np.abs(np.array(ext["p_i_l"]) - d.T_i_l[:3, 3]) < 0.04)
    assert abs(ext["time_offset_s"] - OFFSET_S) < 3e-3
    R = Rotation.from_quat(np.roll(ext["quat_wxyz_i_l"], -1)).as_matrix()
    assert np.rad2deg(np.linalg.norm(Rotation.from_matrix(R @ d.T_i_l[:3, :3].T).as_rotvec())) < 0.5
    lio_out = tmp_path / "lio"
    r2 = RUNNER.invoke(app, ["lio", str(bag), "--imu-topic", "/imu/data", "--points-topic", "/points",
                             "--config", str(out / "lio_config.yaml"), "--calib", str(tmp_path / "calibration.yaml"),
                             "--max-scans", "20", "--out", str(lio_out)])  # fmt: skip
    assert r2.exit_code == 0, r2.output
    assert (lio_out / "trajectory.tum").exists()


def test_missing_topic_is_one_line_naming_the_option(tmp_path: Path) -> None:
    d = simulate_lidar_imu_rig(
        "excited", 3.0, 8, true_T_i_l(), OFFSET_S, lidar=Lidar3dConfig(columns=180)
    )
    bag = _rig_bag(d, tmp_path / "rig")
    r = RUNNER.invoke(app, ["calibrate-lidar", str(bag), "--points-topic", "/velodyne_points",
                            "--out", str(tmp_path / "o")])  # fmt: skip
    assert r.exit_code == 2
    assert "/velodyne_points" in r.output and "Traceback" not in r.output
    r = RUNNER.invoke(
        app, ["calibrate-lidar", str(bag), "--imu-topic", "/imu/raw", "--out", str(tmp_path / "o")]
    )
    assert r.exit_code == 2
    assert "/imu/raw" in r.output and "Traceback" not in r.output
    assert not (tmp_path / "o").exists()
    r = RUNNER.invoke(
        app, ["calibrate-lidar", str(bag), "--out", str(bag / "calib")]
    )  # inside the input
    assert r.exit_code == 2 and "--out" in r.output and "Traceback" not in r.output
    assert not (bag / "calib").exists()


def test_a_bag_without_motion_is_refused_naming_what_cannot_be_seen(tmp_path: Path) -> None:
    """The rig at rest: exit 2 with one line saying the rotation, lever arm and offset are unobservable
    (and the measured rates), nothing written."""
    d = simulate_lidar_imu_rig(
        "static", 3.0, 9, true_T_i_l(), OFFSET_S, lidar=Lidar3dConfig(columns=360)
    )
    bag = _rig_bag(d, tmp_path / "still")
    r = RUNNER.invoke(app, ["calibrate-lidar", str(bag), "--out", str(tmp_path / "o")])
    assert r.exit_code == 2, r.output
    assert "unobservable" in r.output and "rad/s RMS" in r.output and "Traceback" not in r.output
    assert not (tmp_path / "o").exists()
