"""LiDAR-inertial odometry on the simulated street drive (seed 001's car loop, VLP-16, 200 Hz IMU with
seed 000's table-2 errors), against the simulator's truth."""

from __future__ import annotations

import numpy as np
import pytest

from imuslam.errors import FilterDivergence, InputError
from imuslam.eval.metrics import evaluate
from imuslam.imu.model import ImuCalibration, TriadModel
from imuslam.interfaces import ImuLog, Trajectory
from imuslam.io.lidarsets import MemoryDataset
from imuslam.lio.config import ExtrinsicConfig, FilterConfig, FrontEndConfig, LioConfig
from imuslam.lio.pipeline import LioPipeline
from imuslam.lio.report import write_results
from imuslam.sim.drive import LidarDrive, simulate_lidar_drive
from imuslam.sim.imu_errors import SEED000_ACCEL, SEED000_GYRO


@pytest.fixture(scope="module")
def street() -> LidarDrive:
    return simulate_lidar_drive("street", 6.0, seed=11)


def _calibrated(d: LidarDrive) -> ImuLog:
    a, g = SEED000_ACCEL, SEED000_GYRO
    cal = ImuCalibration(
        TriadModel(a.T, a.K, a.b, a.bias_sign), TriadModel(g.T, g.K, g.b, g.bias_sign)
    )
    return cal.correct(d.imu)


def _config(d: LidarDrive, **kw: object) -> LioConfig:
    return LioConfig(extrinsic=ExtrinsicConfig(p_i_l=tuple(d.T_i_l[:3, 3])), **kw)  # type: ignore[arg-type]


def _truth(d: LidarDrive) -> Trajectory:
    return Trajectory(d.gt_t_ns, d.gt_p_w, d.gt_R_w_b, "truth")


@pytest.mark.parametrize(("mode", "state"), [("features", "full"), ("direct", "reduced")])
def test_lio_on_the_street_drive(
    street: LidarDrive, mode: str, state: str, tmp_path: object
) -> None:
    """The issue's accuracy targets (KITTI drift <= 0.5 %, rotation RMSE <= 0.5 deg) as bounds on this
    48 m excerpt: ATE within 0.5 % of the path, rotation RMSE within 0.5 deg. Range noise is 2 cm on
    thousands of planes per scan, so a working filter is far inside both; a wrong Jacobian, deskew or
    extrinsic is not."""
    cfg = _config(street, frontend=FrontEndConfig(mode=mode), filter=FilterConfig(state=state))  # type: ignore[arg-type]
    res = LioPipeline(
        MemoryDataset(street.scans, _calibrated(street), "sim"), cfg, progress=False
    ).run()
    gt = _truth(street)
    ev = evaluate(gt, res.trajectory, "se3", 1.0, "frames", 0.02)
    assert len(res.trajectory) == len(street.scans)
    assert ev.ape_trans.rmse < 0.005 * gt.path_length
    assert ev.ape_rot_deg.rmse < 0.5
    from pathlib import Path

    out = Path(str(tmp_path)) / "res"
    m = write_results(res, out, gt)
    assert {p.name for p in out.iterdir()} >= {"trajectory.tum", "map.ply", "map.pcd", "config.yaml", "scans.csv",
                                                "trajectory.png", "metrics.json"}  # fmt: skip
    assert m["ape_trans"]["rmse"] == pytest.approx(ev.ape_trans.rmse, rel=0.05)


def test_lio_after_a_kalman_alignment(street: LidarDrive) -> None:
    """``align kf`` on the calibrated IMU: the start's alignment is returned with the result (the biases
    it estimated, finite), and the filter that starts from it keeps the same accuracy bounds as with
    ``align none`` (a wrong hand-over of attitude, velocity or biases at the window end is not)."""
    cfg = _config(street, align="kf")
    res = LioPipeline(
        MemoryDataset(street.scans, _calibrated(street), "sim"), cfg, progress=False
    ).run()
    assert res.alignment is not None and res.alignment.method == "kf"
    assert np.all(np.isfinite(res.alignment.gyro_bias[-1]))
    assert np.all(np.isfinite(res.alignment.accel_bias[-1]))
    gt = _truth(street)
    ev = evaluate(gt, res.trajectory, "se3", 1.0, "frames", 0.02)
    assert ev.ape_trans.rmse < 0.005 * gt.path_length
    assert ev.ape_rot_deg.rmse < 0.5
    none = LioPipeline(MemoryDataset(street.scans, _calibrated(street), "sim"), _config(street),
                       progress=False).run()  # fmt: skip
    assert none.alignment is None


def test_lidar_only_on_the_street_drive(street: LidarDrive) -> None:
    cfg = _config(street, frontend=FrontEndConfig(mode="direct"), use_imu=False)
    res = LioPipeline(MemoryDataset(street.scans, None, "sim"), cfg, progress=False).run()
    ev = evaluate(_truth(street), res.trajectory, "se3", 1.0, "frames", 0.02)
    assert ev.ape_trans.rmse < 0.01 * _truth(street).path_length
    assert ev.ape_rot_deg.rmse < 0.5


def test_no_overlap_between_imu_and_lidar_is_named(street: LidarDrive) -> None:
    imu = _calibrated(street)
    late = ImuLog(imu.t_ns + 100_000_000_000, imu.accel, imu.gyro, "m/s^2", "rad/s", "late imu")
    with pytest.raises(InputError, match="no overlap between IMU times"):
        LioPipeline(
            MemoryDataset(street.scans[:5], late, "sim"), _config(street), progress=False
        ).run()


def test_divergence_names_the_scan(street: LidarDrive) -> None:
    """An accelerometer that jumps to 150 m/s^2 along x after 2 s drives the speed past any car's."""
    imu = _calibrated(street)
    acc = imu.accel.copy()
    acc[imu.t_s > 2.0, 0] += 150.0
    bad = ImuLog(imu.t_ns, acc, imu.gyro, "m/s^2", "rad/s", "bad imu")
    cfg = _config(street, filter=FilterConfig(max_speed=40.0))
    with pytest.raises(FilterDivergence, match=r"scan \d+ \(t = "):
        LioPipeline(MemoryDataset(street.scans, bad, "sim"), cfg, progress=False).run()


def _lidar_only(scans: list) -> object:  # type: ignore[type-arg]
    cfg = LioConfig(frontend=FrontEndConfig(mode="direct"), use_imu=False)
    return LioPipeline(MemoryDataset(scans, None, "sim"), cfg, progress=False).run()


def test_nan_points_are_dropped_and_counted(street: LidarDrive) -> None:
    from dataclasses import replace

    scans = list(street.scans[:12])
    pts = scans[3].points_l.copy()
    pts[:100] = np.nan
    pts[100:107] = 0.0  # a driver's "no return"
    scans[3] = replace(scans[3], points_l=pts)
    res = _lidar_only(scans)
    assert "107 NaN / infinite / zero points dropped" in res.warnings  # type: ignore[attr-defined]
    assert len(res.trajectory) == 12  # type: ignore[attr-defined]
    assert np.all(np.isfinite(res.trajectory.p_w))  # type: ignore[attr-defined]


def test_empty_scans_are_skipped_and_counted(street: LidarDrive) -> None:
    from dataclasses import replace

    scans = list(street.scans[:12])
    s5 = scans[5]
    scans[5] = replace(s5, points_l=s5.points_l[:0], t_offset_s=s5.t_offset_s[:0], ring=s5.ring[:0],
                       intensity=s5.intensity[:0])  # fmt: skip
    res = _lidar_only(scans)
    assert "1 scans with fewer than 100 valid points skipped" in res.warnings  # type: ignore[attr-defined]
    assert len(res.trajectory) == 11  # type: ignore[attr-defined]


def test_scans_out_of_order_in_memory_are_skipped(street: LidarDrive) -> None:
    scans = list(street.scans[:12])
    scans[6], scans[7] = scans[7], scans[6]
    res = _lidar_only(scans)
    assert "1 scans out of time order skipped" in res.warnings  # type: ignore[attr-defined]
    assert len(res.trajectory) == 11  # type: ignore[attr-defined]


def _nees(street: LidarDrive) -> tuple[list[float], list[float], list[tuple[float, float]]]:
    """NEES of the [attitude, position] error per filtered scan against the 6 x 6 block of the
    absolute covariance (``LioEstimator.covariance``) and of the filter's own, map-relative one
    (``eskf.P``, the map taken as exact: FAST-LIO2's), from one run (the consider term never enters
    the gain, so the estimate is the same). The truth is put in the filter's world: the first IMU
    frame at the first scan end, levelled by the filter's own rotation ``R_w_i0`` (a definition of
    the world's axes; the filter's tilt error relative to gravity is carried by its gravity state)."""
    from imuslam.geometry import log
    from imuslam.lio.estimator import LioEstimator

    cfg = _config(street, frontend=FrontEndConfig(mode="direct"))
    est = LioEstimator(cfg, _calibrated(street))
    t_ref = street.imu.t_ns[0]
    t_end, R_e, p_e, covs, rels = [], [], [], [], []
    for s in street.scans:
        t = (s.t_ns - t_ref) * 1e-9 + s.t_offset_s.astype(np.float64)
        T = est.register_scan(s.points_l.astype(np.float64), t, s.ring)
        if est.covariance is not None and est.eskf is not None:
            lay = est.layout
            idx = np.r_[lay.TH, lay.P]
            covs.append(est.covariance[np.ix_(idx, idx)])
            rels.append(est.eskf.P[np.ix_(idx, idx)])
            t_end.append(t_ref + int(round(t.max() * 1e9)))
            R_e.append(T[:3, :3])
            p_e.append(T[:3, 3])
    gi = np.searchsorted(street.gt_t_ns, np.array(t_end))
    gi = np.clip(gi, 0, len(street.gt_t_ns) - 1)
    R_t, p_t = street.gt_R_w_b[gi], street.gt_p_w[gi]
    t0 = t_ref + int(
        round(((street.scans[0].t_ns - t_ref) * 1e-9 + street.scans[0].t_offset_s.max()) * 1e9)
    )
    g0 = int(np.clip(np.searchsorted(street.gt_t_ns, t0), 0, len(street.gt_t_ns) - 1))
    R_a = est.T_w_i0[:3, :3] @ street.gt_R_w_b[g0].T
    t_a = -R_a @ street.gt_p_w[g0]
    nees, nees_rel, parts = [], [], []
    for k in range(len(covs)):
        e_th = log(R_e[k].T @ (R_a @ R_t[k]))
        e_p = (R_a @ p_t[k] + t_a) - p_e[k]
        e = np.r_[e_th, e_p]
        nees.append(float(e @ np.linalg.solve(covs[k], e)))
        nees_rel.append(float(e @ np.linalg.solve(rels[k], e)))
        C = covs[k]
        parts.append((float(e_th @ np.linalg.solve(C[:3, :3], e_th)),
                      float(e_p @ np.linalg.solve(C[3:, 3:], e_p))))  # fmt: skip
        if k % 10 == 0 or k == len(covs) - 1:
            print(f"scan {k}: attitude error {np.rad2deg(np.linalg.norm(e_th)):.2f} deg, sigma "
                  f"{np.rad2deg(np.sqrt(np.trace(C[:3, :3]) / 3)):.2f} deg a axis; position error "
                  f"{np.linalg.norm(e_p):.3f} m, sigma {np.sqrt(np.trace(C[3:, 3:]) / 3):.3f} m an axis; "
                  f"map-relative sigma {np.rad2deg(np.sqrt(np.trace(rels[k][:3, :3]) / 3)):.3f} deg, "
                  f"{np.sqrt(np.trace(rels[k][3:, 3:]) / 3):.3f} m")  # fmt: skip
    return nees, nees_rel, parts


def _check_consistent(street: LidarDrive) -> None:
    from scipy.stats import chi2

    nees, nees_rel, parts = _nees(street)
    n = len(nees)
    lower, bound = chi2.ppf(0.001, 6 * n) / n, chi2.ppf(0.999, 6 * n) / n
    print("NEES per scan:", np.round(nees, 2))
    print(f"mean NEES {np.mean(nees):.2f}, chi2 band [{lower:.2f}, {bound:.2f}]")
    att, pos = np.mean(parts, axis=0)
    print(f"mean NEES of the attitude alone {att:.2f}, of the position alone {pos:.2f} (3 each)")
    print("NEES per scan, map taken as exact:", np.round(nees_rel, 1))
    print(f"mean NEES, map taken as exact: {np.mean(nees_rel):.1f}")
    assert n > 30
    # never overconfident: the mean NEES below the band's upper end
    assert np.mean(nees) < bound
    # and not uselessly wide: sigma at most 2.5 times the error's (a mean NEES of 6 / 2.5^2 for 6
    # dof). The band's lower end is not met: the covariance is conservative (README, LIO covariance)
    assert np.mean(nees) > 6 / 2.5**2


def test_covariance_is_consistent(street: LidarDrive) -> None:
    """The absolute pose covariance covers the absolute error: mean NEES over the filtered scans below
    the 99.9 % quantile of chi2(6 n) / n, in the world of the first IMU pose, and sigma within 2.5
    times the error. The map is built from the filter's own poses, so the pose error relative to the
    truth includes the map's; the default ``filter.map_covariance`` adds the matched map's insertion
    covariance to the filter's (``MapCovariance``, a consider term; no drift rate by default)."""
    _check_consistent(street)


@pytest.mark.slow
def test_covariance_is_consistent_on_a_held_out_seed() -> None:
    """The same check on another seed."""
    _check_consistent(simulate_lidar_drive("street", 6.0, seed=17))
