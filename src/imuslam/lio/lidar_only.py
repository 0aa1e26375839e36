"""LiDAR-only odometry: constant-velocity deskew and prediction, point-to-plane / point-to-line
Gauss-Newton against the local map (the KISS-ICP scheme, Vizzo et al. 2023, with LOAM's residuals).
A pure object: ``register_scan(points, times) -> pose``; it knows no files.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import FilterDivergence
from imuslam.geometry import exp
from imuslam.lio.config import LioConfig
from imuslam.lio.deskew import constant_velocity_motion, deskew_constant_velocity
from imuslam.lio.frontend import select_points
from imuslam.lio.matcher import Correspondences, LocalMap, huber_weights

FloatArray = NDArray[np.float64]


@dataclass
class Registration:
    """Result of one scan-to-map registration: pose (R, p), iterations, correspondences used."""

    R_w_s: FloatArray
    p_w: FloatArray
    iterations: int
    n_corr: int


def moved(
    R0: FloatArray, p0: FloatArray, R: FloatArray, p: FloatArray, reach: float = 20.0
) -> float:
    """How far the pose (R, p) moved a point at ``reach`` m from where (R0, p0) put it, m (a bound:
    the translation plus the rotation angle times the reach)."""
    c = np.clip((np.trace(R0.T @ R) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.linalg.norm(p - p0) + reach * np.arccos(c))


def gauss_newton(
    local_map: LocalMap,
    surf: FloatArray,
    edge: FloatArray,
    R_w_s: FloatArray,
    p_w: FloatArray,
    max_iterations: int = 10,
    converge: float = 1e-3,
    huber: float = 0.2,
    reassociate: float = 0.0,
) -> Registration:
    """Iteratively re-associated Gauss-Newton with Huber weights on [dp, dtheta] (right perturbation).

    Two passes: the first associates with the map's coarse gate (``MatchParams.coarse_residual``)
    since a constant-velocity prediction can be decimetres off; once it has converged, a second pass
    of up to ``max_iterations`` re-associates with the tight gate (``max_residual``), which keeps the
    points matched to another surface out of the final pose.

    An iterate searches the map again only when it moved a point 20 m away by more than
    ``reassociate`` m since the last search (``filter.reassociate``, as the filter's measurement);
    else the last search's rows are evaluated at the iterate and gated there (the neighbours of a
    point moved by a few mm are the same ones, and the search is the cost). 0: every iterate."""
    R, p = R_w_s.copy(), p_w.copy()
    n_it, n = 0, 0
    pr = local_map.params
    gates = [pr.coarse_residual] * max_iterations + [pr.max_residual] * max_iterations
    fine = len(gates) // 2
    it = 0
    base: Correspondences | None = None  # the rows of the last search
    at = (R, p)  # the pose of the last search
    while it < len(gates):
        gate = gates[it]
        it += 1
        n_it += 1
        if base is None or moved(at[0], at[1], R, p) > reassociate:
            base = local_map.associate(surf, edge, R, p, gate)
            at = (R, p)
            r, J = base.system(R, p)
        else:
            r, J = base.system(R, p)
            keep = np.abs(r) < gate
            r, J = r[keep], J[keep]
        n = len(r)
        if n < 6:
            break
        w = huber_weights(r, huber)
        H = J.T @ (w[:, None] * J) + 1e-9 * np.eye(6)
        dx = -np.linalg.solve(H, J.T @ (w * r))
        p = p + dx[:3]
        R = R @ exp(dx[3:])
        if np.linalg.norm(dx) < converge:
            if it > fine or pr.coarse_residual <= pr.max_residual:
                break
            it = fine  # the coarse pass has converged: on to the tight gate
    return Registration(R, p, n_it, n)


class LidarOdometry:
    """Scan-to-map odometry with no IMU. Poses are of the LiDAR frame in the first scan's frame."""

    def __init__(self, config: LioConfig | None = None) -> None:
        self.config = config or LioConfig(use_imu=False)
        m = self.config.map
        self.map = LocalMap(m.voxel, m.radius, m.max_per_voxel, m.knn, m.match_params())
        self.T_w_l = np.eye(4)
        self.T_prev = np.eye(4)
        self.t_last: float | None = None
        self.dt_frames = 0.1
        self.n_scans = 0
        self.last_iterations = 0
        self.last_n_corr = 0
        self.last_n_used = 0
        self.peak_map_points = 0
        self.last_cov = np.full((6, 6), np.nan)  # ``filter.lidar_model: plane``: [dp, dtheta]
        #: the last scan's registered points (surface, edge), deskewed, LiDAR frame at the scan end
        self.last_points: tuple[FloatArray, FloatArray] = (np.zeros((0, 3)), np.zeros((0, 3)))

    def register_scan(
        self,
        points_l: FloatArray,
        t_s: FloatArray,
        ring: NDArray[np.integer] | None = None,
        rotation_compensated: bool = False,
        motion: tuple[FloatArray, FloatArray] | None = None,
    ) -> FloatArray:
        """Register one scan; returns ``T_w_l`` (4, 4) at the scan end ``max(t_s)``.

        ``rotation_compensated``: the points were already rotated into the scan-end frame (e.g. from a
        gyro); the constant-velocity model then only removes the translation.

        points_l: (N, 3) LiDAR frame at each point's time; t_s: (N,) point times, s (any origin, the
        same clock for every scan); ring: (N,) beam index or None; motion: the scan-end pose
        prediction ``T_w_l`` (4, 4) and the world velocity (3,) that deskews the translation, in place
        of the constant-velocity model (a second pass over scans whose motion is known).
        """
        t_end = float(np.max(t_s))
        if self.t_last is not None and t_end > self.t_last:
            self.dt_frames = t_end - self.t_last
        omega, vel = constant_velocity_motion(self.T_prev, self.T_w_l, self.dt_frames)
        D = np.linalg.inv(self.T_prev) @ self.T_w_l if self.n_scans >= 2 else np.eye(4)
        T_pred = self.T_w_l @ D
        if self.n_scans < 2:
            omega, vel = np.zeros(3), np.zeros(3)
        if rotation_compensated:
            omega = np.zeros(3)
        if motion is not None:
            T_pred, vel = np.asarray(motion[0], float), np.asarray(motion[1], float)
        pts = deskew_constant_velocity(points_l, t_s, t_end, T_pred, omega, vel)
        surf, edge = select_points(pts, t_s, ring, self.config.frontend)
        if len(self.map) == 0:
            reg = Registration(T_pred[:3, :3], T_pred[:3, 3], 0, 0)
        else:
            reg = gauss_newton(self.map, surf, edge, T_pred[:3, :3], T_pred[:3, 3],
                               reassociate=self.config.filter.reassociate)  # fmt: skip
            if self.config.filter.lidar_model != "dof" and reg.n_corr >= 6:
                # refined with the rows' noise model (lio.rowcov) at the tight gate
                from imuslam.lio.rowcov import gauss_newton_rows

                R_r, p_r, n_it, n_c, self.last_cov = gauss_newton_rows(
                    self.map, surf, edge, reg.R_w_s, reg.p_w, self.config.filter.lidar_range_std,
                    coarse=False, diagonal=self.config.filter.lidar_model == "plane_diag",
                )  # fmt: skip
                reg = Registration(R_r, p_r, reg.iterations + n_it, n_c)
            if reg.n_corr < 6:
                raise FilterDivergence(
                    f"scan {self.n_scans} (t = {t_end:.3f} s): {reg.n_corr} point-to-map "
                    "correspondences; the scan does not overlap the map"
                )
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = reg.R_w_s, reg.p_w
        self.map.insert(surf, edge, reg.R_w_s, reg.p_w)
        if self.n_scans % 10 == 0:
            self.map.prune(reg.p_w)
        self.T_prev, self.T_w_l = self.T_w_l, T
        self.t_last = t_end
        self.n_scans += 1
        self.last_iterations, self.last_n_corr = reg.iterations, reg.n_corr
        self.last_n_used = len(surf) + len(edge)
        self.last_points = (surf, edge)
        self.peak_map_points = max(self.peak_map_points, len(self.map))
        return T
