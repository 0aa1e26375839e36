"""Target-free LiDAR-IMU calibration (``lio.extrinsic``, ``imuslam calibrate-lidar``) against the
simulator's truth: a rig waved in all axes for 20 s in a calibration room (VLP-16 with 900 columns, 200 Hz IMU with
seed 000's table-2 errors corrected by their true model, so noise and bias random walk stay), started
2 deg / 10 cm / 20 ms away from the truth; and a car that only yaws (the street loop, 30 s, seeds 1-3)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from imuslam.cli import app
from imuslam.eval.metrics import KITTI_LENGTHS, evaluate
from imuslam.imu.model import ImuCalibration, TriadModel
from imuslam.interfaces import ImuLog, Trajectory
from imuslam.lio.config import ExtrinsicConfig, LioConfig
from imuslam.lio.extrinsic import GyroAttitude, LidarImuCalibration, calibrate_lidar_imu
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


def truth_and_extrinsic(d: LidarImuRig) -> tuple[Trajectory, ExtrinsicConfig]:
    """The rig's true trajectory and its true extrinsic as the config states it."""
    x, y, z, w = Rotation.from_matrix(d.T_i_l[:3, :3]).as_quat()
    truth = ExtrinsicConfig(
        p_i_l=tuple(d.T_i_l[:3, 3]), quat_wxyz_i_l=(w, x, y, z), time_offset_s=OFFSET_S
    )  # type: ignore[arg-type]
    return Trajectory(d.gt_t_ns, d.gt_p_w, d.gt_R_w_b, "truth"), truth


def errors(c: LidarImuCalibration, T: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Rotation error about the IMU axes, deg; lever-arm error, m; offset error, s."""
    rot = np.rad2deg(Rotation.from_matrix(c.R_i_l @ T[:3, :3].T).as_rotvec())
    return rot, c.p_i_l - T[:3, 3], c.time_offset_s - OFFSET_S


def test_gyro_attitude_at_repeated_times_equals_slerp_at_each_time() -> None:
    """The attitude at times repeated as a LiDAR column's points repeat them (some outside the
    samples, clipped) is bit for bit the slerp at each time taken alone."""
    rng = np.random.default_rng(4)
    t = np.cumsum(rng.uniform(0.004, 0.006, 400))
    att = GyroAttitude(t, rng.normal(size=(400, 3)), np.array([0.01, -0.02, 0.03]))
    tq = np.repeat(rng.uniform(-0.5, 2.5, 60), rng.integers(1, 20, 60))
    tq = np.concatenate([tq, t[::9], rng.permutation(tq)])
    expect = [att.slerp(min(max(x, t[0]), t[-1])).as_matrix() for x in tq]
    np.testing.assert_array_equal(att(tq), np.array(expect))


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
    gt, truth = truth_and_extrinsic(d)
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


# The street drive: the car loop around the urban block (``sim.drive``'s street, the drive of
# ``bench/lio.py robust``) for 30 s (240 m, three and a half corners) with the rig's LiDAR, started
# 2 deg / 10 cm / 20 ms away. A car that only yaws shows the rotation about the IMU x and y axes (the
# gyro about the vertical, and gravity), the rotation about z through its horizontal accelerations
# alone (weakly), the clock offset, and hardly the lever arm (x and y through centripetal terms of
# centimetres per second squared, z not at all).
STREET_S = 30.0


@pytest.fixture(scope="module", params=[1, 2, 3])
def street(request: pytest.FixtureRequest) -> tuple[LidarImuRig, LidarImuCalibration]:
    d = simulate_lidar_imu_rig(
        "street", STREET_S, request.param, true_T_i_l(), OFFSET_S, lidar=SMALL
    )
    return d, calibrate_lidar_imu(d.scans, calibrated(d), start_config(d.T_i_l))


@pytest.mark.slow
def test_street_calibration_meets_the_goals_or_says_it_cannot(
    street: tuple[LidarImuRig, LidarImuCalibration],
) -> None:
    """The goals (0.2 deg, 2 cm on the excited axes, 1 ms) on every parameter reported observed within
    its target; one reported weakly observed (1-sigma above its target) is right within 3 of its
    reported sigma; an unobservable one is held at the start. Never a confident wrong answer: every
    rotation error above 0.2 deg and lever-arm error above 2 cm is on an axis reported weak or
    unobservable."""
    d, c = street
    rot, dp, dt = errors(c, d.T_i_l)
    start = np.asarray(start_config(d.T_i_l).extrinsic.p_i_l)
    assert c.observable_rot.all() and c.observable_time
    # a ground vehicle: the lever arm along z changes no measurement (1-sigma from the data tens of
    # centimetres, against centimetres along x and y)
    assert not c.observable_p[2] and c.sigma_p_m[2] > 0.1
    assert c.sigma_p_m[2] > 5 * c.sigma_p_m[:2].max()
    assert any("lever arm along IMU" in u and "+1.00]" in u for u in c.unobservable)
    assert np.all(np.abs(rot[~c.weak_rot]) < 0.2), (rot, c.sigma_rot_deg)
    assert np.all(np.abs(rot) < 3 * c.sigma_rot_deg), (rot, c.sigma_rot_deg)
    assert abs(dt) < 1e-3 and abs(dt) < 3 * c.sigma_time_offset_s, (dt, c.sigma_time_offset_s)
    sure_p = c.observable_p & ~c.weak_p
    assert np.all(np.abs(dp[sure_p]) < 0.02), (dp, c.sigma_p_m)
    held = ~c.observable_p
    assert np.all(np.abs(c.p_i_l[held] - start[held]) < 2e-3)  # held along near-axis directions
    assert np.all((np.abs(rot) < 0.2) | c.weak_rot)
    assert np.all((np.abs(dp) < 0.02) | c.weak_p | held)
    assert not c.confident and c.weakly_observed


def _kitti(gt: Trajectory, est: Trajectory) -> float:
    """KITTI drift, %, averaged over the segment lengths the drive holds (100 and 200 m)."""
    res = evaluate(gt, est, "se3", 1.0, "frames", 0.02, KITTI_LENGTHS)
    return float(np.mean([v[0] for v in res.kitti.values()]))


def _lidar_frame(tr: Trajectory, ext: ExtrinsicConfig) -> Trajectory:
    """The LiDAR's trajectory from the IMU's through the extrinsic ``ext``."""
    return tr.of_mounted_frame(ext.T_i_l())


@pytest.mark.slow
def test_lio_on_the_street_with_the_recovered_values_drifts_as_with_the_truth(
    street: tuple[LidarImuRig, LidarImuCalibration],
) -> None:
    """``lio`` with the calibrated extrinsic and offset: the LiDAR's trajectory (``lio``'s IMU poses
    through the extrinsic it ran with, against the true LiDAR poses) drifts within 10 % of its drift
    with the true values (KITTI drift over 100 and 200 m), and the IMU's trajectory drifts less than
    with the start's 2 deg / 10 cm / 20 ms. The IMU's own drift is not held to 10 %: the values the
    street cannot show (the lever arm, held 10 cm off; the rotation about z, 0.1-0.2 deg off) move
    the IMU frame against the LiDAR's by exactly that error, which the KITTI drift of the IMU's
    poses counts (0.1 deg of heading is 0.17 % of the path) against 0.03-0.04 % with the truth."""
    from imuslam.io.lidarsets import MemoryDataset
    from imuslam.lio.pipeline import LioPipeline

    d, c = street
    imu = calibrated(d)
    gt, truth = truth_and_extrinsic(d)
    drift: dict[str, tuple[float, float]] = {}
    for name, ext in (
        ("truth", truth),
        ("calibrated", c.extrinsic()),
        ("start", start_config(d.T_i_l).extrinsic),
    ):
        data = MemoryDataset(d.scans, imu, "street")
        est = LioPipeline(data, LioConfig(extrinsic=ext), progress=False).run().trajectory
        drift[name] = (_kitti(gt, est), _kitti(_lidar_frame(gt, truth), _lidar_frame(est, ext)))
    assert drift["calibrated"][1] <= 1.1 * drift["truth"][1], drift
    assert drift["calibrated"][0] < drift["start"][0], drift


def test_weakly_observed_parameters_are_marked_in_the_verdict_and_the_written_config() -> None:
    """A parameter within its observability limit but with a 1-sigma above its accuracy target (0.2
    deg, 2 cm, 1 ms) is 'weak' in the table, listed in metrics.json and commented in lio_config.yaml;
    one above the limit is 'NO'; the estimate is then not confident."""
    from dataclasses import replace

    z = np.zeros(3)
    base = LidarImuCalibration(
        R_i_l=np.eye(3), p_i_l=z, time_offset_s=0.02, sigma_rot_deg=np.array([0.05, 0.05, 0.05]),
        sigma_p_m=np.array([0.01, 0.01, 0.01]), sigma_time_offset_s=5e-4,
        observable_rot=np.ones(3, bool), observable_p=np.ones(3, bool), observable_time=True,
        unobservable=[], gyro_bias=z, accel_bias=z, g_w=np.array([0, 0, -9.8]), rms_gyro=0.0,
        rms_accel=0.0, tau_gyro=1.0, tau_accel=1.0, coarse_time_offset_s=0.02, coarse_R_i_l=np.eye(3),
        start=ExtrinsicConfig(), n_scans=300, duration_s=30.0,
    )  # fmt: skip
    assert base.confident and not base.weakly_observed and base.yaml_header() == ""
    street_like = replace(
        base, sigma_rot_deg=np.array([0.05, 0.05, 0.36]), sigma_p_m=np.array([0.01, 0.01, 0.4]),
        observable_p=np.array([True, True, False]), sigma_time_offset_s=1.2e-3,
        unobservable=["lever arm along IMU [+0.00, +0.00, +1.00]: 1-sigma 0.4 m (kept at the start)"],
    )  # fmt: skip
    c = street_like
    assert [c.verdict("rot", k) for k in range(3)] == ["yes", "yes", "weak"]
    assert [c.verdict("p", k) for k in range(3)] == ["yes", "yes", "NO"]
    assert c.verdict("time") == "weak" and not c.confident
    assert len(c.weakly_observed) == 2 and "IMU z" in c.weakly_observed[0]
    m = c.to_dict()
    assert m["weak_rot"] == {"x": False, "y": False, "z": True} and m["confident"] is False
    head = c.yaml_header()
    assert head.count("# weakly observed") == 2 and head.count("# unobservable") == 1
    assert yaml.safe_load(head + "a: 1\n") == {"a": 1}
