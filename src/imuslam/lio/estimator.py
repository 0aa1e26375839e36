"""LiDAR-inertial odometry: the iterated error-state Kalman filter of seed 001 on the shared inertial core.

State (``imuslam.ins.core.InsState``): IMU position, velocity and attitude in the world w (z up, along
gravity), biases and gravity. Error state (``ErrorLayout``): ``reduced`` = [dtheta, dp, dv, dg] (12), for
an IMU corrected beforehand (seed 001, module 3: the biases are dropped), or ``full`` = [dtheta, dp, dv,
db_a, db_g, dg] (18). Per scan (FAST-LIO2, Xu et al., T-RO 2022, Sec. IV):

1. prediction: the core's propagation kernel over the IMU samples up to the scan end (``Eskf.predict``),
   which returns the per-sample states;
2. deskew: every point moved to the scan-end frame from those states (backward propagation);
3. update: ``Eskf.iterated_update`` with a point-to-plane / point-to-line measurement that re-associates
   against the local map at every iterate, until the correction is below ``converge``;
4. mapping: the registered points go into the voxel map, pruned around the sensor.

Initialisation over the first ``align_seconds``: the LiDAR-only odometry gives poses; ``align none``
(LINS-like) takes the tilt from the mean specific force, the velocity from the LiDAR poses and zero
biases; ``kf`` / ``stkf`` / ``rwnn`` run ``imuslam.ins.align.run_alignment`` with the LiDAR positions
as aiding and start from its attitude, velocity and biases.
A pure object: ``register_scan(points, times, ring) -> T_w_i``; it reads no files.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import FilterDivergence, InputError
from imuslam.ins.coarse import level_rotation
from imuslam.ins.core import ErrorLayout, InsState, KfNoise, boxplus, propagate_covariance
from imuslam.interfaces.imu import ImuLog
from imuslam.lio.config import LioConfig
from imuslam.lio.deskew import deskew
from imuslam.lio.frontend import select_indices, select_points
from imuslam.lio.guards import DegeneracyGuard, GuardedEskf, inflate, repair_imu
from imuslam.lio.lidar_only import LidarOdometry
from imuslam.lio.matcher import Correspondences, LocalMap, huber_weights

if TYPE_CHECKING:  # lio.rowcov (scipy.sparse) is imported only with ``filter.lidar_model: plane``
    import scipy.sparse as sp

    from imuslam.lio.online_calib import OnlineCalibration
    from imuslam.lio.rowcov import SensorOrigins

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]


@dataclass
class SharedMapNoise:
    """What ``filter.lidar_model: plane`` needs (``lio.rowcov``): the LiDAR's origin in the IMU frame
    p_i_l (3,), the inserting scans' LiDAR origins and the range noise 1-sigma, m; ``diagonal``
    (``plane_diag``): the map points' noise on each row's own variance, no sharing between rows."""

    p_i_l: FloatArray
    origins: SensorOrigins
    range_std: float
    diagonal: bool = False


class LidarMeasurement:
    """Point-to-plane / point-to-line residuals of one scan against the local map, re-associated at an
    iterate whose pose moved a point at ``reach`` m by more than ``reassociate`` m since the last
    association (else the same planes are re-evaluated at the new pose: the nearest neighbours of a few
    mm moved points are the same, and the search is the cost); ``linearize`` returns the innovation -r (M,), H (M, dim) and the diagonal R (M,) inflated
    by the Huber weights (iteratively reweighted least squares)."""

    kind = "lidar"

    def __init__(self, local_map: LocalMap, surf_i: FloatArray, edge_i: FloatArray, std: float,
                 huber: float, dof: float = np.inf, reassociate: float = 0.0,
                 reach: float = 20.0, shared: SharedMapNoise | None = None) -> None:  # fmt: skip
        self.map = local_map
        # ``filter.lidar_model: plane``: the rows' own range noise and the frozen map points' noise they
        # share (``lio.rowcov``) instead of the diagonal std^2 scaled by M / dof
        self.shared = shared
        self._s = np.zeros(0)
        self._G: sp.csr_matrix | None = None
        self._s_all = np.zeros(0)
        self._G_all: sp.csr_matrix | None = None
        self.reassociate = reassociate
        self.reach = reach
        self._at: tuple[FloatArray, FloatArray] | None = None
        self._corr: Correspondences | None = None
        self.surf_i = surf_i
        self.edge_i = edge_i
        self.var = std * std
        self.huber = huber
        self.dof = dof
        self.n_corr = 0
        self.last_H, self.last_R = np.zeros((0, 0)), np.zeros(0)
        self.n_calls = 0
        self.n_assoc = 0
        # the association keeps every row within the map's coarse gate (``MatchParams.coarse_residual``);
        # ``tight`` keeps of those the rows within ``max_residual`` at the iterate where it is set or
        # where the rows are searched again (the same rows a search with the tight gate finds there,
        # without a second nearest-neighbour search)
        pr = local_map.params
        self.coarse_gate = max(pr.coarse_residual, pr.max_residual)
        self.tight_gate = pr.max_residual
        self.tight = True
        self._all: Correspondences | None = None

    def set_tight(self, tight: bool) -> None:
        """Use the tight gate (True) or the coarse one from the next linearisation on."""
        if tight != self.tight:
            self.tight, self._corr = tight, None

    def _moved(self, x: InsState) -> float:
        """How far the pose moved a point at ``reach`` m since the last association, m (bound)."""
        assert self._at is not None
        R0, p0 = self._at
        c = np.clip((np.trace(R0.T @ x.R_n_b) - 1.0) / 2.0, -1.0, 1.0)
        return float(np.linalg.norm(x.p_n - p0) + self.reach * np.arccos(c))

    def linearize(
        self, x: InsState, layout: ErrorLayout
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        sh = self.shared
        if self._all is None or self._at is None or self._moved(x) > self.reassociate:
            if sh is None:
                self._all = self.map.associate(
                    self.surf_i, self.edge_i, x.R_n_b, x.p_n, self.coarse_gate
                )
            else:
                from imuslam.lio.rowcov import associate_shared

                origin = x.R_n_b @ sh.p_i_l + x.p_n
                self._all, self._s_all, self._G_all = associate_shared(
                    self.map, self.surf_i, self.edge_i, x.R_n_b, x.p_n, self.coarse_gate,
                    origin, sh.origins, sh.range_std, sh.diagonal,
                )  # fmt: skip
            self._corr, self._at = None, (x.R_n_b.copy(), x.p_n.copy())
            self.n_assoc += 1
        corr = self._corr
        if corr is None:
            corr = self._all
            self._s, self._G = self._s_all, self._G_all
            if self.tight and self.tight_gate < self.coarse_gate:
                r_all, _ = corr.system(x.R_n_b, x.p_n)
                keep = np.abs(r_all) < self.tight_gate
                corr = corr.subset(keep)
                if sh is not None:
                    assert self._G_all is not None
                    self._s, self._G = self._s_all[keep], self._G_all[np.flatnonzero(keep)]
            self._corr = corr
        self.n_corr = len(corr)
        self.n_calls += 1
        r, J = corr.system(x.R_n_b, x.p_n)
        if sh is not None:
            from imuslam.lio.rowcov import tukey_weights, whitened_system

            assert self._G is not None
            # the rows' own variance (a floor of a tenth of the range noise where the beam grazes the
            # plane, numerical) and the shared map noise G G^T
            s = np.maximum(self._s, 0.1 * sh.range_std)
            # Tukey's biweight on the residual in units of its own predicted sigma (IRLS): the row's
            # whole covariance inflated by 1 / w, as scaling its residual and Jacobian by sqrt(w);
            # the metric Huber (0.2 m) would leave the few rows on another surface (a kerb, a corner
            # straddled by the neighbours, 2-3 % beyond 3 sigma) their full weight
            g2 = 0.0 if sh.diagonal else np.asarray(self._G.multiply(self._G).sum(axis=1)).ravel()
            sw = tukey_weights(r / np.sqrt(s * s + g2))
            r, J, D = r * sw, J * sw[:, None], s * s
            U, z = whitened_system(r, J, D, self._G)
            Hc = np.zeros((6, layout.dim))
            Hc[:, layout.P], Hc[:, layout.TH] = U[:, :3], U[:, 3:]
            self.last_H, self.last_R = Hc, np.ones(6)
            return -z, Hc, np.ones(6)
        H = np.zeros((len(r), layout.dim))
        H[:, layout.P] = J[:, :3]
        H[:, layout.TH] = J[:, 3:]
        scale = max(
            1.0, len(r) / self.dof
        )  # correlated residuals: M rows worth ``dof`` independent ones
        Rd = scale * self.var / huber_weights(r, self.huber)
        self.last_H, self.last_R = H, Rd
        return -r, H, Rd

    @property
    def tags(self) -> NDArray[np.int32]:
        """The map tag of each row of the last linearisation."""
        assert self._corr is not None
        return self._corr.tag


class MapCovariance:
    """The map's own error in the absolute pose covariance: a consider term (Schmidt 1966; Simon,
    Optimal State Estimation, 2006, sec. 7.5) that the gain never sees.

    The update registers the scan against a map built from the filter's own poses and takes that map
    as exact (FAST-LIO2, Xu et al. 2022, eq. 12: the noise is the point's only), so the filter's
    covariance ``P_rel`` is that of the pose relative to the map, and its estimate is FAST-LIO2's.
    The absolute error adds the map's: write the prior's error as e_prior = e_map + d, the map's
    error (the error the pose inherits from the matched map, below) plus the error relative to the
    map d, with cov(d) = P_rel (the filter's prior). The innovation only sees d,
    r = H d + n, so the update leaves e_post = e_map + (I - K H) d - K n: the map's error passes
    through unchanged (the LiDAR cannot reduce it) and P_abs = P_rel,post + C with C = cov(e_map).
    Treating e_map as independent of the prior's error instead (P += K H C (K H)^T, or map noise
    independent per point) drops what they share: the map and the pose drift together, and every
    scan would shrink the absolute attitude variance the map keeps. Between updates (a scan with too
    few matches) P_abs - P_rel propagates as Phi D Phi^T (the process noise is in P_rel already).

    C: every map point carries the tag of the scan that inserted it and that scan's pose and
    absolute [theta, p] covariance are recorded here. A map piece inserted at pose j with error
    (dtheta_j, dp_j) (attitude on the right, position in w) is the piece moved rigidly about p_j; a
    pose k registered on it inherits e_map = J_kj [dtheta_j; dp_j] with
    J_kj = [[R_k^T R_j, 0], [-[p_k - p_j]x R_j, I]] (a rotation error about p_j moves the piece by
    dtheta x (p_k - p_j) at the current pose). The pieces' errors come from one drifting trajectory,
    so they are taken as fully correlated: C is the mean of J_kj P_j J_kj^T over the matched rows (a
    mean, not the covariance of a mean of independent errors, which would shrink with the count).
    ``correlation="independent"`` (``filter.map_correlation``) splits P_j into the part the piece
    inherited from its own map (still fully correlated) and its scan's map-relative covariance, taken
    as independent between pieces: that part enters as sum_u w_u^2 J_u Prel_u J_u^T, the covariance
    of the weighted mean of independent errors (README, LIO covariance: neither model is inside the
    NEES band on every drive).
    The world is the first IMU pose (FAST-LIO2's), where the map has no error by construction.
    ``drift`` (``filter.map_drift_*``, zero by default) adds a random walk of the map along the
    path for scenes whose registration drifts: a record gains ``drift`` times the path since the
    previous record; the points from before the filter (LiDAR-only, tag -1) carry the drift over the
    start's path, and with ``filter.start_covariance`` the start's own registration covariance
    (``LioEstimator._start_map_covariance``). (Its rates were once fitted to a 0.5-1 deg roll /
    pitch drift on the simulated street, which was the 1 m association gate's doing,
    ``MapConfig.max_residual``.)"""

    def __init__(self, R0: FloatArray, p0: FloatArray, C0: FloatArray, slots: int = 4096,
                 drift: FloatArray | None = None,
                 correlation: Literal["full", "independent"] = "full") -> None:  # fmt: skip
        # drift (6,): the diagonal [theta, p] variance the map gains per metre of path (rad^2/m, m^2/m)
        self.drift = np.zeros(6) if drift is None else np.asarray(drift, float)
        self._last_p = np.asarray(p0, float).copy()
        # a ring of ``slots`` records (memory flat over any drive): slot 0 holds the points from before
        # the filter (tag -1), tag t >= 0 the slot 1 + t mod (slots - 1); a point older than that many
        # scans still in the map (a revisit) reads a later scan's covariance, which is larger
        self._R = np.zeros((slots, 3, 3))
        self._p = np.zeros((slots, 3))
        self._C = np.zeros((slots, 6, 6))  # [theta, p] absolute covariance at insertion
        self._Crel = np.zeros((slots, 6, 6))  # its map-relative part (the filter's P at insertion)
        self._R[0], self._p[0], self._C[0] = R0, p0, C0
        self.correlation = correlation
        self.n = 0

    def _slot(self, tag: NDArray[np.int64]) -> NDArray[np.int64]:
        return np.where(tag < 0, 0, 1 + tag % (len(self._p) - 1))

    def record(self, R_w_i: FloatArray, p_w: FloatArray, C: FloatArray,
               C_rel: FloatArray | None = None) -> int:  # fmt: skip
        """Record an inserting pose and its absolute [theta, p] covariance (6, 6), of which ``C_rel``
        (6, 6) is the map-relative part (the filter's own; zero if not given); returns its tag."""
        tag = self.n
        i = int(self._slot(np.array([tag]))[0])
        step = float(np.linalg.norm(p_w - self._last_p))  # path since the last record, m
        self._last_p = np.asarray(p_w, float).copy()
        self._R[i], self._p[i], self._C[i] = R_w_i, p_w, C + np.diag(self.drift * step)
        self._Crel[i] = 0.0 if C_rel is None else C_rel
        self.n += 1
        return tag

    def transfer(
        self, tag: NDArray[np.int32], R_w_i: FloatArray, p_w: FloatArray
    ) -> tuple[NDArray[np.int64], FloatArray, FloatArray]:
        """The records of the rows tagged ``tag`` (M,) seen from the pose (R_w_i, p_w): their slots
        (U,), the rows' share of each (U,) and J_kj (U, 6, 6)."""
        count = np.bincount(self._slot(np.asarray(tag, np.int64)), minlength=len(self._p))
        u = np.flatnonzero(count)
        Rj, lever = self._R[u], p_w - self._p[u]
        J = np.zeros((len(u), 6, 6))
        J[:, :3, :3] = np.einsum("ji,ujk->uik", R_w_i, Rj)
        Lx = np.zeros((len(u), 3, 3))  # [lever]x
        Lx[:, 0, 1], Lx[:, 0, 2], Lx[:, 1, 2] = -lever[:, 2], lever[:, 1], -lever[:, 0]
        Lx[:, 1, 0], Lx[:, 2, 0], Lx[:, 2, 1] = lever[:, 2], -lever[:, 1], lever[:, 0]
        J[:, 3:, :3] = -Lx @ Rj
        J[:, 3:, 3:] = np.eye(3)
        return u, count[u] / max(len(tag), 1), J

    def covariance(self, tag: NDArray[np.int32], R_w_i: FloatArray, p_w: FloatArray) -> FloatArray:
        """C (6, 6) on [theta, p]: the matched map's error covariance seen from (R_w_i, p_w)."""
        u, w, J = self.transfer(tag, R_w_i, p_w)
        Cu = self._C[u]
        # independent own parts: sum_u w_u J (C_u - Crel_u) J^T + sum_u w_u^2 J Crel_u J^T
        if self.correlation == "independent":
            Cu = Cu - self._Crel[u] * (1.0 - w)[:, None, None]
        A = (J @ Cu) * w[:, None, None]  # sum_u w_u J_u C_u J_u^T as one (6, 6U) product
        return np.asarray(
            A.transpose(1, 0, 2).reshape(6, -1) @ J.transpose(1, 0, 2).reshape(6, -1).T
        )


class _Memo:
    """``meas.linearize`` at a state, answered again without recomputing when it is asked for the
    same state object with the same gate (the count of rows before an update and the update's first
    iterate linearise at the same state)."""

    def __init__(self, meas: LidarMeasurement, layout: ErrorLayout) -> None:
        self.meas, self.layout = meas, layout
        self._key: tuple[InsState, bool] | None = None
        self._out: tuple[FloatArray, FloatArray, FloatArray] | None = None

    def __call__(self, x: InsState) -> tuple[FloatArray, FloatArray, FloatArray]:
        if (
            self._out is None
            or self._key is None
            or self._key[0] is not x
            or self._key[1] != self.meas.tight
        ):
            self._out = self.meas.linearize(x, self.layout)
            self._key = (x, self.meas.tight)
        return self._out


class LioEstimator:
    """Iterated ESKF LiDAR-inertial odometry. ``imu``: the whole IMU log (SI, IMU frame, already
    calibrated if a calibration is used); scan times are seconds after ``imu.t_ns[0]``."""

    def __init__(self, config: LioConfig, imu: ImuLog) -> None:
        if imu.accel_unit != "m/s^2" or imu.gyro_unit != "rad/s":
            raise ValueError(f"{imu.source}: the LIO needs the IMU in m/s^2 and rad/s")
        if len(imu) < 10:
            raise InputError(f"{imu.source}: {len(imu)} IMU samples; at least 10 are needed")
        self.config = config
        fc = config.filter
        # the gyro's clipped runs bridged, its gaps listed (``lio.guards``), with the covariance they add
        self.repair = (
            repair_imu(imu, fc.gyro_range_dps, fc.gyro_clip_margin) if fc.imu_guard else None
        )
        self.imu = imu if self.repair is None else self.repair.imu
        self.t = imu.t_s
        self.T_i_l = config.extrinsic.T_i_l()
        self.layout = (
            ErrorLayout.reduced() if fc.state == "reduced" else ErrorLayout.full(gravity=True)
        )
        # the extrinsic / offset as states (off by default)
        self.calib: OnlineCalibration | None = None
        if fc.estimate_extrinsic or fc.estimate_time_offset:
            from imuslam.lio.online_calib import OnlineCalibration

            self.calib = OnlineCalibration(config, self.layout)
            self.layout = self.calib.layout
        self.degeneracy = DegeneracyGuard(self.layout, fc.degenerate_std, fc.degeneracy_guard)
        # (scan, time s, degenerate directions, the weakest direction's 1-sigma m) per degenerate scan
        self.degenerate_scans: list[tuple[int, float, list[str], float]] = []
        self._lost: list[
            tuple[int, float, float]
        ] = []  # the scans in a row that matched too little
        self.noise = KfNoise(fc.accel_noise, fc.gyro_noise, max(fc.accel_bias_rw, 1e-12),
                             max(fc.gyro_bias_rw, 1e-12))  # fmt: skip
        m = config.map
        self.map = LocalMap(m.voxel, m.radius, m.max_per_voxel, m.knn, m.match_params())
        self.lidar_only = LidarOdometry(config.model_copy(update={"use_imu": False}))
        self._init_scans: list[tuple[float, FloatArray]] = []
        # the start's rotation-compensated scans (points, times, ring), for its second pass
        self._init_points: list[tuple[FloatArray, FloatArray, NDArray[np.integer] | None]] = []
        self._t_mean0 = 0.0  # the mean point time of the first scan, s
        self.eskf: GuardedEskf | None = None
        self.t_state = 0.0
        self.n_scans = 0
        self.last_iterations = 0
        self.last_n_corr = 0
        self.last_n_used = 0
        #: the last scan's registered points (surface, edge), deskewed, IMU frame at the scan end
        self.last_points: tuple[FloatArray, ...] = (np.zeros((0, 3)), np.zeros((0, 3)))
        self.peak_map_points = 0
        self.n_no_update = 0
        self.alignment: object | None = None
        self.T_w_i0 = np.eye(
            4
        )  # the levelled world in the first IMU frame's terms, set at initialisation
        self.n_before_filter = 0  # poses returned in the first IMU frame, before the filter started
        # those poses again from the start's last pass (``_second_pass``), first IMU frame (n, 4, 4)
        self.start_poses = np.zeros((0, 4, 4))
        self.map_cov: MapCovariance | None = None
        self._D = np.zeros((self.layout.dim, self.layout.dim))  # P_abs - P_rel (MapCovariance)
        self.shared: SharedMapNoise | None = None
        if fc.lidar_model != "dof":
            from imuslam.lio.rowcov import SensorOrigins

            self.shared = SharedMapNoise(self.T_i_l[:3, 3].copy(), SensorOrigins(),
                                         fc.lidar_range_std, fc.lidar_model == "plane_diag")  # fmt: skip
        self._n_inserted = 0
        self._start_covs: list[FloatArray] = []  # the start's registration covariances (last pass)
        self._pose_index = np.r_[self.layout.TH, self.layout.P]  # [theta, p] in the error state

    # ------------------------------------------------------------------------------------------
    def _samples(self, t0: float, t1: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        """IMU samples on [t0, t1] with both ends interpolated: times (K,), accel, gyro (K, 3)."""
        t = self.t
        if t1 > t[-1] + 0.05 or t0 < t[0] - 0.05:
            raise InputError(
                f"{self.imu.source}: scan at {t1:.3f} s is outside the IMU's time span "
                f"[{t[0]:.3f}, {t[-1]:.3f}] s (no overlap between IMU and LiDAR times?)"
            )
        i0, i1 = np.searchsorted(t, t0, side="right"), np.searchsorted(t, t1, side="left")
        inner = np.arange(i0, i1)
        if i1 > i0 and np.max(np.diff(t[max(i0 - 1, 0) : min(i1 + 1, len(t))])) > 0.1:
            log.debug("IMU gap of more than 0.1 s before t = %.3f s", t1)
        ts = np.concatenate([[t0], t[inner], [t1]])
        acc = np.column_stack([np.interp(ts, t, self.imu.accel[:, a]) for a in range(3)])
        gyr = np.column_stack([np.interp(ts, t, self.imu.gyro[:, a]) for a in range(3)])
        keep = np.concatenate([[True], np.diff(ts) > 1e-9])
        return ts[keep], acc[keep], gyr[keep]

    # passes over the start's scans (``_second_pass``): each costs about 20 ms a start scan. With the
    # velocity of a smooth fit of the poses (``start_velocity``) the second pass changes it by 0.1 m/s
    # on the street (1.3 m/s the first): two passes, the deskew then off by at most 1 cm a sweep
    START_PASSES = 2

    @staticmethod
    def start_velocity(ts: FloatArray, p: FloatArray) -> FloatArray:
        """Velocity (K, 3) at the times ``ts`` (K,) of the positions ``p`` (K, 3): the derivative of a
        per-axis least-squares quadratic in time (constant acceleration over the start's second, a
        car's motion; a quadratic through 3 poses, a line through 2). Central differences of poses
        0.2 s apart turn each pose's registration error e into a velocity error of about e / 0.2 s,
        which the next pass's deskew put back into its poses: on the street (seed 11, direct) their
        velocity changed by up to 3.2 m/s at the first pass and still by 0.2 m/s at the fourth; the
        fit averages the start's 11 poses: 1.3, 0.09-0.10, 0.004 m/s at the first three passes."""
        ts = np.asarray(ts, float)
        tt = ts - ts.mean()
        deg = min(2, len(ts) - 1)
        V = np.vander(tt, deg + 1)  # columns t^deg ... t^0
        coef, *_ = np.linalg.lstsq(V, np.asarray(p, float), rcond=None)
        dV = np.zeros_like(V)
        for i in range(deg):  # d/dt of t^(deg - i)
            dV[:, i] = (deg - i) * tt ** (deg - i - 1)
        return np.asarray(dV @ coef)

    def _second_pass(self) -> None:
        """Register the start's scans again, each deskewed for translation with the velocity of the
        first pass (``start_velocity``, a smooth fit of its poses) and predicted at its first-pass
        pose, into a new map. The first pass knows no velocity for the first two scans (constant
        velocity from nothing): they enter the map smeared by the 0.8 m a car drives in a turn of the
        LiDAR, and the map keeps the first point of each voxel, so that warp stayed in it (on the
        street, 0.15 deg of roll / pitch and 5 cm at the filter start, which every later pose
        inherited). The first pass's velocity is wrong around its third scan (the first deskewed with
        a velocity, registered against the smeared ones), so the passes repeat, each with the
        velocity of the one before, until it changes by less than 0.05 m/s (at most
        ``START_PASSES``). One pass with central differences left the direct mode's start 0.09-0.16
        deg of pitch off on six street seeds (the same sign on all: not noise), the map tilted with
        it and the height drifted by that angle times the path (5 cm over 6 s on seed 13); with the
        fit and two passes the pitch at the filter start is within 0.06 deg on those seeds (a roll
        error of 0.04-0.10 deg remains, in both front ends)."""
        ts = np.array([s[0] for s in self._init_scans])
        T1 = np.array([s[1] for s in self._init_scans])
        vel = self.start_velocity(ts, T1[:, :3, 3])  # the LiDAR origin's, first LiDAR frame
        for _ in range(self.START_PASSES):
            lo = LidarOdometry(self.config.model_copy(update={"use_imu": False}))
            out, self._start_covs = [], []
            for (pts, t_s, ring), T, v in zip(self._init_points, T1, vel, strict=True):
                out.append(
                    lo.register_scan(pts, t_s, ring, rotation_compensated=True, motion=(T, v))
                )
                self._start_covs.append(lo.last_cov.copy())  # NaN unless the rows' model refines it
            T1 = np.array(out)
            v_new = self.start_velocity(ts, T1[:, :3, 3])
            change = float(np.max(np.linalg.norm(v_new - vel, axis=1)))
            vel = v_new
            if change < 0.05:  # m/s: the deskew moves a point by at most 5 mm more
                break
        self.lidar_only = lo
        self._init_scans = [(t, T) for t, T in zip(ts, T1, strict=True)]
        self._init_points = []

    def _start_map_covariance(
        self, R_w_i0: FloatArray, R_k: FloatArray, p_k: FloatArray
    ) -> FloatArray:
        """The start map's error covariance (6, 6) on [theta, p] at the start's last pose
        (``filter.start_covariance``): each start scan's registration covariance (the rows' model's,
        ``LidarOdometry.last_cov`` on the LiDAR's [dp, dtheta] in the first LiDAR frame) moved to the
        IMU's [theta, p] in w, chained along the start as odometry (C_k = J C_(k-1) J^T + Creg_k,
        J ``MapCovariance.transfer``'s), and the map, made of every start scan, their mean seen from
        the last pose (fully correlated pieces, ``MapCovariance``). The first scan defines the world."""
        R_i_l, p_i_l = self.T_i_l[:3, :3], self.T_i_l[:3, 3]
        R_w_l0 = R_w_i0 @ R_i_l
        p_l_i = -R_i_l.T @ p_i_l
        Lx = np.array([[0.0, -p_l_i[2], p_l_i[1]], [p_l_i[2], 0.0, -p_l_i[0]],
                       [-p_l_i[1], p_l_i[0], 0.0]])  # fmt: skip
        K = len(R_k)
        chain = MapCovariance(R_k[0], p_k[0], np.zeros((6, 6)), slots=K + 2)
        C = np.zeros((6, 6))
        for k in range(K):
            Creg = self._start_covs[k] if k < len(self._start_covs) else np.full((6, 6), np.nan)
            if k > 0:
                _, _, J = chain.transfer(np.array([k - 1], np.int32), R_k[k], p_k[k])
                C = J[0] @ C @ J[0].T
            if np.all(np.isfinite(Creg)):
                A = np.zeros((6, 6))  # [dp_l, dtheta_l] -> [theta_i, p_i]
                A[:3, 3:] = R_i_l
                A[3:, :3] = R_w_l0
                A[3:, 3:] = -R_k[k] @ R_i_l @ Lx
                C = C + A @ Creg @ A.T
            chain.record(R_k[k], p_k[k], C)
        return chain.covariance(np.arange(K, dtype=np.int32), R_k[-1], p_k[-1])

    def _initialise(self, t_end: float) -> None:
        """Start the filter at ``t_end`` from the LiDAR-only poses of the first scans (see module doc)."""
        from imuslam.ins.align import Aiding, run_alignment
        from imuslam.interfaces.nav import NavState

        cfg = self.config
        self._second_pass()
        ts = np.array([s[0] for s in self._init_scans])
        T_l0 = np.array([s[1] for s in self._init_scans])  # T_l0_lk
        T_l_i = np.linalg.inv(self.T_i_l)
        T_i0_ik = self.T_i_l @ T_l0 @ T_l_i  # IMU poses in the first IMU frame
        self.start_poses = T_i0_ik[:-1].copy()
        t0 = ts[0]
        _, acc, _ = self._samples(t0, min(t0 + 0.5, ts[-1]))
        R_w_i0 = level_rotation(acc.mean(axis=0))  # w: levelled first IMU frame, zero yaw
        R_k = R_w_i0 @ T_i0_ik[:, :3, :3]
        p_k = T_i0_ik[:, :3, 3] @ R_w_i0.T
        # every scan of the start is deskewed with its velocity (``_second_pass``): the map has no
        # shift to take out of the world (with the first scan deskewed for rotation only, a point fired
        # at t_j sat v (t_end0 - t_j) ahead, and the map 0.44 m off on the street)
        shift = np.zeros(3)
        v_end = (p_k[-1] - p_k[-2]) / (ts[-1] - ts[-2])
        ba, bg = np.zeros(3), np.zeros(3)
        R_end, p_end = R_k[-1], p_k[-1]
        if cfg.align != "none":
            sel = (self.t >= t0) & (self.t <= ts[-1])
            win = ImuLog(self.imu.t_ns[sel], self.imu.accel[sel], self.imu.gyro[sel], "m/s^2", "rad/s",
                         self.imu.source)  # fmt: skip
            tw = self.t[sel]
            v0 = (p_k[1] - p_k[0]) / (ts[1] - ts[0])
            aid = Aiding(ts - tw[0], "position", p_k, 0.02)
            # the alignment starts at the first window sample, which lies just after the first scan end
            init = NavState(p_k[0] + v0 * (tw[0] - t0), v0, R_k[0])
            res = run_alignment(win, aid, init, cfg.align, self.noise)
            self.alignment = res
            ba, bg = res.accel_bias[-1], res.gyro_bias[-1]
            if not (np.all(np.isfinite(ba)) and np.all(np.isfinite(bg))):
                ba, bg = np.zeros(3), np.zeros(3)
            # attitude, velocity and position at the window end from the aligned INS, then moved to t_end
            nav = res.final
            ts_e, acc_e, gyr_e = self._samples(float(tw[-1]), t_end)
            from imuslam.ins.core import integrate_nominal

            P, V, R = integrate_nominal(acc_e, gyr_e, np.diff(ts_e), nav.p_n, nav.v_n,
                                        np.ascontiguousarray(nav.R_n_b), ba, bg,
                                        np.array([0.0, 0.0, -cfg.filter.g]), np.zeros(3))  # fmt: skip
            # keep the LiDAR position (the map is built there) and take attitude / velocity from the INS
            R_end, v_end = R[-1], V[-1]
            log.info("alignment %s: accel bias %s m/s^2, gyro bias %s rad/s", cfg.align,
                     np.round(ba, 4), np.round(bg, 5))  # fmt: skip
        x = InsState(p_end.copy(), v_end.copy(), R_end.copy(), ba.copy(), bg.copy(),
                     np.array([0.0, 0.0, -cfg.filter.g]))  # fmt: skip
        lay = self.layout
        sb = 0.05 if cfg.align == "none" else 0.01
        P0 = np.diag(lay.diag(theta=np.deg2rad(1.0) ** 2, p=0.05**2, v=0.2**2, ba=sb**2 * 100,
                              bg=sb**2, g=0.05**2))  # fmt: skip
        if self.calib is None:
            self.eskf = GuardedEskf(x, P=P0, noise=self.noise, layout=lay)
        else:  # the start's errors follow the prior extrinsic's (``OnlineCalibration.start``)
            self.eskf = self.calib.filter(
                x, P0, self._samples(t_end - 0.02, t_end)[2][-1] - bg, self.noise
            )
        if cfg.filter.map_covariance:
            # the world is the first IMU pose (the first scan's end, levelled once by R_w_i0): the map
            # has no error there by construction (FAST-LIO2's world); the points from before the filter
            # (the LiDAR-only start) carry the drift over the start's path, and every later record the
            # drift over the path since the previous one (``MapCovariance``, ``filter.map_drift_*``)
            idx = self._pose_index
            rf = cfg.resolved().filter
            q_deg, q_m = (
                float(rf.map_drift_deg_per_sqrt_m or 0.0),
                float(rf.map_drift_m_per_sqrt_m or 0.0),
            )
            drift = np.r_[np.full(3, np.deg2rad(q_deg) ** 2), np.full(3, q_m**2)]
            path0 = float(np.sum(np.linalg.norm(np.diff(p_k, axis=0), axis=1)))
            C0 = np.diag(drift * path0)
            if rf.start_covariance and self.shared is not None:
                C0 = C0 + self._start_map_covariance(R_w_i0, R_k, p_k)
            self.map_cov = MapCovariance(
                R_end, p_end, C0, drift=drift, correlation=cfg.filter.map_correlation
            )
            self._D[np.ix_(idx, idx)] = C0
        # the LiDAR-only map moves into w: x_w = T_w_i0 T_i_l x_l0
        T_w_l0 = np.eye(4)
        T_w_l0[:3, :3], T_w_l0[:3, 3] = R_w_i0, -shift
        T_w_l0 = T_w_l0 @ self.T_i_l
        self.map = self.lidar_only.map
        self.map.transform(T_w_l0[:3, :3], T_w_l0[:3, 3])
        self.t_state = t_end
        self.T_w_i0[:3, :3], self.T_w_i0[:3, 3] = R_w_i0, -shift
        self.n_before_filter = len(self._init_scans) - 1

    # ------------------------------------------------------------------------------------------
    def register_scan(
        self, points_l: FloatArray, t_s: FloatArray, ring: NDArray[np.integer] | None = None
    ) -> FloatArray:
        """Register one scan; returns ``T_w_i`` (4, 4) of the IMU at the scan end ``max(t_s)``.

        points_l: (N, 3) LiDAR frame at each point's time; t_s: (N,) s after the IMU log's first sample.
        """
        t_end = float(np.max(t_s))
        k = self.n_scans
        if self.eskf is None:
            # before the filter: the gyro takes out the rotation within the scan (a platform turning a
            # full circle per scan included), the LiDAR-only odometry's constant velocity the translation
            from imuslam.ins.core import integrate_nominal

            tk, _, gyr = self._samples(float(np.min(t_s)), t_end)
            z = np.zeros((len(tk), 3))
            _, _, Rk = integrate_nominal(z, gyr, np.diff(tk), np.zeros(3), np.zeros(3), np.eye(3), np.zeros(3),
                                         np.zeros(3), np.zeros(3), np.zeros(3))  # fmt: skip
            pts_rot = deskew(points_l, t_s, tk, Rk, z, z, z, gyr, self.T_i_l, t_end)
            T_l = self.lidar_only.register_scan(pts_rot, t_s, ring, rotation_compensated=True)
            self._init_points.append((pts_rot, np.asarray(t_s, float), ring))
            if not self._init_scans:
                self._t_mean0 = float(np.mean(t_s))
            self._init_scans.append((t_end, T_l))
            self.last_iterations, self.last_n_corr = (
                self.lidar_only.last_iterations,
                self.lidar_only.last_n_corr,
            )
            self.last_n_used = self.lidar_only.last_n_used
            R_i_l, p_i_l = self.T_i_l[:3, :3], self.T_i_l[:3, 3]
            self.last_points = tuple(q @ R_i_l.T + p_i_l for q in self.lidar_only.last_points)
            self.n_scans += 1
            span = t_end - self._init_scans[0][0]
            if span >= self.config.align_seconds and len(self._init_scans) >= 3:
                self._initialise(t_end)
                assert self.eskf is not None
                return self._pose(self.eskf.x)
            T_w_i = self.T_i_l @ T_l @ np.linalg.inv(self.T_i_l)
            return T_w_i  # the first IMU frame, before the filter's levelled world exists
        eskf = self.eskf
        x_prior = eskf.x
        if self.calib is not None:  # the offset estimated so far moves the scan onto the IMU clock
            t_s, self.T_i_l = self.calib.scan_clock(x_prior, t_s)
            t_end = float(np.max(t_s))
        if t_end <= self.t_state:
            raise InputError(
                f"scan {k}: ends at {t_end:.3f} s, not after the previous scan ({self.t_state:.3f} s)"
            )
        tk, acc, gyr = self._samples(self.t_state, t_end)
        Ps, Vs, Rs = eskf.predict(acc, gyr, tk)
        if self.repair is not None:
            eskf.P = inflate(eskf.P, self.layout, self.repair.extra_covariance(self.t_state, t_end))
        x = eskf.x
        omega = gyr - x.gyro_bias
        f_w = np.einsum("kij,kj->ki", Rs, acc - x.accel_bias)
        if self.calib is not None:  # the extra states' random walk, the unguarded covariance
            self.calib.predicted(eskf, Rs, gyr, tk, f_w)
        a_w = f_w + x.g_n
        sel = select_indices(points_l, t_s, ring, self.config.frontend)
        if sel is None:  # deskew everything, then the reference front end
            pts_l = deskew(points_l, t_s, tk, Rs, Ps, Vs, a_w, omega, self.T_i_l, t_end)
            surf_l, edge_l = select_points(pts_l, t_s, ring, self.config.frontend)
        else:
            # select on the scan as fired, deskew only what is registered (LOAM's smoothness spans 11
            # neighbours fired within 0.2 ms, which the motion does not change; FAST-LIO2 also
            # extracts before it undistorts): a tenth of the points go through the deskew
            i_all = np.concatenate(sel)
            pts = deskew(points_l[i_all], t_s[i_all], tk, Rs, Ps, Vs, a_w, omega, self.T_i_l, t_end)
            surf_l, edge_l = pts[: len(sel[0])], pts[len(sel[0]) :]
        R_i_l, p_i_l = self.T_i_l[:3, :3], self.T_i_l[:3, 3]
        surf_i, edge_i = surf_l @ R_i_l.T + p_i_l, edge_l @ R_i_l.T + p_i_l
        meas = LidarMeasurement(self.map, surf_i, edge_i, self.config.filter.lidar_std, 0.2,
                                self.config.filter.lidar_dof, self.config.filter.reassociate,
                                shared=self.shared)  # fmt: skip
        fc = self.config.filter
        # at least as many rows as states, else the IMU carries the filter through (corridors, fog)
        lin = _Memo(meas, self.layout)
        pr = self.map.params
        coarse = pr.coarse_residual > pr.max_residual
        # coarse to fine, as the LiDAR-only Gauss-Newton: the prior can be decimetres off at 50 m
        # (a drifted gyro bias, a raw IMU without bias states), where the tight gate
        # (``MapConfig.max_residual``) would keep too few true matches to pull it in; so the iterations
        # first converge with the coarse gate, then go on from there with the tight one, whose rows
        # alone make the estimate (no wall foot matched to the ground)
        meas.set_tight(not coarse)
        _, H0, R0 = lin(eskf.x)
        if meas.n_corr >= 3 * self.layout.dim:
            x_start = None
            # tested on the prior's rows; if degenerate, both passes' Jacobians projected (the
            # update's projector hook, as the in-filter extrinsic's)
            eskf.projector = self.degeneracy.projector(H0, R0)
            upd = lin if self.calib is None else self.calib.wrap(lin, eskf.x, meas)
            if coarse:
                first = eskf.iterated_update(upd, fc.max_iterations, fc.converge, commit=False)
                meas.set_tight(True)
                x_c = boxplus(eskf.x, first.dx, self.layout)
                lin(x_c)
                if meas.n_corr >= 3 * self.layout.dim:
                    x_start = x_c
                else:  # the tight gate keeps too few rows: the coarse rows make the update
                    meas.set_tight(False)
            res = eskf.iterated_update(upd, fc.max_iterations, fc.converge, x_start=x_start)
            self.last_iterations = res.iterations
            dg = self.degeneracy.last
            if dg is not None and dg.directions:
                self.degenerate_scans.append((k, t_end, dg.directions, float(dg.sigma[0])))
            if self.map_cov is not None:  # the consider term (MapCovariance), not fed to the gain
                idx = self._pose_index
                self._D = np.zeros_like(self._D)
                self._D[np.ix_(idx, idx)] = self.map_cov.covariance(meas.tags, eskf.x.R_n_b,
                                                                    eskf.x.p_n)  # fmt: skip
        else:
            self.n_no_update += 1
            self.last_iterations = 0
            if self.map_cov is not None:  # P_abs - P_rel carries on as Phi D Phi^T (MapCovariance)
                self._D, _ = propagate_covariance(self._D, Rs, gyr, x.gyro_bias, np.diff(tk),
                                                  f_w[:-1].mean(axis=0), np.zeros(4),
                                                  self.layout.offsets)  # fmt: skip
        x = eskf.x
        self._check_lost(k, t_end, meas.n_corr / max(len(surf_i) + len(edge_i), 1))
        speed = float(np.linalg.norm(x.v_n))
        if not (np.all(np.isfinite(x.p_n)) and speed <= fc.max_speed):
            raise FilterDivergence(
                f"scan {k} (t = {t_end:.3f} s): the filter diverged (speed {speed:.1f} m/s, limit {fc.max_speed:g})"
            )
        tag = -1
        if self.map_cov is not None:
            idx = self._pose_index
            P_rel = eskf.P[np.ix_(idx, idx)]
            tag = self.map_cov.record(x.R_n_b, x.p_n, P_rel + self._D[np.ix_(idx, idx)], P_rel)
        elif self.shared is not None:
            tag = self._n_inserted
        if self.shared is not None:  # the LiDAR origin the inserted points were measured from
            self.shared.origins.record(tag, x.R_n_b @ self.shared.p_i_l + x.p_n)
        self._n_inserted += 1
        R_ins, p_ins = x.R_n_b, x.p_n
        if self.calib is not None:  # the points with the updated extrinsic, at their updated time
            surf_i, edge_i, R_ins, p_ins = self.calib.insertion(x, x_prior, surf_l, edge_l)
        self.map.insert(surf_i, edge_i, R_ins, p_ins, tag)
        if k % 10 == 0:
            self.map.prune(x.p_n)
        self.peak_map_points = max(self.peak_map_points, len(self.map))
        self.t_state = t_end
        self.n_scans += 1
        self.last_n_corr = meas.n_corr
        self.last_n_used = len(surf_i) + len(edge_i)
        self.last_points = (surf_i, edge_i)
        self._last_meas = meas
        return self._pose(x)

    def last_residual_rms(self) -> float:
        """RMS point-to-map distance, m, of the last scan's matched points at its estimated pose
        (computed when asked: a viewer's figure, not the filter's); NaN before the filter starts."""
        meas = getattr(self, "_last_meas", None)
        corr = None if meas is None else meas._corr
        if self.eskf is None or corr is None or len(corr) == 0:
            return float("nan")
        r, _ = corr.system(self.eskf.x.R_n_b, self.eskf.x.p_n)
        return float(np.sqrt(np.mean(np.square(r))))

    def _check_lost(self, k: int, t_end: float, matched: float) -> None:
        """FilterDivergence when fewer than ``filter.min_match_fraction`` of a scan's points matched the
        map for ``filter.lost_scans`` scans in a row: the filter lost the map (on the simulated street a
        tracking filter matches 86-96 % of them; an attitude 20 deg off after a clipped turn, 6-14 %)."""
        fc = self.config.filter
        self._lost = self._lost + [(k, t_end, matched)] if matched < fc.min_match_fraction else []
        if len(self._lost) >= fc.lost_scans:
            k0, t0, _ = self._lost[0]
            fr = ", ".join(f"{100 * m:.0f} %" for *_, m in self._lost)
            near = (self.t > t0 - 1.0) & (self.t <= t0)
            peak = float(np.rad2deg(np.abs(self.imu.gyro[near]).max())) if near.any() else 0.0
            hint = (f"; the gyro read up to {peak:.0f} deg/s in the second before: if that is its "
                    "range, set filter.gyro_range_dps" if peak > 100.0 and fc.gyro_range_dps is None
                    else "")  # fmt: skip
            raise FilterDivergence(
                f"scan {k0} (t = {t0:.3f} s): the filter lost the map: {fr} of the points of scans "
                f"{k0}-{k} matched it (at least {100 * fc.min_match_fraction:g} % expected){hint}"
            )

    @staticmethod
    def _pose(x: InsState) -> FloatArray:
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = x.R_n_b, x.p_n
        return T

    @property
    def state(self) -> InsState | None:
        return None if self.eskf is None else self.eskf.x

    @property
    def covariance(self) -> FloatArray | None:
        """The error covariance (dim, dim): the filter's map-relative one plus the matched map's on
        the [attitude, position] block (``MapCovariance``: the absolute pose covariance; the other
        blocks are the filter's own); with ``filter.map_covariance`` off, the map-relative one."""
        if self.eskf is None:
            return None
        return self.eskf.P + self._D if self.map_cov is not None else self.eskf.P
