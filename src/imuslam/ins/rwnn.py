"""Alignment by an observer with a recurrent wavelet neural network (RWNN) estimating the IMU's error
(seed 001, module 1; MISSION.md part B.1).

The seed's observer is x' = A x + B (u + du) + L (y - C x) with L such that A - L C is Hurwitz and du the
RWNN's estimate of the IMU's error. Here x = [p, v] in n, u = R_n_b f_b + g_n, and the network outputs the
body-frame errors e_a, e_g (measured = true + error) that correct the sensor before the strapdown, so
du = -R_n_b e_a (and the attitude integrates omega - e_g).

Network (the choices the seed leaves open are stated here):
- inputs, each normalised to [0, 1] by fixed ranges: the last innovation (3, +-1 m or m/s), the specific
  force (3, +-2 g) and the rate (3, +-5 rad/s);
- recurrent wavelet layer: each input i through 3 Mexican-hat wavelets sigma(mu) = (1 - mu^2) exp(-mu^2 / 2),
  scaled and shifted sigma_{d,t}(mu) = 2^(d/2) sigma(2^d mu - t) with (d, t) = (0, 0), (1, 0.5), (2, 1),
  whose input is mu = z_i + r phi_prev (memory of the previous step, r = ``recurrence``);
- product layer: node j multiplies the j-th wavelet of every input, Pi_j = prod_i phi_ij (3 nodes);
- output layer: per output (e_a, e_g: 6) a weighted sum of [1, Pi_1, Pi_2, Pi_3], e = W Pi.

Learning. The output is linear in the weights W, so the observer is an adaptive observer for a linear
time-varying system (Q. Zhang, "Adaptive observer for multiple-input-multiple-output (MIMO) linear
time-varying systems", IEEE TAC 47(3), 2002). Its error dynamics, with the attitude error phi in n
(R_true = exp(phi) R), are

    dp' = dv,   dv' = -[f_n x] phi - R (w_a - W_a) Pi,   phi' = -R (w_g - W_g) Pi

(Savage; Sola 2017 eq. 262 ff. in the navigation frame). The sensitivity Y = d x / d W obeys
Y' = (A(t) - K C) Y + Psi(t) with the regressor Psi = [0; -R (x) Pi^T; -R (x) Pi^T]; the innovation is
e = C Y (W_true - W) + (a decaying state error), so the weights learn along Y^T C^T e. Because Y carries the
phase of the dynamics, biases modulated by a rotating platform are demodulated correctly, which a gradient of
the raw innovation is not. The weights of the constant input (the biases) learn by recursive least squares
with a forgetting factor (Zhang's Gamma = P); the wavelet weights by a normalised gradient at rate
``eta_wavelet``, each step clipped to ``max_rate`` and each weight to ``max_weight`` (projection), with
leakage (e-modification) so they stay bounded without persistent excitation. On a still base (``zupt``
aiding) the mean rate is also a direct measurement of the gyro error, as the Kalman filter's ZARU.

Gain K (applied at the aiding times, the discrete form of L): position aiding, per axis dp += 3 w h e,
dv += 3 w^2 h e; velocity aiding dv += 2 w h e; and the attitude is turned by k_att h f_n x a_c / |f_n|^2 with
a_c the acceleration correction (3 w^2 e or 2 w e), heading from the horizontal specific force only,
regularised by ``f_h_reg``. With k_att = w / 3 the level channel has all three roots at -w
(:func:`observer_matrix`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, Field

from imuslam.errors import InputError
from imuslam.ins.core import boxplus_attitude, strapdown_step

FloatArray = NDArray[np.float64]


class RwnnConfig(BaseModel):
    """Gains of the RWNN observer."""

    omega: float = Field(1.0, gt=0, description="observer bandwidth, rad/s")
    f_h_reg: float = Field(
        0.3,
        gt=0,
        description="horizontal specific force below which heading is barely corrected, m/s^2",
    )
    accel_error_std: float = Field(
        0.2, gt=0, description="prior 1-sigma of the accelerometer error, m/s^2"
    )
    gyro_error_std: float = Field(0.02, gt=0, description="prior 1-sigma of the gyro error, rad/s")
    attitude_std: float = Field(
        0.05, gt=0, description="prior 1-sigma of the initial attitude, rad"
    )
    velocity_std: float = Field(0.1, gt=0, description="prior 1-sigma of the initial velocity, m/s")
    forgetting_s: float = Field(
        1000.0, gt=0, description="memory of the least-squares learning (forgetting factor), s"
    )
    eta_wavelet: float = Field(0.05, ge=0, description="learning rate of the wavelet weights")
    leakage: float = Field(
        1e-3, ge=0, description="e-modification leakage of the wavelet weights, 1/s"
    )
    max_rate: float = Field(0.05, gt=0, description="bound on a wavelet weight's change per second")
    max_weight: float = Field(
        0.2, gt=0, description="bound on a wavelet weight's magnitude (m/s^2 or rad/s)"
    )
    recurrence: float = Field(
        0.2, ge=0, lt=1, description="memory gain of the recurrent wavelet layer"
    )


def observer_matrix(omega: float, position: bool) -> FloatArray:
    """A - K C of one level axis, x = [p, v, tilt * g] (position aiding) or [v, tilt * g]: the gains put
    every eigenvalue at -omega."""
    if position:
        l1, l2, k = 3 * omega, 3 * omega**2, omega / 3
        return np.array([[-l1, 1.0, 0.0], [-l2, 0.0, -1.0], [k * l2, 0.0, 0.0]])
    l1, k = 2 * omega, omega / 2
    return np.array([[-l1, -1.0], [k * l1, 0.0]])


def innovation_variance(
    omega: float, position: bool, aid_std: float, accel_noise: float, h_a: float
) -> float:
    """Variance the least-squares learning gives each innovation: the aiding's own, plus the observer
    loop's response to accelerometer white noise of density q, P = q^2 c / omega^3 (position) or
    q^2 c / omega (velocity) from the Lyapunov equation of :func:`observer_matrix`, inflated by the number of
    aiding samples over which that response stays correlated, 2 / (omega h_a) (the variance of a mean of
    exponentially correlated samples)."""
    from scipy.linalg import solve_continuous_lyapunov

    A = observer_matrix(omega, position)
    B = np.zeros((A.shape[0], 1))
    B[1 if position else 0] = accel_noise
    P = solve_continuous_lyapunov(A, -B @ B.T)
    return float(aid_std**2 + P[0, 0] * max(1.0, 2.0 / (omega * h_a)))


@numba.njit(cache=True, inline="always")
def _mexican_hat(mu: float) -> float:  # pragma: no cover - compiled
    return (1.0 - mu * mu) * np.exp(-0.5 * mu * mu)


@numba.njit(cache=True)
def _rwnn_observer(
    t: FloatArray,
    accel: FloatArray,
    gyro: FloatArray,
    aid_idx: NDArray[np.int64],
    aid_t: FloatArray,
    aid_val: FloatArray,
    meas_var: float,
    kind: int,
    p0: FloatArray,
    v0: FloatArray,
    R0: FloatArray,
    g: float,
    gains: FloatArray,
) -> tuple[
    FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray
]:  # pragma: no cover - compiled
    """Run the observer over the log. ``kind`` 0 position, 1 velocity, 2 zupt (zero velocity and rate).
    Returns accel error (N, 3), gyro error (N, 3), p (N, 3), v (N, 3), R (N, 3, 3) and the 1-sigma of the
    bias weights (N, 6) from the least-squares covariance."""
    omega, f_h_reg, sa0, sg0, t_forget, eta_w, leak, max_rate, max_w, rec, sth0, sv0 = gains
    position = kind == 0
    n = t.shape[0]
    n_in = 9
    # weights: 6 outputs x [1, Pi_1, Pi_2, Pi_3] at index o * 4 + c; then the initial attitude (24-26) and
    # velocity (27-29) errors, nuisance parameters learned with the biases so that an initial error is not
    # taken for a bias
    n_par = 30
    n_ls = 12
    ls_col = np.array([0, 4, 8, 12, 16, 20, 24, 25, 26, 27, 28, 29])
    d = np.array([0.0, 1.0, 2.0])
    sh = np.array([0.0, 0.5, 1.0])
    scale_in = np.array([1.0, 1.0, 1.0, 2 * 9.81, 2 * 9.81, 2 * 9.81, 5.0, 5.0, 5.0])
    phi_prev = np.zeros((n_in, 3))
    W = np.zeros((6, 4))
    # least-squares covariance: accel bias, gyro bias, initial attitude, initial velocity
    Pb = np.zeros((n_ls, n_ls))
    for i in range(3):
        Pb[i, i] = sa0 * sa0
        Pb[3 + i, 3 + i] = sg0 * sg0
        Pb[6 + i, 6 + i] = sth0 * sth0
        Pb[9 + i, 9 + i] = sv0 * sv0
    Y = np.zeros((9, n_par))  # sensitivity of [dp, dv, phi] to the parameters
    for i in range(3):
        Y[6 + i, 24 + i] = 1.0
        Y[3 + i, 27 + i] = 1.0
    p = p0.copy()
    v = v0.copy()
    R = R0.copy()
    g_n = np.array([0.0, 0.0, -g])
    no_earth_rate = np.zeros(3)
    ea_out = np.zeros((n, 3))
    eg_out = np.zeros((n, 3))
    sd_out = np.zeros((n, 6))
    P = np.zeros((n, 3))
    V = np.zeros((n, 3))
    Rs = np.zeros((n, 3, 3))
    Pi = np.ones(4)
    innov = np.zeros(3)
    f_bar = np.array([0.0, 0.0, g])
    f_sum = np.zeros(3)
    w_sum = np.zeros(3)
    w_sq = np.zeros(3)
    n_sum = 0
    t_last = t[0]
    m = 0
    ri = 0 if position else 3  # first row of Y the aiding sees: dp or dv
    for k in range(n):
        # network forward pass on the current inputs
        z = np.empty(n_in)
        for i in range(3):
            z[i] = 0.5 + 0.5 * max(-1.0, min(1.0, innov[i] / scale_in[i]))
            z[3 + i] = 0.5 + 0.5 * max(-1.0, min(1.0, accel[k, i] / scale_in[3 + i]))
            z[6 + i] = 0.5 + 0.5 * max(-1.0, min(1.0, gyro[k, i] / scale_in[6 + i]))
        for j in range(3):
            prod = 1.0
            for i in range(n_in):
                mu = z[i] + rec * phi_prev[i, j]
                ph = 2.0 ** (d[j] / 2) * _mexican_hat(2.0 ** d[j] * mu - sh[j])
                phi_prev[i, j] = ph
                prod *= ph
            Pi[1 + j] = prod
        du = W @ Pi
        e_a = du[0:3]
        e_g = du[3:6]
        # aiding: output injection and learning at the aiding times
        while m < aid_idx.shape[0] and aid_idx[m] <= k:
            h_a = min(max(aid_t[m] - t_last, 0.0), 1.0)
            t_last = aid_t[m]
            if n_sum > 0:
                f_bar = f_sum / n_sum
            innov = aid_val[m] - (p if position else v)
            H = Y[ri : ri + 3, :]  # (3, 24)
            # least squares on the bias weights and the initial state
            Hb = np.empty((3, n_ls))
            for j in range(n_ls):
                Hb[:, j] = H[:, ls_col[j]]
            lam = max(1.0 - h_a / t_forget, 0.5)
            Pb = Pb / lam
            S = Hb @ Pb @ Hb.T
            for i in range(3):
                S[i, i] += meas_var
            if not (np.all(np.isfinite(S)) and np.all(np.isfinite(innov))):
                ea_out[k:] = np.nan  # diverged: the caller reports the first non-finite sample
                P[k:] = np.nan
                return ea_out, eg_out, P, V, Rs, sd_out
            Kb = Pb @ Hb.T @ np.linalg.inv(S)
            dtheta = np.zeros(n_par)
            db = Kb @ innov
            for j in range(n_ls):
                dtheta[ls_col[j]] = db[j]
            Pb = Pb - Kb @ Hb @ Pb
            Pb = 0.5 * (Pb + Pb.T)
            # normalised gradient on the wavelet weights, bounded and leaky
            nrm = 1.0 + np.sum(H * H)
            for o in range(6):
                for c in range(1, 4):
                    col = o * 4 + c
                    hi = H[0, col] * innov[0] + H[1, col] * innov[1] + H[2, col] * innov[2]
                    step = h_a * (eta_w * hi / nrm - leak * W[o, c])
                    step = max(-max_rate * h_a, min(max_rate * h_a, step))
                    dtheta[col] = max(-max_w, min(max_w, W[o, c] + step)) - W[o, c]
            if kind == 2 and n_sum > 1:  # still: the mean rate measures the gyro error directly
                wm = w_sum / n_sum
                for i in range(3):
                    var = max((w_sq[i] - n_sum * wm[i] * wm[i]) / (n_sum - 1), 1e-12) / n_sum
                    o = 3 + i
                    cur = e_g[i] + db[o]
                    s_ = Pb[o, o] + var
                    kk = Pb[:, o] / s_
                    r_ = wm[i] - cur
                    for q in range(n_ls):
                        dtheta[ls_col[q]] += kk[q] * r_
                    Pb = Pb - np.outer(kk, Pb[o, :])
                    db = db + kk * r_
            # state correction: what the new weights explain, then the gain on the rest
            dx = Y @ dtheta
            res = innov - (dx[ri : ri + 3])
            if position:
                l1, l2 = 3 * omega, 3 * omega * omega
                dx[0:3] += l1 * h_a * res
                dx[3:6] += l2 * h_a * res
                a_c = l2 * res
                k_att = omega / 3
            else:
                l1 = 2 * omega
                dx[3:6] += l1 * h_a * res
                a_c = l1 * res
                k_att = omega / 2
            ff = f_bar @ f_bar
            fh2 = f_bar[0] * f_bar[0] + f_bar[1] * f_bar[1]
            # M maps the acceleration correction to the attitude correction (level rows, heading row)
            M = np.zeros((3, 3))
            if ff > 1e-6:
                M[0, 1] = -f_bar[2] / ff
                M[0, 2] = f_bar[1] / ff
                M[1, 0] = f_bar[2] / ff
                M[1, 2] = -f_bar[0] / ff
            M[2, 0] = -f_bar[1] / (fh2 + f_h_reg * f_h_reg)
            M[2, 1] = f_bar[0] / (fh2 + f_h_reg * f_h_reg)
            M = M * (k_att * h_a)
            dx[6:9] += M @ a_c
            p = p + dx[0:3]
            v = v + dx[3:6]
            # the observer's tilt phi is in n (R_true = exp(phi) R); the core's convention is on the
            # right in b: dtheta = R^T phi gives the same attitude
            R = boxplus_attitude(R, R.T @ dx[6:9])
            for o in range(6):
                for c in range(4):
                    W[o, c] += dtheta[o * 4 + c]
            # Y <- (I - K C) Y
            Hc = Y[ri : ri + 3, :].copy()
            if position:
                Y[0:3, :] -= 3 * omega * h_a * Hc
                Y[3:6, :] -= 3 * omega * omega * h_a * Hc
                Y[6:9, :] -= (M * (3 * omega * omega)) @ Hc
            else:
                Y[3:6, :] -= 2 * omega * h_a * Hc
                Y[6:9, :] -= (M * (2 * omega)) @ Hc
            du = W @ Pi
            e_a = du[0:3]
            e_g = du[3:6]
            f_sum[:] = 0.0
            w_sum[:] = 0.0
            w_sq[:] = 0.0
            n_sum = 0
            m += 1
        ea_out[k], eg_out[k] = e_a, e_g
        for o in range(6):
            sd_out[k, o] = np.sqrt(max(Pb[o, o], 0.0))
        P[k], V[k], Rs[k] = p, v, R
        if k + 1 == n:
            break
        # strapdown of the corrected sensor (trapezoidal, as ins/strapdown.py)
        h = t[k + 1] - t[k]
        pn, vn, Rn, a0 = strapdown_step(p, v, R, accel[k] - e_a, accel[k + 1] - e_a, gyro[k] - e_g,
                                        gyro[k + 1] - e_g, h, g_n, no_earth_rate)  # fmt: skip
        p = pn
        # sensitivity: Y' = A(t) Y + Psi(t), A with the block-mean specific force
        for c in range(n_par):
            o = c // 4
            pc = Pi[c % 4] if c < 24 else 0.0
            for i in range(3):
                Y[i, c] += h * Y[3 + i, c]
            ph0, ph1, ph2 = Y[6, c], Y[7, c], Y[8, c]
            Y[3, c] += h * (ph1 * f_bar[2] - ph2 * f_bar[1])
            Y[4, c] += h * (ph2 * f_bar[0] - ph0 * f_bar[2])
            Y[5, c] += h * (ph0 * f_bar[1] - ph1 * f_bar[0])
            if c >= 24:  # the initial-state columns only follow the dynamics
                continue
            if o < 3:  # Y = d x / d W: an accelerometer weight drives v' by -R e_o Pi_c
                for i in range(3):
                    Y[3 + i, c] -= h * R[i, o] * pc
            else:  # a gyro weight turns the attitude by -R e_o Pi_c
                for i in range(3):
                    Y[6 + i, c] -= h * R[i, o - 3] * pc
        v, R = vn, Rn
        f_sum += a0
        for i in range(3):
            w_sum[i] += gyro[k, i]
            w_sq[i] += gyro[k, i] * gyro[k, i]
        n_sum += 1
    return ea_out, eg_out, P, V, Rs, sd_out


@dataclass
class RwnnResult:
    """Accelerometer and gyro error estimates (N, 3) (body frame, measured = true + error), the
    least-squares 1-sigma of their constant part (N, 3) each, and the observer's p, v (N, 3), R_n_b
    (N, 3, 3)."""

    accel_error: FloatArray
    gyro_error: FloatArray
    accel_error_std: FloatArray
    gyro_error_std: FloatArray
    p_n: FloatArray
    v_n: FloatArray
    R_n_b: FloatArray


def run_rwnn(
    t_s: FloatArray,
    accel: FloatArray,
    gyro: FloatArray,
    aid_t: FloatArray,
    aid_values: FloatArray,
    aid_kind: str,
    p0: FloatArray,
    v0: FloatArray,
    R0: FloatArray,
    g: float = 9.80665,
    config: RwnnConfig | None = None,
    aid_std: float = 0.01,
    accel_noise: float = 0.0,
) -> RwnnResult:
    """Run the RWNN observer over a log (SI, body frame) with position, velocity or zupt aiding of
    1-sigma ``aid_std`` (m or m/s); ``accel_noise`` is the accelerometer's white noise density
    (m/s^2/sqrt(Hz)) for the learning's measurement variance (:func:`innovation_variance`)."""
    kinds = {"position": 0, "velocity": 1, "zupt": 2}
    if aid_kind not in kinds:
        raise InputError(f"aiding kind '{aid_kind}'; expected position, velocity or zupt")
    if not (np.isfinite(aid_std) and aid_std > 0):
        raise InputError(f"aiding 1-sigma must be positive, got {aid_std}")
    if not (np.isfinite(accel_noise) and accel_noise >= 0):
        raise InputError(f"accelerometer noise density must be >= 0, got {accel_noise}")
    c = config or RwnnConfig()
    gains = np.array([c.omega, c.f_h_reg, c.accel_error_std, c.gyro_error_std, c.forgetting_s, c.eta_wavelet,
                      c.leakage, c.max_rate, c.max_weight, c.recurrence, c.attitude_std, c.velocity_std])  # fmt: skip
    t = np.asarray(t_s, float)
    at = np.asarray(aid_t, float)
    idx = np.searchsorted(t, at).astype(np.int64)
    ok = idx < len(t)
    vals = np.ascontiguousarray(aid_values, float)[ok]
    if aid_kind == "zupt":
        vals = np.zeros_like(vals)
    h_a = float(np.median(np.diff(at))) if len(at) > 1 else 0.1
    var = innovation_variance(c.omega, aid_kind == "position", aid_std, accel_noise, h_a)
    ea, eg, P, V, R, sd = _rwnn_observer(
        t, np.ascontiguousarray(accel, float), np.ascontiguousarray(gyro, float), idx[ok], at[ok], vals,
        var, kinds[aid_kind], np.asarray(p0, float), np.asarray(v0, float),
        np.ascontiguousarray(R0, float), g, gains,
    )  # fmt: skip
    bad = ~(np.isfinite(ea).all(axis=1) & np.isfinite(eg).all(axis=1) & np.isfinite(P).all(axis=1)
            & np.isfinite(R).all(axis=(1, 2)))  # fmt: skip
    if bad.any():
        from imuslam.ins.kf import FilterDivergence

        k = int(np.argmax(bad))
        raise FilterDivergence(
            f"RWNN observer diverged at sample {k} (t = {t[k]:.3f} s): state not finite; check the log "
            "there (a NaN, a saturated sample) and the aiding"
        )
    return RwnnResult(ea, eg, sd[:, 0:3], sd[:, 3:6], P, V, R)
