"""The inertial core every estimator shares: one propagation kernel, one error-state layout with one
boxplus / boxminus, measurements that linearise themselves, chi-square gating, and an error-state Kalman
filter with ``predict``, ``update`` and ``iterated_update``.

Nominal state ``x = (p_n, v_n, R_n_b, b_a, b_g, g_n)``: position (m) and velocity (m/s) in the navigation
frame n, attitude R_n_b, accelerometer and gyro biases (measured = true + bias + noise) and gravity in n.
The error state is addressed by NAMED slices of an :class:`ErrorLayout`, rotation first as everywhere in
imuslam (:mod:`imuslam.geometry`): ``[dtheta, dp, dv, db_a, db_g, dg]``, with the bias and gravity blocks
optional: 15 states (alignment, VIO), 18 with gravity (a world frame whose z is not exactly vertical),
12 = [dtheta, dp, dv, dg] (a LIO that leaves the biases out).

ONE attitude convention: the error is on the right, in the body frame, ``R_true = R exp(dtheta)``
(Sola, "Quaternion kinematics for the error-state Kalman filter", 2017, eqs. 262-270; FAST-LIO2's
``boxplus``). An estimator that thinks in a navigation-frame tilt phi (R_true = exp(phi) R) converts with
``dtheta = R^T phi`` before :func:`boxplus_attitude`.

Propagation per sample interval h (:func:`strapdown_step`; Titterton & Weston 2nd ed. eqs. 3.29-3.33,
transport rate dropped): the attitude by the rotation vector of the mean rate of the two samples plus the
two-sample coning term (h^2 / 12) w_k x w_k+1 (Savage 1998, JGCD 21(1)); the velocity by the trapezoid of
the specific force rotated by the attitude at each end (sculling to second order) plus gravity and
Coriolis; the position by the trapezoid of the velocity. The error-state transition (continuous form,
right perturbation):

    dtheta' = -[w x] dtheta - db_g,   dp' = dv,   dv' = -R [f x] dtheta - R db_a + dg,   db' = random walk

discretised per sample as Phi = I + F h with the attitude block exactly exp(-[w x] h) (first order is
unstable at fast rates), and the velocity-attitude coupling using the navigation-frame specific force
averaged over the block (with each noisy sample a filter on a still base would believe it observes the
heading).

The iterated update is FAST-LIO2's IEKF (Xu, Cai, He, Lin, Zhang, "FAST-LIO2: Fast direct LiDAR-inertial
odometry", IEEE T-RO 38(4), 2022, eqs. 18-20; Xu & Zhang, FAST-LIO, RA-L 2021, eq. 20): re-linearise at
each iterate, gain in state dimension K = (H^T R^-1 H + P^-1)^-1 H^T R^-1, stop when |dx| < eps.
"""

from __future__ import annotations

from collections.abc import Callable

import numba
import numpy as np
from numpy.typing import NDArray

from imuslam.errors import FilterDivergence
from imuslam.geometry.so3_nb import exp_nb
from imuslam.ins.measurement import (
    BlockMeasurement,
    Measurement,
    PositionMeasurement,
    UpdateResult,
    VelocityMeasurement,
    ZeroAngularRate,
    chi2_threshold,
    gate,
)
from imuslam.ins.noise import KfNoise
from imuslam.ins.state import ErrorLayout, InsState, boxminus, boxplus, boxplus_attitude

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

__all__ = [
    "Eskf",
    "ErrorLayout",
    "InsState",
    "KfNoise",
    "Measurement",
    "PositionMeasurement",
    "UpdateResult",
    "VelocityMeasurement",
    "ZeroAngularRate",
    "BlockMeasurement",
    "boxminus",
    "boxplus",
    "boxplus_attitude",
    "chi2_threshold",
    "gate",
    "integrate_nominal",
    "is_pd",
    "kalman_update",
    "propagate",
    "propagate_covariance",
    "strapdown_step",
]


# ---------------------------------------------------------------------------------------------------
# propagation: the one kernel


@numba.njit(cache=True, inline="always")
def strapdown_step(
    p: FloatArray,
    v: FloatArray,
    R: FloatArray,
    f0: FloatArray,
    f1: FloatArray,
    w0: FloatArray,
    w1: FloatArray,
    h: float,
    g_n: FloatArray,
    w_ie_n: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:  # pragma: no cover - compiled
    """One interval of length h (s) between samples (f0, w0) and (f1, w1) (bias-corrected specific force
    m/s^2 and rate rad/s, body frame): the state (p, v, R_n_b) at the second sample, and the first
    sample's specific force in n (R f0). ``w_ie_n``: earth rate in n (zeros to neglect it)."""
    wm = 0.5 * (w0 + w1) * h + (h * h / 12.0) * np.cross(w0, w1)  # coning (Savage 1998)
    Rn = R @ exp_nb(wm)
    earth = w_ie_n[0] != 0.0 or w_ie_n[1] != 0.0 or w_ie_n[2] != 0.0
    if earth:
        Rn = exp_nb(-w_ie_n * h) @ Rn
    f0_n = R @ f0
    dv = 0.5 * (f0_n + Rn @ f1) + g_n
    if earth:
        dv -= 2.0 * np.cross(w_ie_n, v)
    vn = v + h * dv
    pn = p + 0.5 * h * (v + vn)
    return pn, vn, Rn, f0_n


@numba.njit(cache=True)
def integrate_corrected(
    f_b: FloatArray,
    w_b: FloatArray,
    dt: FloatArray,
    p0: FloatArray,
    v0: FloatArray,
    R0: FloatArray,
    g_n: FloatArray,
    w_ie_n: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:  # pragma: no cover - compiled
    """:func:`integrate_nominal` on bias-corrected samples; also the sum of R_k f_k over the intervals."""
    n = f_b.shape[0]
    P = np.empty((n, 3))
    V = np.empty((n, 3))
    Rs = np.empty((n, 3, 3))
    P[0], V[0], Rs[0] = p0, v0, R0
    fn_sum = np.zeros(3)
    for k in range(n - 1):
        pn, vn, Rn, f0_n = strapdown_step(
            P[k], V[k], Rs[k], f_b[k], f_b[k + 1], w_b[k], w_b[k + 1], dt[k], g_n, w_ie_n
        )
        P[k + 1], V[k + 1], Rs[k + 1] = pn, vn, Rn
        fn_sum += f0_n
    return P, V, Rs, fn_sum


@numba.njit(cache=True)
def integrate_nominal(
    accel: FloatArray,
    gyro: FloatArray,
    dt: FloatArray,
    p0: FloatArray,
    v0: FloatArray,
    R0: FloatArray,
    ba: FloatArray,
    bg: FloatArray,
    g_n: FloatArray,
    w_ie_n: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray]:  # pragma: no cover - compiled
    """IMU samples (N, 3) with intervals dt (N - 1,) s -> per-sample states p (N, 3), v (N, 3),
    R_n_b (N, 3, 3), starting at (p0, v0, R0) on sample 0, biases removed from every sample."""
    P, V, Rs, _ = integrate_corrected(accel - ba, gyro - bg, dt, p0, v0, R0, g_n, w_ie_n)
    return P, V, Rs


@numba.njit(cache=True)
def propagate_covariance(
    P: FloatArray,
    Rs: FloatArray,
    gyro: FloatArray,
    bg: FloatArray,
    dt: FloatArray,
    fn_mean: FloatArray,
    q: FloatArray,
    off: IntArray,
) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - compiled
    """Error-state covariance over the block: P (m, m) -> P, and the process noise added in it (Qsum).

    Rs (N, 3, 3) the attitudes at the samples; fn_mean (3,) the block-mean specific force in n;
    q = [accel^2, gyro^2, accel_bias_rw^2, gyro_bias_rw^2] (continuous densities squared); off the
    layout's offsets (TH, P, V, BA, BG, G; -1 absent)."""
    m = P.shape[0]
    Qsum = np.zeros((m, m))
    ith, ip, iv, iba, ibg, ig = off[0], off[1], off[2], off[3], off[4], off[5]
    Fx = np.array(
        [
            [0.0, -fn_mean[2], fn_mean[1]],
            [fn_mean[2], 0.0, -fn_mean[0]],
            [-fn_mean[1], fn_mean[0], 0.0],
        ]
    )
    eye3 = np.eye(3)
    for k in range(dt.shape[0]):
        h = dt[k]
        Rk = Rs[k]
        wm = 0.5 * (gyro[k] + gyro[k + 1]) - bg
        Phi = np.eye(m)
        Phi[ip : ip + 3, iv : iv + 3] += eye3 * h
        Phi[iv : iv + 3, ith : ith + 3] += -(Fx @ Rk) * h
        if iba >= 0:
            Phi[iv : iv + 3, iba : iba + 3] += -Rk * h
        if ibg >= 0:
            Phi[ith : ith + 3, ibg : ibg + 3] += -eye3 * h
        if ig >= 0:
            Phi[iv : iv + 3, ig : ig + 3] += eye3 * h
        Phi[ith : ith + 3, ith : ith + 3] = exp_nb(-wm * h)
        Qd = np.zeros((m, m))
        for i in range(3):
            Qd[iv + i, iv + i] = q[0] * h
            Qd[ith + i, ith + i] = q[1] * h
            if iba >= 0:
                Qd[iba + i, iba + i] = q[2] * h
            if ibg >= 0:
                Qd[ibg + i, ibg + i] = q[3] * h
        P = Phi @ P @ Phi.T + Qd
        Qsum = Phi @ Qsum @ Phi.T + Qd
    return P, Qsum


@numba.njit(cache=True)
def propagate(
    accel: FloatArray,
    gyro: FloatArray,
    dt: FloatArray,
    p: FloatArray,
    v: FloatArray,
    R: FloatArray,
    ba: FloatArray,
    bg: FloatArray,
    g_n: FloatArray,
    P: FloatArray,
    q: FloatArray,
    off: IntArray,
) -> tuple[
    FloatArray, FloatArray, FloatArray, FloatArray, FloatArray
]:  # pragma: no cover - compiled
    """The filter's prediction over samples 0..N-1: per-sample p (N, 3), v (N, 3), R_n_b (N, 3, 3) from
    :func:`integrate_nominal`, and the covariance P and the process noise Qsum at the last sample."""
    Ps, Vs, Rs, fn_sum = integrate_corrected(accel - ba, gyro - bg, dt, p, v, R, g_n, np.zeros(3))
    fn_mean = fn_sum / max(dt.shape[0], 1)
    P, Qsum = propagate_covariance(P, Rs, gyro, bg, dt, fn_mean, q, off)
    return Ps, Vs, Rs, P, Qsum


# ---------------------------------------------------------------------------------------------------
# update


@numba.njit(cache=True)
def is_pd(P: FloatArray) -> bool:  # pragma: no cover - compiled
    """Cholesky without raising: False when P is not positive definite or not finite."""
    n = P.shape[0]
    L = np.zeros((n, n))
    for j in range(n):
        s = P[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not (s > 0.0):
            return False
        L[j, j] = np.sqrt(s)
        for i in range(j + 1, n):
            s = P[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]
    return True


@numba.njit(cache=True)
def kalman_update(
    P: FloatArray,
    Qsum: FloatArray,
    r: FloatArray,
    H: FloatArray,
    Rm: FloatArray,
    stkf: bool,
    V: FloatArray,
    have_v: bool,
    rho: float,
    beta: float,
    max_fading: float,
) -> tuple[FloatArray, FloatArray, FloatArray, float]:  # pragma: no cover - compiled
    """One Kalman update (Joseph form) with innovation r (k,), Jacobian H (k, m), noise Rm (k, k); with
    the strong tracking fading factor when ``stkf`` (Zhou & Frank, Int. J. Control 1996: lambda =
    max(1, tr N / tr M), N = V - H Q H^T - beta R, M = H (P - Q) H^T, V the innovation covariance with
    forgetting rho, Q the process noise since the last update; capped at max_fading).
    Returns dx (m,), the new P, the new V and the fading factor."""
    fading = 1.0
    if stkf:
        rr = np.outer(r, r)
        V = rr if not have_v else (rho * V + rr) / (1.0 + rho)
        N = V - H @ Qsum @ H.T - beta * Rm
        M = H @ (P - Qsum) @ H.T
        lam = np.trace(N) / max(np.trace(M), 1e-300)
        fading = min(max(lam, 1.0), max_fading)
        P = fading * (P - Qsum) + Qsum
    PHt = P @ H.T
    S = H @ PHt + Rm
    K = np.linalg.solve(S, PHt.T).T
    dx = K @ r
    I_KH = np.eye(P.shape[0]) - K @ H
    P = I_KH @ P @ I_KH.T + K @ Rm @ K.T
    P = 0.5 * (P + P.T)
    return dx, P, V, fading


# ---------------------------------------------------------------------------------------------------
# the filter


class Eskf:
    """Error-state Kalman filter on :class:`InsState` with the layout's error state.

    ``predict`` runs the propagation kernel over IMU samples and returns the per-sample states;
    ``update`` takes a :class:`Measurement` (optionally chi-square gated); ``iterated_update`` is the
    IEKF of FAST-LIO2. ``strong_tracking`` turns on the fading factor (STKF) in ``update``. A covariance
    that is not positive definite, or a state that is not finite, raises :class:`FilterDivergence`
    naming the sample.

    x: the initial nominal state; P: its covariance in the layout's order (15 x 15, or 18 x 18 with
    gravity, when no ``layout`` is given).
    """

    def __init__(
        self,
        x: InsState,
        P: FloatArray,
        noise: KfNoise | None = None,
        strong_tracking: bool = False,
        rho: float = 0.95,
        beta: float = 3.0,
        max_fading: float = 5.0,
        layout: ErrorLayout | None = None,
    ) -> None:
        self.x = x.copy()
        self.P = np.array(P, dtype=float)
        if layout is None:
            if self.P.shape[0] not in (15, 18):  # a caller's mistake, not the user's input
                raise ValueError(
                    f"covariance must be 15 x 15 (or 18 x 18 with gravity), got {self.P.shape}"
                )
            layout = ErrorLayout.full(gravity=self.P.shape[0] == 18)
        if self.P.shape != (layout.dim, layout.dim):
            raise ValueError(
                f"covariance {self.P.shape} does not fit the {layout.dim}-state layout"
            )
        self.layout = layout
        self.noise = noise or KfNoise()
        self.strong_tracking = strong_tracking
        self.rho, self.beta, self.max_fading = rho, beta, max_fading
        self.fading = 1.0
        self.n_samples = 0
        self._V: dict[str, FloatArray] = {}
        self._Qsum = np.zeros_like(self.P)
        self._t_s = 0.0

    # the nominal state by its old names
    @property
    def p(self) -> FloatArray:
        return self.x.p_n

    @property
    def v(self) -> FloatArray:
        return self.x.v_n

    @property
    def R(self) -> FloatArray:
        return self.x.R_n_b

    @property
    def ba(self) -> FloatArray:
        return self.x.accel_bias

    @property
    def bg(self) -> FloatArray:
        return self.x.gyro_bias

    @property
    def n(self) -> int:
        return self.layout.dim

    def predict(
        self, accel: FloatArray, gyro: FloatArray, t_s: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Propagate over a block of samples (N, 3) at times t_s (N,) (the first sample ends the last
        block). Returns the per-sample p (N, 3), v (N, 3), R_n_b (N, 3, 3) (e.g. to deskew a scan)."""
        x = self.x
        Ps, Vs, Rs, self.P, Qs = propagate(
            np.ascontiguousarray(accel, float), np.ascontiguousarray(gyro, float),
            np.diff(np.asarray(t_s, float)), x.p_n, x.v_n, np.ascontiguousarray(x.R_n_b),
            x.accel_bias, x.gyro_bias, x.g_n, self.P, self.noise.q, self.layout.offsets,
        )  # fmt: skip
        x.p_n, x.v_n, x.R_n_b = Ps[-1].copy(), Vs[-1].copy(), Rs[-1].copy()
        self._Qsum = self._Qsum + Qs
        self.n_samples += len(t_s) - 1
        self._t_s = float(t_s[-1])
        self._check()
        return Ps, Vs, Rs

    def _apply(self, dx: FloatArray) -> None:
        self.x = boxplus(self.x, dx, self.layout)

    def update(self, meas: Measurement, gate_prob: float | None = None) -> UpdateResult:
        """Linearise ``meas`` at the current state, gate it (when ``gate_prob``), and correct."""
        r, H, Rm = meas.linearize(self.x, self.layout)
        nis = float("nan")
        if gate_prob is not None:
            ok, nis = gate(r, H, Rm, self.P, gate_prob)
            if not ok:
                return UpdateResult(False, nis, r, np.zeros(self.n))
        prev = self._V.get(meas.kind)
        dx, self.P, V, self.fading = kalman_update(
            self.P, self._Qsum, np.asarray(r, float), np.ascontiguousarray(H, float),
            np.ascontiguousarray(Rm, float), self.strong_tracking,
            prev if prev is not None else np.zeros((len(r), len(r))), prev is not None,
            self.rho, self.beta, self.max_fading,
        )  # fmt: skip
        if self.strong_tracking:
            self._V[meas.kind] = V
        self._apply(dx)
        self._Qsum = np.zeros_like(self.P)
        self._check()
        return UpdateResult(True, nis, r, dx)

    def iterated_update(
        self,
        linearize_fn: Callable[[InsState], tuple[FloatArray, FloatArray, FloatArray]],
        max_iter: int = 5,
        eps: float = 1e-6,
        gate_prob: float | None = None,
        x_start: InsState | None = None,
        commit: bool = True,
    ) -> UpdateResult:
        """IEKF update (FAST-LIO2, Xu et al. 2022, eqs. 18-20): at iterate x_j with
        delta = x_j ⊟ x_prior, ``(r, H, R) = linearize_fn(x_j)``, K = (H^T R^-1 H + P^-1)^-1 H^T R^-1
        (state dimension: cheap for thousands of point-to-plane rows), x_j+1 = x_j ⊞ (K r - (I - K H)
        delta); stop when |x_j+1 ⊟ x_j| < eps or after ``max_iter``; then P = (I - K H) P. The Jacobian
        of ⊟ at the prior is taken as identity (its attitude block differs from it by O(|dtheta|)).
        ``linearize_fn`` may return R as a 1-D array of variances (a diagonal R), which keeps the cost
        linear in the number of rows; gating needs the full matrix. ``x_start`` starts the iterations
        at another iterate than the prior (Gauss-Newton on the same posterior cost, so any start that
        converges gives the same estimate); with ``commit=False`` the state and covariance are left as
        they were and the result's dx is the last iterate's offset from the prior."""
        x0 = self.x
        proj, P0 = self._update_prior(self.P)
        try:
            Pinv = np.linalg.inv(P0)
        except np.linalg.LinAlgError:
            raise FilterDivergence(
                f"filter diverged at sample {self.n_samples} (t = {self._t_s:.3f} s): prior covariance singular"
            ) from None
        xj = x0 if x_start is None else self._start(x_start)
        r0 = np.zeros(0)
        nis = float("nan")
        m = self.n
        KH: FloatArray = np.zeros((m, m))
        H0: FloatArray = np.zeros((0, m))
        R0: FloatArray = np.zeros(0)
        it = 0
        for it in range(1, max_iter + 1):
            r, H, Rm = linearize_fn(xj)
            if it == 1:
                r0, H0, R0 = r, H, Rm
                if gate_prob is not None:
                    ok, nis = gate(r, H, Rm, P0, gate_prob)
                    if not ok:
                        return UpdateResult(False, nis, r, np.zeros(m), 0)
            if proj is not None:
                H = H @ proj
            delta = self._minus(xj, x0)
            # R^-1 H; a 1-D R is the diagonal (independent rows: thousands of point-to-plane residuals)
            Rinv_H = H / Rm[:, None] if np.ndim(Rm) == 1 else np.linalg.solve(Rm, H)
            HtRH = H.T @ Rinv_H
            A = HtRH + Pinv
            # K = A^-1 H^T R^-1 never formed (m x k): only K H and K r are needed
            KH = np.asarray(np.linalg.solve(A, HtRH), dtype=np.float64)
            step = np.linalg.solve(A, Rinv_H.T @ r) - (np.eye(m) - KH) @ delta
            xj = self._plus(xj, step)
            if not np.all(np.isfinite(step)):
                break
            if float(np.linalg.norm(step)) < eps:
                break
        if not commit:
            return UpdateResult(True, nis, r0, self._minus(xj, x0), it)
        self._committed(H0, R0)
        self.x = xj
        self.P = (np.eye(m) - KH) @ P0
        self.P = 0.5 * (self.P + self.P.T)
        self._Qsum = np.zeros_like(self.P)
        self._check()
        return UpdateResult(True, nis, r0, self._minus(xj, x0), it)

    # the iterated update's hooks: a filter with states ``boxplus`` leaves to their owner (the LIO's
    # in-filter extrinsic, lio.online_calib) overrides them; the defaults are the plain ESKF's
    def _plus(self, x: InsState, dx: FloatArray) -> InsState:
        return boxplus(x, dx, self.layout)

    def _minus(self, x1: InsState, x0: InsState) -> FloatArray:
        return boxminus(x1, x0, self.layout)

    def _start(self, x: InsState) -> InsState:
        """The first iterate from a caller's start state."""
        return x

    def _update_prior(self, P: FloatArray) -> tuple[FloatArray | None, FloatArray]:
        """(a projector applied to H's columns, or None; the prior covariance the update uses)."""
        return None, P

    def _committed(self, H: FloatArray, R: FloatArray) -> None:
        """Called with the first iterate's Jacobian and noise when an update is committed."""

    # the alignment's measurements by name
    def update_position(self, p_meas: FloatArray, std: float, t_s: float) -> FloatArray:
        self._t_s = t_s
        return self.update(PositionMeasurement(p_meas, std)).r

    def update_velocity(self, v_meas: FloatArray, std: float, t_s: float) -> FloatArray:
        self._t_s = t_s
        return self.update(VelocityMeasurement(v_meas, std)).r

    def update_zupt(self, std: float, t_s: float) -> FloatArray:
        return self.update_velocity(np.zeros(3), std, t_s)

    def update_zaru(self, gyro_mean: FloatArray, std: float, t_s: float) -> FloatArray:
        """Zero angular rate update (see :class:`ZeroAngularRate`): without it the gyro bias along
        gravity is unobservable on a still base and an EKF can still grow overconfident in it."""
        self._t_s = t_s
        return self.update(ZeroAngularRate(gyro_mean, std)).r

    def _check(self) -> None:
        x = self.x
        ok = bool(np.isfinite(self.P).all() and np.isfinite(x.p_n).all() and np.isfinite(x.v_n).all()
                  and np.isfinite(x.R_n_b).all())  # fmt: skip
        if ok:
            self.P = 0.5 * (self.P + self.P.T)
            ok = is_pd(self.P + np.eye(self.n) * 1e-18)
        if not ok:
            raise FilterDivergence(
                f"filter diverged at sample {self.n_samples} (t = {self._t_s:.3f} s): covariance not "
                "positive definite or state not finite; check the noise settings and the aiding"
            )

    @property
    def bias_std(self) -> tuple[FloatArray, FloatArray]:
        d = np.sqrt(np.diag(self.P))
        lay = self.layout
        return d[lay.BA], d[lay.BG]
