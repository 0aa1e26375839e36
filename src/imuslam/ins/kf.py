"""Fine alignment by an error-state Kalman filter, and its strong tracking variant.

Nominal state: position p, velocity v (ENU), attitude R_n_b, accelerometer bias b_a and gyro bias b_g
(measured = true + bias + noise). Error state (15): ``[dp, dv, dtheta, db_a, db_g]`` with the attitude
error on the right, ``R_true = R exp(dtheta)`` (Sola 2017, eqs. 262-270):

    dp' = dv,   dv' = -R [f x] dtheta - R db_a,   dtheta' = -[w x] dtheta - db_g,   db' = random walk

discretised per sample as Phi = I + F dt. Aiding: zero velocity (ZUPT), velocity, or position in n.
Strong tracking (Zhou & Frank, "Strong tracking filtering of nonlinear time-varying stochastic systems
with coloured noise", Int. J. Control 1996): at each update the predicted covariance is inflated by a
fading factor lambda = max(1, tr N / tr M), N = V - H Q H^T - beta R, M = H (P - Q) H^T, with V the
innovation covariance estimated with forgetting factor rho, and Q the process noise added since the last
update (the multi-rate form of the STF); lambda is capped. Defaults beta = 3, cap 5, rho = 0.95: with
beta = 1 the factor fires on measurement noise alone and the bias states wander off (simulated hand-held
case, 1 cm position fixes: 9-12 sigma errors, against 1.4 sigma with beta = 3).
A covariance that loses symmetry or positive definiteness, or a NaN, raises :class:`FilterDivergence`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numba
import numpy as np
import yaml
from numpy.typing import NDArray

from imuslam.errors import FilterDivergence, InputError
from imuslam.ins.strapdown import _exp3

FloatArray = NDArray[np.float64]


@dataclass
class KfNoise:
    """Continuous noise densities: accel (m/s^2/sqrt(Hz)), gyro (rad/s/sqrt(Hz)), bias random walks."""

    accel: float = 3e-3
    gyro: float = 2e-4
    accel_bias_rw: float = 1e-4
    gyro_bias_rw: float = 2e-5

    def __post_init__(self) -> None:
        for name in ("accel", "gyro", "accel_bias_rw", "gyro_bias_rw"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise InputError(f"noise '{name}' must be a positive number, got {v}")

    @classmethod
    def from_kalibr_yaml(cls, path: str | Path) -> KfNoise:
        """Read a Kalibr ``imu.yaml`` (as ``imuslam allan`` writes): the four noise fields."""
        p = Path(path)
        if not p.is_file():
            raise InputError(f"{p}: no such noise file")
        try:
            d = yaml.safe_load(p.read_text())
        except yaml.YAMLError as e:
            raise InputError(f"{p}: not valid YAML ({e})") from None
        keys = ("accelerometer_noise_density", "gyroscope_noise_density", "accelerometer_random_walk",
                "gyroscope_random_walk")  # fmt: skip
        vals = []
        for k in keys:
            v = d.get(k) if isinstance(d, dict) else None
            if not isinstance(v, (int, float)) or isinstance(v, bool):
                raise InputError(f"{p}: field '{k}' must be a number (Kalibr imu.yaml), got {v!r}")
            vals.append(float(v))
        try:
            return cls(*vals)
        except InputError as e:
            raise InputError(f"{p}: {e}") from None

    @classmethod
    def from_log(cls, accel: FloatArray, gyro: FloatArray, rate_hz: float,
                 floor: KfNoise | None = None) -> KfNoise:  # fmt: skip
        """White-noise densities as the log shows them, vibration included, never below ``floor``.

        The Allan variance at the shortest cluster time tau0 = 1 / rate is E[(x[k+1] - x[k])^2] / 2, and
        for white noise of density N it equals N^2 / tau0 (IEEE Std 952-1997, annex C), so
        N = std(diff x) / sqrt(2 rate). On a moving robot this sees the vibration that a bench Allan
        analysis does not (EuRoC's MAV: 0.04-0.10 m/s^2/sqrt(Hz) against the ADIS16448's 0.002), plus the
        signal's own change between samples, which is small at IMU rates. Axes are combined as RMS; the
        random walks cannot be seen in a short log and come from ``floor``.
        """
        fl = floor or cls()
        a = np.asarray(accel, float)
        w = np.asarray(gyro, float)
        if a.ndim != 2 or a.shape[1] != 3 or a.shape != w.shape or len(a) < 3:
            raise InputError(
                f"noise estimate needs (N >= 3, 3) accel and gyro, got {a.shape} and {w.shape}"
            )
        if not (np.isfinite(rate_hz) and rate_hz > 0):
            raise InputError(f"noise estimate needs a positive sample rate, got {rate_hz}")

        def density(x: FloatArray) -> float:
            return float(np.sqrt(np.mean(np.var(np.diff(x, axis=0), axis=0)) / (2.0 * rate_hz)))

        return cls(
            max(density(a), fl.accel), max(density(w), fl.gyro), fl.accel_bias_rw, fl.gyro_bias_rw
        )


@numba.njit(cache=True)
def _propagate(
    accel: FloatArray,
    gyro: FloatArray,
    dt: FloatArray,
    p: FloatArray,
    v: FloatArray,
    R: FloatArray,
    ba: FloatArray,
    bg: FloatArray,
    P: FloatArray,
    g_n: FloatArray,
    q: FloatArray,
) -> tuple[
    FloatArray, FloatArray, FloatArray, FloatArray, FloatArray
]:  # pragma: no cover - compiled
    """Propagate nominal state and covariance over samples 0..N-1 (N - 1 steps). Returns p, v, R, P, Qsum.

    P is 15 x 15, or 18 x 18 with a gravity-vector error in n as the last three states (dv' += dg).
    """
    m = P.shape[0]
    Qsum = np.zeros((m, m))
    ns = dt.shape[0]
    Rs = np.empty((ns + 1, 3, 3))
    Rs[0] = R
    fn_mean = np.zeros(3)
    for k in range(ns):  # nominal state
        h = dt[k]
        f0 = accel[k] - ba
        f1 = accel[k + 1] - ba
        wm = 0.5 * (gyro[k] + gyro[k + 1]) - bg
        wm = wm + (h / 12.0) * np.cross(
            gyro[k] - bg, gyro[k + 1] - bg
        )  # coning, as ins/strapdown.py
        Rn = R @ _exp3(wm[0] * h, wm[1] * h, wm[2] * h)
        a0 = R @ f0
        vn = v + h * (0.5 * (a0 + Rn @ f1) + g_n)
        p = p + 0.5 * h * (v + vn)
        fn_mean += a0
        v, R = vn, Rn
        Rs[k + 1] = R
    # The coupling of attitude error into velocity, -[(R f) x] R dtheta, uses the navigation-frame specific
    # force averaged over the block: with each noisy sample instead, white noise in f would make the
    # filter believe it observes the heading (and the gyro bias along gravity) on a still base.
    fn_mean /= max(ns, 1)
    Fx = np.array(
        [
            [0.0, -fn_mean[2], fn_mean[1]],
            [fn_mean[2], 0.0, -fn_mean[0]],
            [-fn_mean[1], fn_mean[0], 0.0],
        ]
    )
    for k in range(ns):  # covariance
        h = dt[k]
        Rk = Rs[k]
        wm = 0.5 * (gyro[k] + gyro[k + 1]) - bg
        F = np.zeros((m, m))
        if m == 18:
            F[3:6, 15:18] = np.eye(3)
        F[0:3, 3:6] = np.eye(3)
        F[3:6, 6:9] = -Fx @ Rk
        F[3:6, 9:12] = -Rk
        F[6:9, 12:15] = -np.eye(3)
        Phi = np.eye(m) + F * h
        # the attitude-error block exactly, exp(-[w x] h): first order is unstable at fast rates
        # (a platform turning at 10 Hz moves 0.16 rad per 400 Hz sample)
        Phi[6:9, 6:9] = _exp3(-wm[0] * h, -wm[1] * h, -wm[2] * h)
        Qd = np.zeros((m, m))
        for i in range(3):
            Qd[3 + i, 3 + i] = q[0] * h
            Qd[6 + i, 6 + i] = q[1] * h
            Qd[9 + i, 9 + i] = q[2] * h
            Qd[12 + i, 12 + i] = q[3] * h
        P = Phi @ P @ Phi.T + Qd
        Qsum = Phi @ Qsum @ Phi.T + Qd
    return p, v, R, P, Qsum


@dataclass
class Eskf:
    """15-state error-state KF (18 with the gravity vector, for a world frame whose z is not exactly
    vertical, e.g. a motion-capture frame). ``strong_tracking`` turns on the fading factor (STKF)."""

    p: FloatArray
    v: FloatArray
    R: FloatArray
    P: FloatArray
    ba: FloatArray = field(default_factory=lambda: np.zeros(3))
    bg: FloatArray = field(default_factory=lambda: np.zeros(3))
    noise: KfNoise = field(default_factory=KfNoise)
    g: float = 9.80665
    strong_tracking: bool = False
    rho: float = 0.95
    beta: float = 3.0
    max_fading: float = 5.0
    fading: float = 1.0
    _V: dict[str, FloatArray] = field(default_factory=dict)
    _Qsum: FloatArray | None = None
    n_samples: int = 0
    dg: FloatArray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        self.n = self.P.shape[0]
        if self.n not in (15, 18):
            raise InputError(
                f"covariance must be 15 x 15 (or 18 x 18 with gravity), got {self.P.shape}"
            )
        self._Qsum = np.zeros((self.n, self.n))

    def predict(self, accel: FloatArray, gyro: FloatArray, t_s: FloatArray) -> None:
        """Propagate over a block of samples (N, 3) at times t_s (N,) (the first sample ends the last block)."""
        q = np.array(
            [
                self.noise.accel**2,
                self.noise.gyro**2,
                self.noise.accel_bias_rw**2,
                self.noise.gyro_bias_rw**2,
            ]
        )
        self.p, self.v, self.R, self.P, Qs = _propagate(
            np.ascontiguousarray(accel, float), np.ascontiguousarray(gyro, float), np.diff(t_s), self.p, self.v,
            self.R, self.ba, self.bg, self.P, np.array([0.0, 0.0, -self.g]) + self.dg, q,
        )  # fmt: skip
        assert self._Qsum is not None
        self._Qsum = self._Qsum + Qs
        self.n_samples += len(t_s) - 1
        self._check(float(t_s[-1]))

    def update(
        self,
        z: FloatArray,
        zhat: FloatArray,
        H: FloatArray,
        Rm: FloatArray,
        t_s: float,
        kind: str = "generic",
    ) -> FloatArray:
        """Kalman update with measurement z (m,), prediction zhat, Jacobian H (m, 15), noise Rm (m, m).

        ``kind`` names the measurement model: the strong tracking filter keeps one innovation covariance
        estimate per kind (innovations of different models must not be mixed). Returns the innovation.
        """
        r = z - zhat
        assert self._Qsum is not None
        if self.strong_tracking:
            prev = self._V.get(kind)
            V = (
                np.outer(r, r)
                if prev is None
                else (self.rho * prev + np.outer(r, r)) / (1 + self.rho)
            )
            self._V[kind] = V
            N = V - H @ self._Qsum @ H.T - self.beta * Rm
            M = H @ (self.P - self._Qsum) @ H.T
            lam = float(np.trace(N) / max(np.trace(M), 1e-300))
            self.fading = float(np.clip(lam, 1.0, self.max_fading))
            self.P = self.fading * (self.P - self._Qsum) + self._Qsum
        S = H @ self.P @ H.T + Rm
        K = np.linalg.solve(S, H @ self.P).T
        dx = K @ r
        I_KH = np.eye(self.n) - K @ H
        self.P = I_KH @ self.P @ I_KH.T + K @ Rm @ K.T  # Joseph form
        self.p = self.p + dx[0:3]
        self.v = self.v + dx[3:6]
        self.R = self.R @ _exp3(dx[6], dx[7], dx[8])
        self.ba = self.ba + dx[9:12]
        self.bg = self.bg + dx[12:15]
        if self.n == 18:
            self.dg = self.dg + dx[15:18]
        self._Qsum = np.zeros((self.n, self.n))
        self._check(t_s)
        return r

    def update_velocity(self, v_meas: FloatArray, std: float, t_s: float) -> FloatArray:
        H = np.zeros((3, self.n))
        H[:, 3:6] = np.eye(3)
        return self.update(
            np.asarray(v_meas, float), self.v, H, np.eye(3) * std**2, t_s, "velocity"
        )

    def update_zupt(self, std: float, t_s: float) -> FloatArray:
        return self.update_velocity(np.zeros(3), std, t_s)

    def update_zaru(self, gyro_mean: FloatArray, std: float, t_s: float) -> FloatArray:
        """Zero angular rate update: on a still base the mean raw rate (3,) over a block is the gyro bias
        (the earth's rate, 15 deg/h at most, is neglected; give ``std`` above it for a navigation-grade gyro).
        Without it the gyro bias along gravity is unobservable and an EKF can still grow overconfident in it."""
        H = np.zeros((3, self.n))
        H[:, 12:15] = np.eye(3)
        return self.update(
            np.asarray(gyro_mean, float), self.bg, H, np.eye(3) * std**2, t_s, "zaru"
        )

    def update_position(self, p_meas: FloatArray, std: float, t_s: float) -> FloatArray:
        H = np.zeros((3, self.n))
        H[:, 0:3] = np.eye(3)
        return self.update(
            np.asarray(p_meas, float), self.p, H, np.eye(3) * std**2, t_s, "position"
        )

    def _check(self, t_s: float) -> None:
        ok = bool(
            np.isfinite(self.P).all() and np.isfinite(self.p).all() and np.isfinite(self.R).all()
        )
        if ok:
            self.P = 0.5 * (self.P + self.P.T)
            try:
                np.linalg.cholesky(self.P + np.eye(self.n) * 1e-18)
            except np.linalg.LinAlgError:
                ok = False
        if not ok:
            raise FilterDivergence(
                f"filter diverged at sample {self.n_samples} (t = {t_s:.3f} s): covariance not positive definite "
                "or state not finite; check the noise settings and the aiding"
            )

    @property
    def bias_std(self) -> tuple[FloatArray, FloatArray]:
        d = np.sqrt(np.diag(self.P))
        return d[9:12], d[12:15]


@numba.njit(cache=True)
def _is_pd(P: FloatArray) -> bool:  # pragma: no cover - compiled
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
def _kf_update(
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
    """One Kalman update (Joseph form), with the strong tracking fading factor when ``stkf``. Returns the
    state correction dx, the new P, the new innovation covariance estimate V and the fading factor."""
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


@numba.njit(cache=True)
def _eskf_batch(
    accel: FloatArray,
    gyro: FloatArray,
    t: FloatArray,
    aid_k: NDArray[np.int64],
    aid_val: FloatArray,
    kind: int,
    std: float,
    zaru_std: FloatArray,
    p: FloatArray,
    v: FloatArray,
    R: FloatArray,
    ba: FloatArray,
    bg: FloatArray,
    dg: FloatArray,
    P: FloatArray,
    g_n: FloatArray,
    q: FloatArray,
    stkf: bool,
    rho: float,
    beta: float,
    max_fading: float,
) -> tuple[
    FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray,
    FloatArray, FloatArray, FloatArray, FloatArray, int, int,
]:  # fmt: skip  # pragma: no cover - compiled
    """The filter over every aiding epoch j (sample ``aid_k[j]``): predict, then update by ``kind`` (0
    position, 1 velocity, 2 zupt = zero velocity and the block's mean rate with 1-sigma ``zaru_std[j]``).
    Returns the histories (M, ...) of b_a, b_g, their 1-sigma, R, p, v, fading; the final p, v, R, P; the
    number of epochs done and, on divergence, the sample index (else -1)."""
    m = P.shape[0]
    M_ = aid_k.shape[0]
    hb_a = np.zeros((M_, 3))
    hb_g = np.zeros((M_, 3))
    hs_a = np.zeros((M_, 3))
    hs_g = np.zeros((M_, 3))
    hR = np.zeros((M_, 3, 3))
    hp = np.zeros((M_, 3))
    hv = np.zeros((M_, 3))
    hf = np.ones(M_)
    Qsum = np.zeros((m, m))
    V0 = np.zeros((3, 3))
    V1 = np.zeros((3, 3))
    have0 = False
    have1 = False
    Rm = np.eye(3) * std * std
    k = 0
    for j in range(M_):
        kn = aid_k[j]
        k0 = k
        if kn > k:
            p, v, R, P, Qs = _propagate(accel[k : kn + 1], gyro[k : kn + 1], t[k + 1 : kn + 1] - t[k:kn],
                                        p, v, R, ba, bg, P, g_n + dg, q)  # fmt: skip
            Qsum += Qs
            k = kn
            if not (np.all(np.isfinite(P)) and np.all(np.isfinite(p)) and np.all(np.isfinite(R))):
                return hb_a, hb_g, hs_a, hs_g, hR, hp, hv, hf, p, v, R, P, j, k
            P = 0.5 * (P + P.T)
            if not _is_pd(P + np.eye(m) * 1e-18):
                return hb_a, hb_g, hs_a, hs_g, hR, hp, hv, hf, p, v, R, P, j, k
        H = np.zeros((3, m))
        if kind == 0:
            H[:, 0:3] = np.eye(3)
            r = aid_val[j] - p
        else:
            H[:, 3:6] = np.eye(3)
            r = (aid_val[j] if kind == 1 else np.zeros(3)) - v
        n_upd = 2 if kind == 2 else 1
        for u in range(n_upd):
            if u == 1:  # zero angular rate: the block's mean raw rate is the gyro bias
                H = np.zeros((3, m))
                H[:, 12:15] = np.eye(3)
                mean = np.zeros(3)
                for i in range(k0, kn + 1):
                    mean += gyro[i]
                mean /= kn + 1 - k0
                r = mean - bg
                Rz = np.eye(3) * zaru_std[j] * zaru_std[j]
                dx, P, V1, fad = _kf_update(
                    P, Qsum, r, H, Rz, stkf, V1, have1, rho, beta, max_fading
                )
                have1 = True
            else:
                dx, P, V0, fad = _kf_update(
                    P, Qsum, r, H, Rm, stkf, V0, have0, rho, beta, max_fading
                )
                have0 = True
            hf[j] = fad
            p = p + dx[0:3]
            v = v + dx[3:6]
            R = R @ _exp3(dx[6], dx[7], dx[8])
            ba = ba + dx[9:12]
            bg = bg + dx[12:15]
            if m == 18:
                dg = dg + dx[15:18]
            Qsum[:, :] = 0.0
            if not (np.all(np.isfinite(P)) and np.all(np.isfinite(p)) and np.all(np.isfinite(R))):
                return hb_a, hb_g, hs_a, hs_g, hR, hp, hv, hf, p, v, R, P, j, kn
            if not _is_pd(P + np.eye(m) * 1e-18):
                return hb_a, hb_g, hs_a, hs_g, hR, hp, hv, hf, p, v, R, P, j, kn
        hb_a[j] = ba
        hb_g[j] = bg
        for i in range(3):
            hs_a[j, i] = np.sqrt(P[9 + i, 9 + i])
            hs_g[j, i] = np.sqrt(P[12 + i, 12 + i])
        hR[j] = R
        hp[j] = p
        hv[j] = v
    return hb_a, hb_g, hs_a, hs_g, hR, hp, hv, hf, p, v, R, P, M_, -1
