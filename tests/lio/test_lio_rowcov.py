"""The LiDAR rows' noise model with the frozen map's shared point noise (``lio.rowcov``,
``filter.lidar_model: plane``)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from numpy.typing import NDArray

from imuslam.eval.metrics import evaluate
from imuslam.geometry import log as so3_log
from imuslam.imu.model import ImuCalibration, TriadModel
from imuslam.interfaces import Trajectory
from imuslam.io.lidarsets import MemoryDataset
from imuslam.lio.config import ExtrinsicConfig, FilterConfig, FrontEndConfig, LioConfig
from imuslam.lio.frontend import select_points
from imuslam.lio.matcher import LocalMap, MatchParams
from imuslam.lio.pipeline import LioPipeline
from imuslam.lio.residuals import fit_planes_reference
from imuslam.lio.rowcov import SensorOrigins, associate_shared, gauss_newton_rows, whitened_system
from imuslam.sim.drive import LidarDrive, simulate_lidar_drive
from imuslam.sim.imu_errors import SEED000_ACCEL, SEED000_GYRO

FloatArray = NDArray[np.float64]


def test_whitened_system_is_the_generalised_least_squares_one() -> None:
    """U^T U = J^T R^-1 J and U^T z = J^T R^-1 r with R = diag(D) + G G^T, against a dense inverse."""
    rng = np.random.default_rng(3)
    M, N = 40, 15
    J, r = rng.normal(size=(M, 6)), rng.normal(size=M)
    D = rng.uniform(0.5, 2.0, M)
    Gd = np.where(rng.uniform(size=(M, N)) < 0.2, rng.normal(size=(M, N)), 0.0)
    U, z = whitened_system(r, J, D, sp.csr_matrix(Gd))
    Rinv = np.linalg.inv(np.diag(D) + Gd @ Gd.T)
    np.testing.assert_allclose(U.T @ U, J.T @ Rinv @ J, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(U.T @ z, J.T @ Rinv @ r, rtol=1e-9, atol=1e-9)


def test_plane_fit_error_and_its_sharing_match_monte_carlo() -> None:
    """Two scan points fitted to the same 5 map points on the plane z = 0, each map point measured by
    a beam from 10 m above with 2 cm range noise: the first-order covariance of the two rows' plane-fit
    errors (G G^T) against 20000 draws of the points' noise refitted by eigen-decomposition. The
    sampled variances' relative 1-sigma is sqrt(2 / n) = 1 %; bound 5 %, which also covers the
    first-order model's neglect of the noise's tilt of the fit (2 cm over 0.4 m)."""
    pts = np.array([[0.0, 0.0, 0.0], [0.4, 0.05, 0.0], [-0.35, 0.3, 0.0], [0.1, -0.4, 0.0],
                    [-0.2, -0.25, 0.0]])  # fmt: skip
    lmap = LocalMap(0.5, 100.0, 5, "ivox", MatchParams(k=5))
    lmap.insert(pts, np.zeros((0, 3)), np.eye(3), np.zeros(3), tag=0)
    origins = SensorOrigins()
    origins.record(0, np.array([0.0, 0.0, 10.0]))
    q = np.array([[0.05, 0.02, 0.0], [0.3, -0.1, 0.0]])
    sigma = 0.02
    corr, s, G = associate_shared(lmap, q, np.zeros((0, 3)), np.eye(3), np.zeros(3), 0.1,
                                  np.array([0.0, 0.0, 10.0]), origins, sigma)  # fmt: skip
    assert len(corr) == 2 and G.shape == (2, 5)
    np.testing.assert_allclose(s, sigma, rtol=1e-3)  # the beam nearly along the normal
    C_pred = (G @ G.T).toarray()
    rng = np.random.default_rng(1)
    n_draw = 20000
    b = (pts - [0.0, 0.0, 10.0]) / np.linalg.norm(pts - [0.0, 0.0, 10.0], axis=1)[:, None]
    noisy = pts[None] + rng.normal(size=(n_draw, 5, 1)) * sigma * b[None]
    n, c = fit_planes_reference(np.arange(n_draw * 5).reshape(n_draw, 5), noisy.reshape(-1, 3))
    r = np.stack([np.einsum("mk,mk->m", n, qi - c) for qi in q], axis=1)
    C_mc = np.cov(r.T)
    assert C_pred[0, 1] > 0.2 * np.sqrt(C_pred[0, 0] * C_pred[1, 1])  # shared: strongly correlated
    np.testing.assert_allclose(np.diag(C_mc), np.diag(C_pred), rtol=0.05)
    corr_mc = C_mc[0, 1] / np.sqrt(C_mc[0, 0] * C_mc[1, 1])
    corr_pred = C_pred[0, 1] / np.sqrt(C_pred[0, 0] * C_pred[1, 1])
    assert corr_mc == pytest.approx(corr_pred, abs=0.03)


def _per_scan_nees(d: LidarDrive, mode: str) -> FloatArray:
    """Each scan registered with the rows' model against a map built from the TRUE poses of the scans
    before it (ten scans first), from the true pose, deskewed with the true motion: the NEES (6 dof) of
    its covariance per scan (``bench/lio.py rowmodel``)."""
    R_i_l, p_i_l = d.T_i_l[:3, :3], d.T_i_l[:3, 3]
    lmap = LocalMap(0.5, 100.0, 1, "ivox", MatchParams())
    origins = SensorOrigins()
    out = []
    for j, s in enumerate(d.scans):
        x_l, t, pe, Re = d.true_deskewed(j)
        surf_l, edge_l = select_points(x_l, t - t.min(), s.ring, FrontEndConfig(mode=mode))  # type: ignore[arg-type]
        surf, edge = surf_l @ R_i_l.T + p_i_l, edge_l @ R_i_l.T + p_i_l
        if j >= 10:
            Rk, pk, _, _, C = gauss_newton_rows(lmap, surf, edge, Re, pe, 0.02, origins,
                                                coarse=False, p_s=p_i_l)  # fmt: skip
            e = np.r_[pe - pk, so3_log(Rk.T @ Re)]
            out.append(float(e @ np.linalg.solve(C, e)))
        lmap.insert(surf, edge, Re, pe, j)
        origins.record(j, Re @ p_i_l + pe)
    return np.array(out)


@pytest.mark.slow
def test_one_scans_covariance_is_consistent_on_a_held_out_seed() -> None:
    """The rows' model gives one scan's registration covariance: against a map from the true poses
    (its points with the simulated 2 cm range noise), the mean NEES of the 6-dof pose over the scans of
    a held-out street seed (19; the model was built looking at seeds 5, 7, 11, 13) lies inside the
    0.1-99.9 % band of chi2(6 n) / n (the scans share map points, so the band is approximate), with
    the LOAM features front end (the direct one read 3.5-4.5 on the chosen seeds, a little below the
    band: conservative). The
    filter with this model is not consistent (README, LIO covariance): the start's and the map
    chain's slowly varying errors are not in it."""
    from scipy.stats import chi2

    nees = _per_scan_nees(simulate_lidar_drive("street", 6.0, seed=19), "features")
    n = len(nees)
    print(f"mean NEES {nees.mean():.2f} over {n} scans")
    assert n > 30
    assert chi2.ppf(0.001, 6 * n) / n < nees.mean() < chi2.ppf(0.999, 6 * n) / n


@pytest.mark.slow
@pytest.mark.parametrize(("model", "start"), [("plane", False), ("plane_diag", True)])
def test_lio_with_the_rows_model_on_the_street_drive(model: str, start: bool) -> None:
    """``filter.lidar_model: plane`` / ``plane_diag`` (with ``start_covariance``) end to end (options,
    off by default) within the accuracy targets of ``test_lio_sim.test_lio_on_the_street_drive`` (ATE
    0.5 % of the path, rotation RMSE 0.5 deg) on the seed-11 excerpt."""
    d = simulate_lidar_drive("street", 6.0, seed=11)
    a, g = SEED000_ACCEL, SEED000_GYRO
    cal = ImuCalibration(
        TriadModel(a.T, a.K, a.b, a.bias_sign), TriadModel(g.T, g.K, g.b, g.bias_sign)
    )
    cfg = LioConfig(extrinsic=ExtrinsicConfig(p_i_l=tuple(d.T_i_l[:3, 3])),  # type: ignore[arg-type]
                    frontend=FrontEndConfig(mode="direct"),
                    filter=FilterConfig(lidar_model=model, start_covariance=start))  # type: ignore[arg-type]  # fmt: skip
    res = LioPipeline(MemoryDataset(d.scans, cal.correct(d.imu), "sim"), cfg, progress=False).run()
    gt = Trajectory(d.gt_t_ns, d.gt_p_w, d.gt_R_w_b, "truth")
    ev = evaluate(gt, res.trajectory, "se3", 1.0, "frames", 0.02)
    assert len(res.trajectory) == len(d.scans)
    assert ev.ape_trans.rmse < 0.005 * gt.path_length
    assert ev.ape_rot_deg.rmse < 0.5


def test_diagonal_rows_model_keeps_each_rows_whole_variance() -> None:
    """``plane_diag``: each row's variance is the full model's diagonal (its own range noise, floored
    at a tenth of the range noise, plus its plane-fit error (G G^T)_mm), with no shared columns."""
    pts = np.array([[0.0, 0.0, 0.0], [0.4, 0.05, 0.0], [-0.35, 0.3, 0.0], [0.1, -0.4, 0.0],
                    [-0.2, -0.25, 0.0]])  # fmt: skip
    lmap = LocalMap(0.5, 100.0, 5, "ivox", MatchParams(k=5))
    lmap.insert(pts, np.zeros((0, 3)), np.eye(3), np.zeros(3), tag=0)
    origins = SensorOrigins()
    origins.record(0, np.array([3.0, 1.0, 2.0]))  # oblique beams: the floor and G both matter
    q = np.array([[0.05, 0.02, 0.0], [0.3, -0.1, 0.0], [-0.1, 0.2, 0.0]])
    args = (lmap, q, np.zeros((0, 3)), np.eye(3), np.zeros(3), 0.1, np.array([5.0, 0.0, 0.3]),
            origins, 0.02)  # fmt: skip
    _, s, G = associate_shared(*args)
    _, s_d, G_d = associate_shared(*args, diagonal=True)
    assert G_d.shape == (3, 0) and G.shape == (3, 5)
    expected = np.maximum(s, 0.002) ** 2 + np.asarray(G.multiply(G).sum(axis=1)).ravel()
    np.testing.assert_allclose(s_d**2, expected, rtol=1e-12)


def test_start_covariance_moves_the_lidar_registrations_to_the_imu_pose() -> None:
    """``filter.start_covariance``: a start of two scans (the first defines the world) whose second
    registration has covariance Creg on the LiDAR's [dp, dtheta] (first LiDAR frame, rotation on the
    right): the start map's record is the mean over its two scans, 0 and A Creg A^T, with A the
    Jacobian of the IMU's [theta, p] in w, here by central differences of the composed poses
    T_w_i = T_w_l0 T_l0_l1 T_l_i (a rotated, offset LiDAR; a levelled world)."""
    from imuslam.geometry import exp as so3_exp
    from imuslam.interfaces.imu import ImuLog
    from imuslam.lio.estimator import LioEstimator

    q = np.array([0.9, 0.1, -0.2, 0.3])
    cfg = LioConfig(extrinsic=ExtrinsicConfig(p_i_l=(0.3, -0.1, 0.5), quat_wxyz_i_l=tuple(q / np.linalg.norm(q))),  # type: ignore[arg-type]
                    filter=FilterConfig(lidar_model="plane_diag", start_covariance=True))  # fmt: skip
    n = 20
    imu = ImuLog(np.arange(n, dtype=np.int64) * 10_000_000, np.tile([0.0, 0.0, 9.8], (n, 1)),
                 np.zeros((n, 3)), "m/s^2", "rad/s", "test")  # fmt: skip
    est = LioEstimator(cfg, imu)
    T_i_l = est.T_i_l
    R_w_i0 = so3_exp(np.array([0.02, -0.03, 0.0]))
    T_w_l0 = np.eye(4)
    T_w_l0[:3, :3] = R_w_i0
    T_w_l0 = T_w_l0 @ T_i_l
    R_l1, p_l1 = so3_exp(np.array([0.1, 0.2, 0.7])), np.array([4.0, -1.0, 0.2])

    def imu_pose(e: FloatArray) -> tuple[FloatArray, FloatArray]:
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R_l1 @ so3_exp(e[3:]), p_l1 + e[:3]
        Tw = T_w_l0 @ T @ np.linalg.inv(T_i_l)
        return Tw[:3, :3], Tw[:3, 3]

    R1, p1 = imu_pose(np.zeros(6))
    A = np.zeros((6, 6))
    h = 1e-6
    for j in range(6):
        e = np.zeros(6)
        e[j] = h
        Rp, pp = imu_pose(e)
        Rm, pm = imu_pose(-e)
        A[:3, j] = (so3_log(R1.T @ Rp) - so3_log(R1.T @ Rm)) / (2 * h)
        A[3:, j] = (pp - pm) / (2 * h)
    rng = np.random.default_rng(2)
    L = rng.normal(size=(6, 6)) * 1e-3
    Creg = L @ L.T
    est._start_covs = [np.full((6, 6), np.nan), Creg]
    T0 = T_w_l0 @ np.linalg.inv(T_i_l)
    R0, p0 = T0[:3, :3], T0[:3, 3]
    C = est._start_map_covariance(R_w_i0, np.array([R0, R1]), np.array([p0, p1]))
    np.testing.assert_allclose(C, 0.5 * A @ Creg @ A.T, rtol=1e-6, atol=1e-14)


def test_start_covariance_without_a_rows_model_is_refused() -> None:
    """``filter.start_covariance`` with the default ``dof`` model (no registration covariance to
    carry) is a configuration error naming the field, not a silent no-op."""
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match="filter.start_covariance needs"):
        FilterConfig(start_covariance=True)
