"""The LiDAR-IMU extrinsic and clock offset refined inside the LIO's iterated ESKF (FAST-LIO2, Xu et al.,
T-RO 2022, Sec. IV: the extrinsic as states of the filter; LI-Init, Zhu et al., IROS 2022, Sec. V: with
the offset), with an observability guard. ``filter.estimate_extrinsic`` / ``estimate_time_offset``.

Extra error states after the inertial ones (``ErrorLayout.extra``, ``base_dim`` on): the rotation
``psi`` about the IMU axes (left: ``R_i_l_true = Exp(psi) R_i_l``), the lever arm ``dp`` (IMU frame,
m) and the offset error ``dt`` (s, ``t_imu = t_lidar + time_offset_s``). The propagation carries them
with an identity transition; a random walk is added per block. A scan point ``p_l`` with
``q = R_i_l p_l`` and ``p_i = q + p_i_l`` has the residual ``r = n . (R p_i + p - c)`` (FAST-LIO2 eq.
12) at the pose of the true time ``t + dt``, ``R Exp(omega dt)``, ``p + v dt``, so with ``a = R^T n``::

    dr/dpsi = (q x a)^T,   dr/ddp = a^T,   dr/ddt = n . v + a . (omega x p_i)

The guard (the offline calibration's verdict, ``lio.config.ObservabilityLimits``): beside the
filter's covariance the covariance of the same filter without the guard is kept (propagated and
updated alike, along the guarded estimate); its information on the extra states less the prior's is
eigen-decomposed. An eigenvector whose 1-sigma from the scans alone exceeds the limits is reported
unobserved (the lever arm along the yaw axis of a car on flat ground); one whose 1-sigma from the
scans is still above the prior's (the scans know less of it than the prior) is frozen for the
update: the Jacobian's extra columns are projected off it and its correlations with every other
state removed (variance kept), so it stays at its prior with its prior variance and the pose is
estimated for the extrinsic held there (the map is built with it). (Freezing at the limits instead
held the street car's lever arm along x and y, seen at 1.2-1.4x the 3 cm limit, at the prior's
error, and the rotation and offset took it up: 1 deg and 17 ms left against 0.2 deg and 0.3 ms
unguarded.) The start's attitude and position come from the
LiDAR through the prior extrinsic and offset; their errors are a linear function of the extra states'
(``start_jacobian``) and enter the initial covariance with that correlation. ``ins.core``'s
``boxplus`` leaves extra states to their owner, so ``CalibratingEskf`` fills ``Eskf.iterated_update``'s
hooks for ``LioState`` (one iterated update for every filter).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import NDArray

from imuslam.geometry.so3 import exp, hat, log
from imuslam.ins.core import ErrorLayout, Eskf, InsState, boxminus, boxplus
from imuslam.lio.config import ObservabilityLimits
from imuslam.lio.guards import GuardedEskf

if TYPE_CHECKING:
    from imuslam.ins.noise import KfNoise
    from imuslam.lio.config import LioConfig
    from imuslam.lio.matcher import Correspondences

FloatArray = NDArray[np.float64]
AXES = ("x", "y", "z")


class Rows(Protocol):
    """A point-to-plane measurement's rows of its last linearisation (``estimator.LidarMeasurement``)."""

    _corr: Correspondences | None


@dataclass
class LioState(InsState):
    """The inertial state with the LiDAR's rotation ``R_i_l`` (3, 3) and lever arm ``p_i_l`` (3,) m on
    the IMU and the clock offset ``time_offset_s`` (the nominal values of the extra states)."""

    R_i_l: FloatArray = field(default_factory=lambda: np.eye(3))
    p_i_l: FloatArray = field(default_factory=lambda: np.zeros(3))
    time_offset_s: float = 0.0

    def copy(self) -> LioState:
        return LioState(self.p_n.copy(), self.v_n.copy(), self.R_n_b.copy(), self.accel_bias.copy(),
                        self.gyro_bias.copy(), self.g_n.copy(), self.R_i_l.copy(), self.p_i_l.copy(),
                        self.time_offset_s)  # fmt: skip


class OnlineCalibration:
    """Which extra states there are (``ROT``, ``P``, ``DT`` index arrays into the error state, empty when
    absent), their prior, random walk, the guard's information and the report."""

    def __init__(self, config: LioConfig, base: ErrorLayout) -> None:
        fc = config.filter
        self.config = config
        n_ext = 6 if fc.estimate_extrinsic else 0
        n = n_ext + (1 if fc.estimate_time_offset else 0)
        self.layout = ErrorLayout(base.accel_bias, base.gyro_bias, base.gravity, extra=n)
        b = base.base_dim
        self.E = np.arange(b, b + n)  # the extra states
        self.ROT = np.arange(b, b + 3) if n_ext else np.zeros(0, np.int64)
        self.P = np.arange(b + 3, b + 6) if n_ext else np.zeros(0, np.int64)
        self.DT = np.arange(b + n_ext, b + n) if fc.estimate_time_offset else np.zeros(0, np.int64)
        self.limits = ObservabilityLimits()
        lim = np.r_[np.full(3, np.deg2rad(self.limits.rotation_deg)),
                    np.full(3, self.limits.translation_m)][:n_ext]  # fmt: skip
        self.scale = np.r_[lim, [self.limits.time_offset_s] * len(self.DT)]  # 1-sigma limits
        std = np.r_[
            np.full(3, np.deg2rad(fc.extrinsic_rot_std_deg)), np.full(3, fc.extrinsic_p_std)
        ]
        self.prior_std = np.r_[std[:n_ext], [fc.time_offset_std] * len(self.DT)]
        rw = np.r_[np.full(3, np.deg2rad(fc.extrinsic_rot_rw_deg)), np.full(3, fc.extrinsic_p_rw)]
        self.rw = np.r_[rw[:n_ext], [fc.time_offset_rw] * len(self.DT)]  # per sqrt(s)
        self.guard = fc.extrinsic_guard
        self.var0 = self.prior_std**2  # the prior's variance with the random walk since the start
        # the covariance of the filter without the guard along the same states: what the scans have
        # said about the extra states (the guard's own covariance holds the frozen ones at the prior)
        self.P_free = np.zeros((self.layout.dim, self.layout.dim))
        self.n_updates = 0
        self.omega_i = np.zeros(3)  # the IMU rate at the scan end, rad/s (for dr/ddt)
        ext = config.extrinsic
        self.T0 = ext.T_i_l()
        self.time_offset0 = ext.time_offset_s

    # ---- the state ------------------------------------------------------------------------------
    def boxplus(self, x: InsState, dx: FloatArray) -> LioState:
        y = boxplus(x, dx, self.layout)
        assert isinstance(y, LioState)
        if len(self.ROT):
            y.R_i_l = exp(dx[self.ROT]) @ y.R_i_l
            y.p_i_l = y.p_i_l + dx[self.P]
        if len(self.DT):
            y.time_offset_s = y.time_offset_s + float(dx[self.DT][0])
        return y

    def boxminus(self, x1: InsState, x0: InsState) -> FloatArray:
        dx = boxminus(x1, x0, self.layout)
        assert isinstance(x1, LioState) and isinstance(x0, LioState)
        if len(self.ROT):
            dx[self.ROT] = log(x1.R_i_l @ x0.R_i_l.T)
            dx[self.P] = x1.p_i_l - x0.p_i_l
        if len(self.DT):
            dx[self.DT] = x1.time_offset_s - x0.time_offset_s
        return dx

    def start(self, x: InsState, P0: FloatArray) -> tuple[LioState, FloatArray]:
        """The filter's first state with the prior extrinsic and offset, and its covariance: the base
        ``P0`` (base_dim, base_dim) plus the start's errors caused by the extra states' (``start_jacobian``)."""
        T = self.T0
        y = LioState(x.p_n, x.v_n, x.R_n_b, x.accel_bias, x.gyro_bias, x.g_n, T[:3, :3].copy(),
                     T[:3, 3].copy(), self.time_offset0)  # fmt: skip
        m, b = self.layout.dim, self.layout.base_dim
        Pa = np.zeros((m, m))
        Pa[:b, :b] = P0
        Pa[self.E, self.E] = self.prior_std**2
        A = np.eye(m)
        A[:b, b:] = self.start_jacobian(y)
        return y, A @ Pa @ A.T

    def filter(self, x: InsState, P0: FloatArray, omega_i: FloatArray, noise: KfNoise
               ) -> CalibratingEskf:  # fmt: skip
        """The filter from the start's state and covariance (the extra states' block zero) and the IMU
        rate at the start, rad/s."""
        self.omega_i = np.asarray(omega_i, float)
        b = self.layout.base_dim
        y, P = self.start(x, P0[:b, :b])
        self.P_free = P.copy()
        return CalibratingEskf(y, P, self, noise=noise)

    def scan_clock(self, x: InsState, t_s: FloatArray) -> tuple[FloatArray, FloatArray]:
        """A scan's point times (N,) s moved by the offset estimated so far (the pipeline applied the
        config's), and the LiDAR pose on the IMU ``T_i_l`` (4, 4) of the state ``x``."""
        assert isinstance(x, LioState)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = x.R_i_l, x.p_i_l
        return t_s + (x.time_offset_s - self.time_offset0), T

    def insertion(self, x: InsState, x0: InsState, surf_l: FloatArray, edge_l: FloatArray
                  ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:  # fmt: skip
        """The scan's points (LiDAR frame, deskewed to its end) in the IMU frame with the updated
        extrinsic, and the IMU pose (R, p) at the scan end's updated time (the state ``x`` stands
        for the time of the prior ``x0``'s offset)."""
        assert isinstance(x, LioState) and isinstance(x0, LioState)
        dt = x.time_offset_s - x0.time_offset_s
        R, p = x.R_n_b @ exp(self.omega_i * dt), x.p_n + x.v_n * dt
        return surf_l @ x.R_i_l.T + x.p_i_l, edge_l @ x.R_i_l.T + x.p_i_l, R, p

    def start_jacobian(self, x: LioState) -> FloatArray:
        """d(start error)/d(extra error) (base_dim, n): the start's IMU pose is the LiDAR's through the
        prior extrinsic, ``T_w_i = T_w_l T_i_l^-1``, so the true one is off by ``dtheta = -psi``,
        ``dp_w = -R_w_i (dp + [p_i_l]x psi)``; the state held at the scan end stands for the true time
        ``t + dt``: ``dp_w = -v dt``, ``dtheta = -omega dt``. (The world's levelling has the start's
        attitude error too, so gravity in w is off by ``[g]x R_w_i0 psi`` plus the levelling's own
        error; tying gravity to psi made the filter take a levelling error for the extrinsic on the
        waved rig, so gravity keeps its own prior.)"""
        lay = self.layout
        J = np.zeros((lay.base_dim, lay.extra))
        e = self.E[0]
        R = x.R_n_b
        if len(self.ROT):
            r, p = self.ROT - e, self.P - e
            J[lay.TH, r] = -np.eye(3)
            J[lay.P, r] = -R @ hat(x.p_i_l)
            J[lay.P, p] = -R
        if len(self.DT):
            d = int(self.DT[0] - e)
            J[lay.P, d] = -x.v_n
            J[lay.TH, d] = -self.omega_i
        return J

    def predicted(self, eskf: Eskf, Rs: FloatArray, gyro: FloatArray, t_s: FloatArray,
                  f_w: FloatArray) -> None:  # fmt: skip
        """After the filter's prediction over the IMU samples at ``t_s`` (K,) (attitudes ``Rs`` (K, 3, 3),
        rates ``gyro`` (K, 3) rad/s, specific force in w ``f_w`` (K, 3)): the extra states' random walk
        added to the filter's covariance and to the unguarded one's (propagated alike)."""
        from imuslam.ins.core import propagate_covariance

        dt = max(float(t_s[-1] - t_s[0]), 0.0)
        q = self.rw**2 * dt
        self.omega_i = gyro[-1] - eskf.x.gyro_bias
        eskf.P = eskf.P.copy()
        eskf.P[self.E, self.E] += q
        self.var0 = self.var0 + q
        self.P_free, _ = propagate_covariance(self.P_free, Rs, gyro, eskf.x.gyro_bias, np.diff(t_s),
                                              f_w[:-1].mean(axis=0), eskf.noise.q,
                                              self.layout.offsets)  # fmt: skip
        self.P_free[self.E, self.E] += q

    # ---- the measurement ------------------------------------------------------------------------
    def wrap(self, lin: Callable[[InsState], tuple[FloatArray, FloatArray, FloatArray]],
             x0: InsState, meas: Rows
             ) -> Callable[[InsState], tuple[FloatArray, FloatArray, FloatArray]]:  # fmt: skip
        """The point-to-plane linearisation ``lin`` (rows built with the extrinsic of ``x0``) with the
        extra states' columns, and its innovation moved to first order to the iterate's extrinsic and
        offset (a scan's update moves them by far less than their effect's curvature)."""

        def f(x: InsState) -> tuple[FloatArray, FloatArray, FloatArray]:
            r, H, R = lin(x)
            corr = meas._corr
            if corr is None or not len(r):
                return r, H, R
            assert isinstance(x, LioState) and isinstance(x0, LioState)
            H = H.copy()
            a = corr.n @ x.R_n_b  # R^T n per row
            e = self.E[0]
            He = np.zeros((len(r), self.layout.extra))
            if len(self.ROT):
                q = corr.p_i - x0.p_i_l
                He[:, self.ROT - e] = np.cross(q, a)
                He[:, self.P - e] = a
            if len(self.DT):
                He[:, self.DT[0] - e] = corr.n @ x.v_n + np.einsum(
                    "mk,mk->m", a, np.cross(self.omega_i, corr.p_i)
                )
            H[:, self.E] = He
            d = self.boxminus(x, x0)[self.E]
            return r - He @ d, H, R

        return f

    # ---- the guard ------------------------------------------------------------------------------
    def information(self, P: FloatArray) -> FloatArray:
        """The scans' information on the extra states (n, n): the filter's marginal information
        ``P_ee^-1`` less the prior's (with its random walk)."""
        info = np.linalg.inv(P[np.ix_(self.E, self.E)]) - np.diag(1.0 / self.var0)
        return np.asarray(0.5 * (info + info.T))

    def _excited(self, P: FloatArray, S: FloatArray | None = None
                 ) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:  # fmt: skip
        """Eigenvalues and vectors of the information in units of ``S`` (n,) (the limits by default);
        True where the 1-sigma from the scans alone is within them."""
        S = self.scale if S is None else S
        lam, V = np.linalg.eigh(self.information(P) * S[:, None] * S[None, :])
        return lam, V, lam >= 1.0

    def frozen(self) -> tuple[FloatArray, NDArray[np.bool_]] | None:
        """The guard's change of the extra states' coordinates ``y = U^T S^-1 e`` (S the prior's
        1-sigma, U the information's eigenvectors) (n, n) and the mask of the y whose 1-sigma from the
        scans alone is still above the prior's (the scans know less of them than the prior); None
        when there is none or the guard is off."""
        if not self.guard:
            return None
        _, V, ok = self._excited(self.P_free, self.prior_std)
        if ok.all():
            return None
        return V.T / self.prior_std[None, :], ~ok

    def freeze(self, P: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The projector (dim, dim) that keeps the excited directions of the extra states (identity
        on the others) and ``P`` with the unexcited directions' correlations to every other state
        removed (their variance kept): with the Jacobian's extra columns projected, the update then
        neither moves them nor learns from them."""
        m = self.layout.dim
        fz = self.frozen()
        if fz is None:
            return np.eye(m), P
        Ty, bad = fz
        T = np.eye(m)
        T[np.ix_(self.E, self.E)] = Ty
        Ti = np.linalg.inv(T)
        Py = T @ P @ T.T
        u = self.E[bad]
        keep = np.diag(Py)[u].copy()
        Py[u, :] = 0.0
        Py[:, u] = 0.0
        Py[u, u] = keep
        Pi = np.eye(m)
        Pi[u, u] = 0.0
        return Ti @ Pi @ T, Ti @ Py @ Ti.T

    def report(self, x: LioState, P: FloatArray) -> dict[str, Any]:
        """The final extrinsic and offset with 1-sigma, and what the motion excited (JSON-ready)."""
        out: dict[str, Any] = {"guard": self.guard, "updates": self.n_updates,
                               "limits": {"rotation_deg": self.limits.rotation_deg,
                                          "translation_m": self.limits.translation_m,
                                          "time_offset_s": self.limits.time_offset_s}}  # fmt: skip
        sd = np.sqrt(np.diag(P)[self.E])
        e = self.E[0]
        S = self.scale
        info = self.information(self.P_free)
        try:
            data_sd = np.sqrt(np.maximum(np.diag(np.linalg.inv(info + np.diag(1e-9 / S**2))), 0))
        except np.linalg.LinAlgError:
            data_sd = np.full(len(S), np.inf)
        excited = data_sd <= S
        if len(self.ROT):
            r, p = self.ROT - e, self.P - e
            w, xq, yq, zq = _quat_wxyz(x.R_i_l)
            out.update({
                "quat_wxyz_i_l": [w, xq, yq, zq],
                "rpy_deg_i_l": _rpy_deg(x.R_i_l).tolist(),
                "sigma_rot_deg": np.rad2deg(sd[r]).tolist(),
                "p_i_l_m": x.p_i_l.tolist(),
                "sigma_p_i_l_m": sd[p].tolist(),
                "data_sigma_rot_deg": np.rad2deg(data_sd[r]).tolist(),
                "data_sigma_p_i_l_m": data_sd[p].tolist(),
                "observed_rot": dict(zip(AXES, excited[r].tolist(), strict=True)),
                "observed_p_i_l": dict(zip(AXES, excited[p].tolist(), strict=True)),
            })  # fmt: skip
        if len(self.DT):
            d = int(self.DT[0] - e)
            out.update({"time_offset_s": x.time_offset_s, "sigma_time_offset_s": float(sd[d]),
                        "data_sigma_time_offset_s": float(data_sd[d]),
                        "observed_time_offset": bool(excited[d])})  # fmt: skip
        out["unobserved"] = self.unobserved()
        return out

    def _held(self, v: FloatArray) -> str:
        """What the guard did along the direction ``v`` (in units of the limits)."""
        if not self.guard:
            return "not guarded"
        fz = self.frozen()
        if fz is None:
            return "estimated (the scans know it better than the prior)"
        Ty, bad = fz
        y = Ty @ (self.scale * v)  # the direction in the frozen coordinates
        return "kept at its prior" if np.abs(y[bad]).sum() > np.abs(y[~bad]).sum() else "estimated"

    def unobserved(self) -> list[str]:
        """One line per direction the motion did not excite (1-sigma from the scans above the limit)."""
        lam, V, ok = self._excited(self.P_free)
        lines = []
        names = ["rotation about IMU"] * 3 + ["lever arm along IMU"] * 3 if len(self.ROT) else []
        names += ["clock offset"] * len(self.DT)
        for j in np.flatnonzero(~ok):
            v = V[:, j]
            k = int(np.argmax(np.abs(v)))
            blk = (
                slice(3 * (k // 3), 3 * (k // 3) + 3)
                if names[k] != "clock offset"
                else slice(k, k + 1)
            )
            u = v[blk] / np.linalg.norm(v[blk])
            u = u * np.sign(u[np.argmax(np.abs(u))])
            vec = (
                "" if names[k] == "clock offset" else " [" + " ".join(f"{c:+.2f}" for c in u) + "]"
            )
            sig = 1.0 / np.sqrt(max(lam[j], 1e-300))
            held = self._held(v)
            lines.append(f"{names[k]}{vec}: 1-sigma from the scans {sig:.2g} x the limit, {held}")
        return lines


def _quat_wxyz(R: FloatArray) -> list[float]:
    from scipy.spatial.transform import Rotation

    xq, yq, zq, w = Rotation.from_matrix(R).as_quat()
    s = 1.0 if w >= 0 else -1.0
    return [float(s * w), float(s * xq), float(s * yq), float(s * zq)]


def _rpy_deg(R: FloatArray) -> FloatArray:
    from scipy.spatial.transform import Rotation

    return np.asarray(Rotation.from_matrix(R).as_euler("ZYX", degrees=True)[::-1])


class CalibratingEskf(GuardedEskf):
    """``Eskf`` whose iterated update carries the extra states' nominal values (``LioState``) and holds
    the guard's unexcited directions as consider states. ``ins.core``'s ``boxplus`` leaves the extra
    states to their owner, so the iterate's extra part would be dropped there. The degeneracy guard's
    ``projector`` (the pose's columns) is applied with the extra states' (their columns: the two
    commute)."""

    def __init__(self, x: LioState, P: FloatArray, calib: OnlineCalibration, **kw: Any) -> None:
        super().__init__(x, P, layout=calib.layout, **kw)
        self.calib = calib

    # Eskf.iterated_update's hooks (FAST-LIO2 eqs. 18-20 on the augmented state): the extra states'
    # nominal values carried through the iterates, and the step's columns along the unexcited
    # directions zeroed by ``OnlineCalibration.freeze`` (Schmidt's consider states)
    def _plus(self, x: InsState, dx: FloatArray) -> InsState:
        return self.calib.boxplus(x, dx)

    def _minus(self, x1: InsState, x0: InsState) -> FloatArray:
        return self.calib.boxminus(x1, x0)

    def _start(self, x: InsState) -> InsState:
        # a start from ins.core's boxplus keeps the prior's extra states
        return (
            x
            if isinstance(x, LioState)
            else self.calib.boxplus(self.x, boxminus(x, self.x, self.layout))
        )

    def _update_prior(self, P: FloatArray) -> tuple[FloatArray | None, FloatArray]:
        proj, P0 = self.calib.freeze(P)
        return (proj if self.projector is None else self.projector @ proj), P0

    def _committed(self, H: FloatArray, R: FloatArray) -> None:
        """The scans-only covariance (the guard's evidence) takes the update unprojected on the extra
        states (the pose's columns as the degeneracy guard left them)."""
        if self.projector is not None:
            H = H @ self.projector
        c = self.calib
        c.n_updates += 1
        Rinv_H = H / R[:, None] if np.ndim(R) == 1 else np.linalg.solve(R, H)
        c.P_free = np.linalg.inv(H.T @ Rinv_H + np.linalg.inv(c.P_free))
        c.P_free = 0.5 * (c.P_free + c.P_free.T)
