"""Target-free LiDAR-IMU calibration: the LiDAR pose on the IMU ``T_i_l`` and the LiDAR clock offset
(``t_imu = t_lidar + time_offset_s``) from a LiDAR-only odometry of the scans and the IMU samples, with
1-sigma from the least squares and an observability verdict. Pure: no files.

The method follows LI-Init (Zhu, Ren and Zhang, "Robust Real-time LiDAR-inertial Initialization",
IROS 2022, Sec. IV), written here as a batch least squares over a smoothed LiDAR trajectory (the
continuous-time form of Furgale, Rehder and Siegwart, "Unified Temporal and Spatial Calibration for
Multi-Sensor Systems", IROS 2013, and of Lv et al., "Targetless Calibration of LiDAR-IMU System Based
on Continuous-time Batch Estimation", IROS 2020):

1. LiDAR-only odometry (``lio.lidar_only``, constant-velocity deskew) gives ``T_w_l(t_k)`` at each
   scan end, in the LiDAR clock; the LiDAR angular rate over each scan interval is
   ``omega_l = Log(R_w_l(t_k)^T R_w_l(t_k+1)) / (t_k+1 - t_k)``.
2. Coarse time offset: the maximum of the zero-mean cross-correlation of ``|omega_l|`` with the norm of
   the gyro averaged over the same interval shifted by the offset (LI-Init Sec. IV-B: the norms do not
   depend on the unknown rotation).
3. Coarse rotation: the hand-eye rotation of the angular rates ``omega_i = R_i_l omega_l + b_g``
   (LI-Init Sec. IV-C), in closed form by the SVD of the centred cross-covariance (Kabsch / Arun et
   al. 1987), then refined with the gyro bias and the offset by least squares.
4. The scans are registered again with their rotation deskewed by the gyro through the coarse
   rotation and offset (the constant-velocity deskew is wrong by the angular acceleration times the
   scan period).
5. Joint refinement of ``R_i_l``, ``p_i_l``, the offset, both biases and the gravity direction at every
   IMU sample: smoothing splines of the LiDAR position and rate give ``a_w_l``, ``omega_l``,
   ``alpha_l``; the gyro measures ``omega_i = R_i_l omega_l + b_g`` and the accelerometer the specific
   force of the IMU point ``p_l_i = -R_i_l^T p_i_l`` (LI-Init Sec. IV-D, rigid-body kinematics)::

       f_i = R_i_l [R_w_l^T (a_w_l - g_w) + alpha_l x p_l_i + omega_l x (omega_l x p_l_i)] + b_a

   all evaluated at the LiDAR time ``t_imu - time_offset_s``. A weak prior at the starting values
   keeps the directions the motion did not excite where they started.

The covariance is the inverse of the information ``J^T W J`` with the weights from the residuals'
own scatter, inflated by their integrated autocorrelation time (the spline's error is correlated
over many IMU samples; the effective number of samples is N / tau). Observability: the information
of the rotation and the lever-arm blocks, with the other parameters marginalised (Schur complement),
is eigen-decomposed; a direction whose 1-sigma exceeds the limit (``ObservabilityLimits``) was not
excited by the motion, and a parameter whose 1-sigma exceeds it is reported unobservable (a ground
vehicle that only yaws cannot see the lever arm along its yaw axis). A parameter within the limit whose
1-sigma still exceeds its accuracy target (``AccuracyTargets``: 0.2 deg, 2 cm, 1 ms) is reported weakly
observed: its value is the data's, but the data do not promise the target (a car that only yaws sees the
LiDAR's rotation about the vertical through its horizontal accelerations alone: 1-sigma 0.2-0.45 deg on
20-30 s of the simulated street loop).
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import BSpline, make_lsq_spline
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation, RotationSpline, Slerp

from imuslam.errors import InputError
from imuslam.interfaces import ImuLog, Scan3d
from imuslam.lio.config import ExtrinsicConfig, LioConfig, ObservabilityLimits
from imuslam.lio.lidar_only import LidarOdometry

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]
AXES = ("x", "y", "z")


@dataclass(frozen=True)
class AccuracyTargets:
    """The accuracy the calibration is meant to reach: rotation about an IMU axis, deg; lever arm along
    an IMU axis, m; clock offset, s. An observed parameter whose 1-sigma exceeds its target is reported
    weakly observed (``LidarImuCalibration.weakly_observed``)."""

    rotation_deg: float = 0.2
    translation_m: float = 0.02
    time_offset_s: float = 1e-3


@dataclass
class LidarTrack:
    """LiDAR-only odometry: scan-end times ``t_s`` (K,), LiDAR clock, s after ``t_ref_ns``; poses of the
    LiDAR in the first scan's frame ``R_w_l`` (K, 3, 3), ``p_w_l`` (K, 3)."""

    t_s: FloatArray
    R_w_l: FloatArray
    p_w_l: FloatArray
    t_ref_ns: int

    def rates(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Interval starts, ends (K-1,) s and the mean LiDAR-frame rate over each (K-1, 3), rad/s."""
        dR = np.einsum("kji,kjl->kil", self.R_w_l[:-1], self.R_w_l[1:])
        dt = np.diff(self.t_s)
        return self.t_s[:-1], self.t_s[1:], Rotation.from_matrix(dR).as_rotvec() / dt[:, None]


@dataclass
class LidarImuCalibration:
    """The LiDAR-IMU calibration and what the data said about it.

    R_i_l (3, 3), p_i_l (3,) m, time_offset_s: ``t_imu = t_lidar + time_offset_s``;
    sigma_rot_deg (3,): 1-sigma of the rotation about the IMU x, y, z axes (``R_i_l = Exp(d) R``);
    sigma_p_m (3,), sigma_time_offset_s; observable_rot / observable_p (3,) bool and observable_time:
    1-sigma within ``limits``; unobservable: the directions the motion did not excite, one line each
    (their values stay near the start's); gyro_bias (3,) rad/s, accel_bias (3,) m/s^2 (constant over
    the data); targets: the accuracy whose 1-sigma marks an observed parameter weak (``weak_rot``,
    ``weak_p``, ``weak_time``, ``weakly_observed``); g_w (3,) gravity in the first scan's LiDAR frame, m/s^2; rms_gyro rad/s and rms_accel
    m/s^2 of the fit's residuals; tau_gyro / tau_accel their correlation times in samples (the
    covariance's inflation); the coarse stage's offset and rotation; the starting extrinsic."""

    R_i_l: FloatArray
    p_i_l: FloatArray
    time_offset_s: float
    sigma_rot_deg: FloatArray
    sigma_p_m: FloatArray
    sigma_time_offset_s: float
    observable_rot: NDArray[np.bool_]
    observable_p: NDArray[np.bool_]
    observable_time: bool
    unobservable: list[str]
    gyro_bias: FloatArray
    accel_bias: FloatArray
    g_w: FloatArray
    rms_gyro: float
    rms_accel: float
    tau_gyro: float
    tau_accel: float
    coarse_time_offset_s: float
    coarse_R_i_l: FloatArray
    start: ExtrinsicConfig
    n_scans: int
    duration_s: float
    limits: ObservabilityLimits = field(default_factory=ObservabilityLimits)
    targets: AccuracyTargets = field(default_factory=AccuracyTargets)

    @property
    def weak_rot(self) -> NDArray[np.bool_]:
        """Rotation axes observed but with a 1-sigma above the target."""
        return self.observable_rot & (self.sigma_rot_deg > self.targets.rotation_deg)

    @property
    def weak_p(self) -> NDArray[np.bool_]:
        """Lever-arm axes observed but with a 1-sigma above the target."""
        return self.observable_p & (self.sigma_p_m > self.targets.translation_m)

    @property
    def weak_time(self) -> bool:
        """The clock offset observed but with a 1-sigma above the target."""
        return self.observable_time and self.sigma_time_offset_s > self.targets.time_offset_s

    @property
    def weakly_observed(self) -> list[str]:
        """One line per weakly observed parameter, with its 1-sigma and the target."""
        t = self.targets
        out = [f"rotation about IMU {AXES[k]}: 1-sigma {self.sigma_rot_deg[k]:.3g} deg > "
               f"{t.rotation_deg:g} deg" for k in np.flatnonzero(self.weak_rot)]  # fmt: skip
        out += [f"lever arm along IMU {AXES[k]}: 1-sigma {100 * self.sigma_p_m[k]:.3g} cm > "
                f"{100 * t.translation_m:g} cm" for k in np.flatnonzero(self.weak_p)]  # fmt: skip
        if self.weak_time:
            out.append(f"clock offset: 1-sigma {1e3 * self.sigma_time_offset_s:.3g} ms > "
                       f"{1e3 * t.time_offset_s:g} ms")  # fmt: skip
        return out

    @property
    def observable(self) -> bool:
        """Every parameter within its limit."""
        return bool(self.observable_rot.all() and self.observable_p.all() and self.observable_time)

    @property
    def confident(self) -> bool:
        """Every parameter observed and within its accuracy target at 1-sigma."""
        weak = self.weak_rot.any() or self.weak_p.any() or self.weak_time
        return bool(self.observable and not weak)

    def verdict(self, kind: str, k: int = 0) -> str:
        """'yes', 'weak' or 'NO' for ``kind`` 'rot' / 'p' (axis ``k``) or 'time'."""
        obs, weak = {"rot": (self.observable_rot, self.weak_rot), "p": (self.observable_p, self.weak_p),
                     "time": (np.array([self.observable_time]), np.array([self.weak_time]))}[kind]  # fmt: skip
        return "NO" if not obs[k] else "weak" if weak[k] else "yes"

    def yaml_header(self) -> str:
        """Comment lines for a written config: the parameters the data did not pin down."""
        lines = [f"# weakly observed (1-sigma above its target): {w}" for w in self.weakly_observed]
        lines += [f"# unobservable, held at the start: {u}" for u in self.unobservable]
        return "".join(f"{ln}\n" for ln in lines)

    @property
    def quat_wxyz_i_l(self) -> FloatArray:
        x, y, z, w = Rotation.from_matrix(self.R_i_l).as_quat()
        q = np.array([w, x, y, z])
        return q if w >= 0 else -q

    @property
    def rpy_deg_i_l(self) -> FloatArray:
        """R_i_l as roll, pitch, yaw (Z-Y-X: ``R = Rz(yaw) Ry(pitch) Rx(roll)``), deg."""
        return np.asarray(Rotation.from_matrix(self.R_i_l).as_euler("ZYX", degrees=True)[::-1])

    def extrinsic(self) -> ExtrinsicConfig:
        """The estimate as the LIO's ``extrinsic`` section."""
        return ExtrinsicConfig(
            p_i_l=tuple(float(v) for v in self.p_i_l),  # type: ignore[arg-type]
            quat_wxyz_i_l=tuple(float(v) for v in self.quat_wxyz_i_l),  # type: ignore[arg-type]
            time_offset_s=float(self.time_offset_s),
        )

    def to_dict(self) -> dict[str, Any]:
        """Values, 1-sigma and the verdict, JSON-ready (units in the keys)."""
        return {
            "p_i_l_m": self.p_i_l.tolist(),
            "sigma_p_i_l_m": self.sigma_p_m.tolist(),
            "quat_wxyz_i_l": self.quat_wxyz_i_l.tolist(),
            "rpy_deg_i_l": self.rpy_deg_i_l.tolist(),
            "sigma_rot_deg": self.sigma_rot_deg.tolist(),
            "time_offset_s": self.time_offset_s,
            "sigma_time_offset_s": self.sigma_time_offset_s,
            "observable": self.observable,
            "observable_p_i_l": dict(zip(AXES, self.observable_p.tolist(), strict=True)),
            "observable_rot": dict(zip(AXES, self.observable_rot.tolist(), strict=True)),
            "observable_time_offset": self.observable_time,
            "unobservable": list(self.unobservable),
            "confident": self.confident,
            "weak_p_i_l": dict(zip(AXES, self.weak_p.tolist(), strict=True)),
            "weak_rot": dict(zip(AXES, self.weak_rot.tolist(), strict=True)),
            "weak_time_offset": self.weak_time,
            "weakly_observed": list(self.weakly_observed),
            "targets": {
                "rotation_deg": self.targets.rotation_deg,
                "translation_m": self.targets.translation_m,
                "time_offset_s": self.targets.time_offset_s,
            },  # fmt: skip
            "limits": {
                "rotation_deg": self.limits.rotation_deg,
                "translation_m": self.limits.translation_m,
                "time_offset_s": self.limits.time_offset_s,
            },  # fmt: skip
            "gyro_bias_rad_s": self.gyro_bias.tolist(),
            "accel_bias_m_s2": self.accel_bias.tolist(),
            "gravity_lidar0_m_s2": self.g_w.tolist(),
            "residual_rms_gyro_rad_s": self.rms_gyro,
            "residual_rms_accel_m_s2": self.rms_accel,
            "residual_correlation_samples": {"gyro": self.tau_gyro, "accel": self.tau_accel},
            "coarse_time_offset_s": self.coarse_time_offset_s,
            "coarse_quat_wxyz_i_l": _quat_wxyz(self.coarse_R_i_l).tolist(),
            "start": self.start.model_dump(mode="json"),
            "n_scans": self.n_scans,
            "duration_s": self.duration_s,
        }


def _quat_wxyz(R: FloatArray) -> FloatArray:
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return np.array([w, x, y, z]) * (1.0 if w >= 0 else -1.0)


class GyroAttitude:
    """The IMU attitude integrated from the gyro (bias removed), ``R_i0_i(t)``, t in s after
    ``t_ref_ns`` (IMU clock), interpolated by slerp between samples."""

    def __init__(self, t_s: FloatArray, gyro_i: FloatArray, gyro_bias: FloatArray) -> None:
        w = gyro_i - gyro_bias
        dt = np.diff(t_s)
        inc = Rotation.from_rotvec(0.5 * (w[:-1] + w[1:]) * dt[:, None]).as_matrix()
        R = np.empty((len(t_s), 3, 3))
        R[0] = np.eye(3)
        for k in range(len(dt)):
            R[k + 1] = R[k] @ inc[k]
        self.t_s = t_s
        self.slerp = Slerp(t_s, Rotation.from_matrix(R))

    def __call__(self, t: FloatArray) -> FloatArray:
        """``R_i0_i`` (N, 3, 3) at times ``t`` (N,) s, clipped to the samples' span. Each distinct
        time is interpolated once (a LiDAR column's points share one) and the rotations indexed back:
        slerp is evaluated per time, so this equals interpolating at every entry of ``t``."""
        t_u, inv = np.unique(np.clip(t, self.t_s[0], self.t_s[-1]), return_inverse=True)
        return np.asarray(self.slerp(t_u).as_matrix())[inv.reshape(-1)]


def lidar_odometry(
    scans: Iterable[Scan3d],
    config: LioConfig,
    t_ref_ns: int,
    gyro: GyroAttitude | None = None,
    R_i_l: FloatArray | None = None,
    time_offset_s: float = 0.0,
) -> LidarTrack:
    """Register the scans with the LiDAR-only odometry; with ``gyro`` (and the rotation ``R_i_l`` and
    offset it is seen through), each scan's points are first rotated into the scan-end frame by the
    gyro, ``x_end = R_i_l^T R_i(t_e)^T R_i(t_j) R_i_l x_j`` (times in the IMU clock), and the scan-end
    rotation is predicted from it; translation stays constant-velocity (a third pass with the
    translation deskewed by the second's velocity spline did not help: 2.4 cm of lever-arm error
    instead of 1.3 on one seed)."""
    from imuslam.lio.pipeline import clean_scan

    odo = LidarOdometry(config.model_copy(update={"use_imu": False}))
    ts: list[float] = []
    Ts: list[FloatArray] = []
    for k, scan in enumerate(scans):
        pts, toff, ring, _ = clean_scan(scan, k)
        if len(pts) < 100:
            continue
        t_pt = (int(scan.t_ns) - t_ref_ns) * 1e-9 + toff
        t_end = float(t_pt.max())
        if ts and t_end <= ts[-1]:
            continue
        if gyro is None or R_i_l is None:
            T = odo.register_scan(pts, t_pt, ring)
        else:
            R_i0_ie = gyro(np.array([t_end + time_offset_s]))[0]
            R_ie_ij = np.einsum("ba,nbc->nac", R_i0_ie, gyro(t_pt + time_offset_s))
            R_le_lj = np.einsum("ba,nbc,cd->nad", R_i_l, R_ie_ij, R_i_l)
            pts = np.einsum("nij,nj->ni", R_le_lj, pts)
            motion = None
            if Ts:
                R_i0_ip = gyro(np.array([ts[-1] + time_offset_s]))[0]
                dR_l = R_i_l.T @ R_i0_ip.T @ R_i0_ie @ R_i_l
                T_pred = np.eye(4)
                T_pred[:3, :3] = Ts[-1][:3, :3] @ dR_l
                vel = np.zeros(3)
                if len(Ts) >= 2:
                    vel = (Ts[-1][:3, 3] - Ts[-2][:3, 3]) / (ts[-1] - ts[-2])
                T_pred[:3, 3] = Ts[-1][:3, 3] + vel * (t_end - ts[-1])
                motion = (T_pred, vel)
            T = odo.register_scan(pts, t_pt, ring, rotation_compensated=True, motion=motion)
        ts.append(t_end)
        Ts.append(T)
    if len(Ts) < 10:
        raise InputError(f"{len(Ts)} usable scans; the calibration needs at least 10")
    P = np.array(Ts)
    return LidarTrack(np.array(ts), P[:, :3, :3], P[:, :3, 3], t_ref_ns)


def odometry_config(config: LioConfig, scans: list[Scan3d]) -> LioConfig:
    """``config`` with its scan and map voxels scaled to the scene: a thirtieth of the median range of
    the first scans, within [0.1, 1] m, for the scan and 0.7 of it for the map (never coarser than
    ``config``'s). The defaults suit a street; in a 7 m room the lever arm's error fell from about
    1.5 cm to 2 mm as the voxels went from 0.3 / 0.2 m to 0.1 / 0.07 m (one simulated seed, the truth
    as the start; docs/lidar_calibration.md)."""
    r = [
        np.median(np.linalg.norm(s.points_l[:: max(1, len(s) // 2000)], axis=1))
        for s in scans[:5]
        if len(s)
    ]
    if not r:
        return config
    v = float(np.clip(np.median(r) / 30.0, 0.1, 1.0))
    fe = config.frontend.model_copy(update={"scan_voxel": min(v, config.frontend.scan_voxel)})
    mp = config.map.model_copy(update={"voxel": min(0.7 * v, config.map.voxel)})
    return config.model_copy(update={"frontend": fe, "map": mp})


def _interval_means(
    t_imu: FloatArray, gyro: FloatArray, a: FloatArray, b: FloatArray
) -> FloatArray:
    """Mean of the linearly interpolated gyro over each [a, b] (M,) -> (M, 3) (exact: the integral of
    the piecewise-linear signal, differenced)."""
    cum = np.concatenate(
        [
            np.zeros((1, 3)),
            np.cumsum(0.5 * (gyro[1:] + gyro[:-1]) * np.diff(t_imu)[:, None], axis=0),
        ]
    )
    Ga = np.stack([np.interp(a, t_imu, cum[:, j]) for j in range(3)], axis=1)
    Gb = np.stack([np.interp(b, t_imu, cum[:, j]) for j in range(3)], axis=1)
    return (Gb - Ga) / (b - a)[:, None]  # type: ignore[no-any-return]


def coarse_time_offset(
    track: LidarTrack, t_imu: FloatArray, gyro: FloatArray, centre_s: float, search_s: float
) -> tuple[float, float]:
    """The offset in ``centre_s +- search_s`` (1 ms steps, parabolic refinement) that maximises the
    correlation coefficient of the LiDAR and gyro rate norms (LI-Init Sec. IV-B), and that
    coefficient."""
    a, b, w_l = track.rates()
    n_l = np.linalg.norm(w_l, axis=1)
    cands = centre_s + np.arange(-search_s, search_s + 5e-4, 1e-3)
    corr = np.full(len(cands), -np.inf)
    for j, d in enumerate(cands):
        ok = (a + d >= t_imu[0]) & (b + d <= t_imu[-1])
        if ok.sum() < 10:
            continue
        n_i = np.linalg.norm(_interval_means(t_imu, gyro, a[ok] + d, b[ok] + d), axis=1)
        if np.std(n_i) > 0 and np.std(n_l[ok]) > 0:
            corr[j] = float(np.corrcoef(n_i, n_l[ok])[0, 1])
    j = int(np.argmax(corr))
    if not np.isfinite(corr[j]):
        raise InputError("the IMU and the LiDAR scans do not overlap in time")
    d = float(cands[j])
    if 0 < j < len(cands) - 1 and np.all(np.isfinite(corr[j - 1 : j + 2])):
        den = corr[j - 1] - 2 * corr[j] + corr[j + 1]
        if den < 0:
            d += 0.5 * (corr[j - 1] - corr[j + 1]) / den * 1e-3
    return d, float(corr[j])


def hand_eye_rotation(omega_i: FloatArray, omega_l: FloatArray) -> FloatArray:
    """``R_i_l`` minimising sum |omega_i - b - R omega_l|^2 over R and a constant b: the SVD of the
    centred cross-covariance (Arun, Huang and Blostein 1987; LI-Init Sec. IV-C's rotation)."""
    A = (omega_i - omega_i.mean(0)).T @ (omega_l - omega_l.mean(0))
    U, _, Vt = np.linalg.svd(A)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt  # type: ignore[no-any-return]


def refine_rotation_offset(
    track: LidarTrack, t_imu: FloatArray, gyro: FloatArray, R0: FloatArray, d0: FloatArray | float
) -> tuple[FloatArray, float, FloatArray]:
    """Least squares of the interval rates ``mean_gyro(t + d) = R omega_l + b_g`` over the rotation,
    the offset d and the gyro bias (LI-Init Sec. IV-C with the time lag). Returns R, d, b_g."""
    a, b, w_l = track.rates()
    d0f = float(d0)
    ok = (a + d0f - 0.05 >= t_imu[0]) & (b + d0f + 0.05 <= t_imu[-1])
    a, b, w_l = a[ok], b[ok], w_l[ok]

    def res(x: FloatArray) -> FloatArray:
        R = Rotation.from_rotvec(x[:3]).as_matrix() @ R0
        w_i = _interval_means(t_imu, gyro, a + x[3], b + x[3])
        return (w_i - x[4:7] - w_l @ R.T).ravel()  # type: ignore[no-any-return]

    w0 = _interval_means(t_imu, gyro, a + d0f, b + d0f)
    b0 = (w0 - w_l @ R0.T).mean(0)
    sol = least_squares(
        res,
        np.concatenate([np.zeros(3), [d0f], b0]),
        x_scale=[0.01, 0.01, 0.01, 0.005, 0.01, 0.01, 0.01],
    )
    return Rotation.from_rotvec(sol.x[:3]).as_matrix() @ R0, float(sol.x[3]), sol.x[4:7]


def _tau(r: FloatArray, max_lag: int = 400) -> float:
    """Integrated autocorrelation time of residual columns (N, C), samples (>= 1): 1 + 2 sum rho(k),
    summed while rho > 0 (Sokal's window), the largest over the columns."""
    out = 1.0
    for c in range(r.shape[1]):
        x = r[:, c] - r[:, c].mean()
        v = float(x @ x)
        if v <= 0:
            continue
        f = np.fft.rfft(x, 2 * len(x))
        ac = np.fft.irfft(f * np.conj(f))[: min(max_lag, len(x) - 1)] / v
        neg = np.flatnonzero(ac <= 0)
        m = int(neg[0]) if len(neg) else len(ac)
        out = max(out, float(1.0 + 2.0 * ac[1:m].sum()))
    return out


def lsq_spline(t: FloatArray, y: FloatArray, knot_s: float) -> BSpline:
    """The cubic B-spline with uniform knots ``knot_s`` apart fitted to samples ``y`` (N, C) at ``t``
    (N,) by least squares: a low-pass whose derivatives do not amplify the samples' jitter (a
    smoothing spline chosen by cross-validation follows the jitter of an odometry at 10 Hz)."""
    n_in = max(1, int(np.floor((t[-1] - t[0]) / knot_s)))
    inner = np.linspace(t[0], t[-1], n_in + 1)
    k = 3
    knots = np.concatenate([[t[0]] * k, inner, [t[-1]] * k])
    return make_lsq_spline(t, y, knots, k=k)


class _SplineTrack:
    """Least-squares B-splines of the LiDAR trajectory: position (world) and rate (LiDAR frame), and
    the attitude's cubic rotation spline (slerp between scans would be wrong by the angular
    acceleration times dt^2 / 8, milliradians at 10 Hz, which tilt gravity by centimetres per second
    squared in step with the lever-arm terms); derivatives give the acceleration ``a_w_l`` and the angular acceleration."""

    def __init__(self, track: LidarTrack, knot_s: float = 0.4) -> None:
        t = track.t_s
        self.p = lsq_spline(t, track.p_w_l, knot_s)
        self.a = self.p.derivative(2)
        a, b, w_l = track.rates()
        tm = 0.5 * (a + b)
        self.w = lsq_spline(tm, w_l, knot_s)
        self.dw = self.w.derivative(1)
        self.rot = RotationSpline(t, Rotation.from_matrix(track.R_w_l))
        self.lo, self.hi = float(tm[0]), float(tm[-1])

    def __call__(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """R_w_l (N, 3, 3), a_w_l (N, 3), omega_l (N, 3), alpha_l (N, 3) at LiDAR times t (N,)."""
        R = self.rot(t).as_matrix()
        return R, self.a(t), self.w(t), self.dw(t)


def _gravity_basis(g0: FloatArray) -> FloatArray:
    u = g0 / np.linalg.norm(g0)
    e = np.eye(3)[int(np.argmin(np.abs(u)))]
    b1 = np.cross(u, e)
    b1 /= np.linalg.norm(b1)
    return np.stack([b1, np.cross(u, b1)], axis=1)


# priors that keep an unexcited direction at its start: rotation rad, lever arm m, offset s, gyro bias
# rad/s, accel bias m/s^2, gravity direction (unit-free); wide enough to be nothing where the data speak
_PRIOR = np.array([0.2] * 3 + [0.5] * 3 + [0.1] + [0.1] * 3 + [1.0] * 3 + [1.0] * 2)
_NAMES = ("rotation", "lever arm")
# below this rate (RMS about every axis) the LiDAR odometry's noise (0.01 rad/s a scan) hides the motion
MIN_RATE_RMS = 0.03


def calibrate_lidar_imu(
    scans: list[Scan3d],
    imu: ImuLog,
    config: LioConfig | None = None,
    limits: ObservabilityLimits | None = None,
    search_s: float = 0.2,
    imu_rate_hz: float = 100.0,
    targets: AccuracyTargets | None = None,
) -> LidarImuCalibration:
    """Calibrate ``T_i_l`` and the clock offset from ``scans`` and ``imu`` (the whole overlap).

    config: the start (``config.extrinsic``: its offset centres the search of +- ``search_s``; its
    rotation and lever arm are the prior's means) and the odometry's front end and map;
    imu_rate_hz: the IMU samples the joint fit uses (decimated to about this rate); limits / targets:
    the 1-sigma above which a parameter is reported unobservable / weakly observed.
    """
    cfg = config or LioConfig()
    lim = limits or ObservabilityLimits()
    start = cfg.extrinsic
    imu = imu.to_si()
    if len(imu) < 100:
        raise InputError(
            f"{imu.source}: {len(imu)} IMU samples; the calibration needs at least 100"
        )
    t_ref = int(imu.t_ns[0])
    t_imu = (imu.t_ns - t_ref).astype(float) * 1e-9
    g_mag = cfg.filter.g

    scans = list(scans)
    cfg = odometry_config(cfg, scans)
    # 1-3: LiDAR-only odometry, offset by cross-correlation, hand-eye rotation, gyro least squares
    track = lidar_odometry(scans, cfg, t_ref)
    _, _, w_l = track.rates()
    rms = np.sqrt(np.mean(w_l**2, axis=0))
    if rms.max() < MIN_RATE_RMS:
        raise InputError(
            f"the LiDAR turned at {', '.join(f'{v:.3f}' for v in rms)} rad/s RMS about its x, y, z "
            f"axes (below {MIN_RATE_RMS} rad/s about every axis): the rotation, the lever arm and the "
            "clock offset are all unobservable; record a motion that turns about all three axes"
        )
    d0, rho = coarse_time_offset(track, t_imu, imu.gyro, start.time_offset_s, search_s)
    a, b, w_l = track.rates()
    ok = (a + d0 >= t_imu[0]) & (b + d0 <= t_imu[-1])
    w_i = _interval_means(t_imu, imu.gyro, a[ok] + d0, b[ok] + d0)
    R0 = hand_eye_rotation(w_i, w_l[ok])
    R1, d1, bg1 = refine_rotation_offset(track, t_imu, imu.gyro, R0, d0)
    log.info("coarse: offset %.4f s (correlation %.3f), refined %.4f s", d0, rho, d1)
    coarse_R, coarse_d = R1.copy(), d1

    # 4: the scans again, their rotation deskewed by the gyro
    att = GyroAttitude(t_imu, imu.gyro, bg1)
    track = lidar_odometry(scans, cfg, t_ref, att, R1, d1)
    R1, d1, bg1 = refine_rotation_offset(track, t_imu, imu.gyro, R1, d1)
    return refine_extrinsic(track, imu, R1, d1, bg1, start, lim, search_s, imu_rate_hz, g_mag,
                            coarse_R, coarse_d, targets=targets)  # fmt: skip


def refine_extrinsic(
    track: LidarTrack,
    imu: ImuLog,
    R1: FloatArray,
    d1: float,
    bg1: FloatArray,
    start: ExtrinsicConfig,
    lim: ObservabilityLimits,
    search_s: float = 0.2,
    imu_rate_hz: float = 100.0,
    g_mag: float = 9.80665,
    coarse_R: FloatArray | None = None,
    coarse_d: float | None = None,
    knot_s: float = 0.4,
    targets: AccuracyTargets | None = None,
) -> LidarImuCalibration:
    """Step 5: the joint least squares from the coarse rotation ``R1``, offset ``d1`` and gyro bias
    ``bg1`` over the LiDAR ``track`` (times after ``track.t_ref_ns``) and the IMU (SI units)."""
    t_imu = (imu.t_ns - track.t_ref_ns).astype(float) * 1e-9
    sp = _SplineTrack(track, knot_s)
    step = max(1, int(round(imu.rate_hz / imu_rate_hz)))
    sel = np.arange(0, len(imu), step)
    margin = 0.3 + search_s
    sel = sel[(t_imu[sel] - d1 > sp.lo + margin) & (t_imu[sel] - d1 < sp.hi - margin)]
    if len(sel) < 50:
        raise InputError("the IMU and the LiDAR overlap for too short a time for the calibration")
    tq, f_m = t_imu[sel], imu.accel[sel]
    ia, ib, w_l = track.rates()
    keep = (ia + d1 - 0.05 >= t_imu[0]) & (ib + d1 + 0.05 <= t_imu[-1])
    ia, ib, w_l = ia[keep], ib[keep], w_l[keep]

    # gravity in the LiDAR world from the mean of R_w_l R_l_i f - a_w_l (the specific force, level)
    R_wl, acc, _, _ = sp(tq - d1)
    g0 = np.mean(acc - np.einsum("nij,jk,nk->ni", R_wl, R1.T, f_m), axis=0)
    g0 = g0 / np.linalg.norm(g0) * g_mag
    B = _gravity_basis(g0)
    R_s = np.asarray(start.T_i_l()[:3, :3])
    p_s = np.asarray(start.p_i_l, float)

    def unpack(
        x: FloatArray,
    ) -> tuple[FloatArray, FloatArray, float, FloatArray, FloatArray, FloatArray]:
        R = Rotation.from_rotvec(x[:3]).as_matrix() @ R1
        g = g0 + B @ x[13:15]
        return R, x[3:6], float(x[6]), x[7:10], x[10:13], g / np.linalg.norm(g) * g_mag

    def model(x: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Gyro interval means minus their prediction (M, 3), and the predicted specific force (N, 3)."""
        R, p, d, bg, ba, g = unpack(x)
        Rw, acc, w, dw = sp(tq - d)
        p_l_i = -R.T @ p
        e_w = _interval_means(t_imu, imu.gyro, ia + d, ib + d) - bg - w_l @ R.T
        spec = np.einsum("nji,nj->ni", Rw, acc - g)
        spec += np.cross(dw, p_l_i) + np.cross(w, np.cross(w, p_l_i))
        return e_w, spec @ R.T + ba

    def prior(x: FloatArray) -> FloatArray:
        R, p, d, *_ = unpack(x)
        r_rot = Rotation.from_matrix(R @ R_s.T).as_rotvec()
        return np.concatenate([r_rot, p - p_s, [d - start.time_offset_s], x[7:15]]) / _PRIOR

    sig = np.array([1e-2, 0.1])  # gyro rad/s, accel m/s^2: first guesses, then from the residuals
    tau = np.ones(2)

    def residuals(x: FloatArray) -> FloatArray:
        eg, fp = model(x)
        rg = eg / (sig[0] * np.sqrt(tau[0]))
        ra = (f_m - fp) / (sig[1] * np.sqrt(tau[1]))
        return np.concatenate([rg.ravel(), ra.ravel(), prior(x)])

    x = np.zeros(15)
    x[3:6] = p_s
    x[6] = d1
    x[7:10] = bg1
    scale = np.array([1e-3] * 3 + [1e-2] * 3 + [1e-3] + [1e-3] * 3 + [1e-2] * 3 + [1e-3] * 2)
    for _ in range(3):
        sol = least_squares(residuals, x, x_scale=scale, method="trf")
        x = sol.x
        eg, fp = model(x)
        ea = f_m - fp
        sig = np.array([np.sqrt(np.mean(eg**2)), np.sqrt(np.mean(ea**2))])
        tau = np.array([_tau(eg), _tau(ea)])
    sol = least_squares(residuals, x, x_scale=scale, method="trf")
    x = sol.x
    J = sol.jac
    n_data = 3 * len(ia) + 3 * len(tq)
    H_data = J[:n_data].T @ J[:n_data]
    H = J.T @ J
    cov = np.linalg.inv(H)
    sd = np.sqrt(np.diag(cov))

    # observability: the rotation and lever-arm blocks' information with the rest marginalised
    unobs: list[str] = []
    fixed: list[FloatArray] = [np.zeros((3, 0)), np.zeros((3, 0))]
    lims = (np.deg2rad(lim.rotation_deg), lim.translation_m)
    for blk, (name, limit) in enumerate(zip(_NAMES, lims, strict=True)):
        idx = np.arange(3 * blk, 3 * blk + 3)
        rest = np.setdiff1d(np.arange(15), idx)
        Hr = H_data[np.ix_(rest, rest)] + np.diag(1.0 / _PRIOR[rest] ** 2)
        S = H_data[np.ix_(idx, idx)] - H_data[np.ix_(idx, rest)] @ np.linalg.solve(
            Hr, H_data[np.ix_(rest, idx)]
        )
        lam, V = np.linalg.eigh(0.5 * (S + S.T))
        for k in range(3):
            s = 1.0 / np.sqrt(max(lam[k], 1e-300))
            if s > limit:
                v = V[:, k] * np.sign(V[np.argmax(np.abs(V[:, k])), k])
                fixed[blk] = np.column_stack([fixed[blk], v])
                sd_txt = f"{np.rad2deg(s):.3g} deg" if blk == 0 else f"{s:.3g} m"
                unobs.append(f"{name} along IMU [{v[0]:+.2f}, {v[1]:+.2f}, {v[2]:+.2f}]: 1-sigma {sd_txt} "
                             "from the data alone (kept at the start)")  # fmt: skip
    fix_offset = bool(sd[6] > lim.time_offset_s)
    if fix_offset:
        unobs.append(f"clock offset: 1-sigma {sd[6] * 1e3:.3g} ms (kept at the start)")
    if fixed[0].shape[1] or fixed[1].shape[1] or fix_offset:
        # the directions the data do not see stay where they started: the weak prior alone would let
        # the residuals' systematic errors move them by as much as their large sigma
        Vr, Vp = fixed

        def constraint(x: FloatArray) -> FloatArray:
            R, p, d, *_ = unpack(x)
            c = [Vr.T @ Rotation.from_matrix(R @ R_s.T).as_rotvec() / 1e-6, Vp.T @ (p - p_s) / 1e-6]
            if fix_offset:
                c.append(np.array([(d - start.time_offset_s) / 1e-6]))
            return np.concatenate(c)

        n_res = len(residuals(x))
        x[3:6] -= Vp @ (Vp.T @ (x[3:6] - p_s))
        if fix_offset:
            x[6] = start.time_offset_s
        sol = least_squares(lambda x: np.concatenate([residuals(x), constraint(x)]), x,
                            x_scale=scale, method="trf")  # fmt: skip
        x = sol.x
        J = sol.jac[:n_res]  # the sigma: the data's and the weak prior's information only
        sd = np.sqrt(np.diag(np.linalg.inv(J.T @ J)))

    R, p, d, bg, ba, g = unpack(x)
    eg, fp = model(x)
    return LidarImuCalibration(
        R_i_l=R, p_i_l=np.asarray(p, float).copy(), time_offset_s=d,
        sigma_rot_deg=np.rad2deg(sd[:3]), sigma_p_m=sd[3:6], sigma_time_offset_s=float(sd[6]),
        observable_rot=np.rad2deg(sd[:3]) <= lim.rotation_deg, observable_p=sd[3:6] <= lim.translation_m,
        observable_time=bool(sd[6] <= lim.time_offset_s), unobservable=unobs,
        gyro_bias=bg.copy(), accel_bias=ba.copy(), g_w=g,
        rms_gyro=float(np.sqrt(np.mean(eg**2))), rms_accel=float(np.sqrt(np.mean((f_m - fp) ** 2))),
        tau_gyro=float(tau[0]), tau_accel=float(tau[1]), coarse_time_offset_s=d1 if coarse_d is None else coarse_d,
        coarse_R_i_l=R1 if coarse_R is None else coarse_R,
        start=start, n_scans=len(track.t_s), duration_s=float(track.t_s[-1] - track.t_s[0]), limits=lim,
        targets=targets or AccuracyTargets(),
    )  # fmt: skip
