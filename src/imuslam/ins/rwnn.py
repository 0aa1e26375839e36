"""Alignment by an observer with a recurrent wavelet neural network (RWNN) estimating the IMU's error
(seed 001, module 1; MISSION.md part B.1).

The seed's observer is x' = A x + B (u + du) + L (y - C x) with L such that A - L C is Hurwitz and du the
RWNN's estimate of the IMU's error. Here x = [p, v] in n, u = R_n_b f_b + g_n, and the network outputs the
body-frame errors e_a, e_g (measured = true + error) that correct the sensor before the strapdown, so
du = -R_n_b e_a (and the attitude integrates omega - e_g).

Network (seed 001 fig. 2 and eqs. 2-8; the choices the seed leaves open are stated here):
- input layer: the normalised state estimate and sensor output, mu_i in [0, 1] by fixed ranges: the
  velocity estimate v_n (3, +-5 m/s), the specific force f_b (3, +-2 g) and the rate omega_b (3, +-5 rad/s);
- recurrent wavelet layer: each input i through 3 Mexican-hat wavelets j,
  phi_ij = 2^(d_ij/2) sigma(2^d_ij s_ij - t_ij), sigma(x) = (1 - x^2) exp(-x^2 / 2), whose argument carries
  the memory of the previous step, s_ij = mu_i + r_ij phi_ij(k-1); the dilations d_ij, translations t_ij
  and recurrent weights r_ij (27 each) are learned; they start at d = 0, t = (0, 0.5, 1), r = 0.1 so that
  the three wavelets of an input peak at the two ends and the middle of its range;
- product layer: node j multiplies the j-th wavelet of every input, Pi_j = prod_i phi_ij (3 nodes);
- output layer: per output (e_a, e_g: 6) a weighted sum of [1, Pi_1, Pi_2, Pi_3], e = W Pi; the weight of
  the constant input is the bias.

Learning. The output is linear in the weights W, so the observer is an adaptive observer for a linear
time-varying system (Q. Zhang, "Adaptive observer for multiple-input-multiple-output (MIMO) linear
time-varying systems", IEEE TAC 47(3), 2002). Its error dynamics, with the attitude error phi in n
(R_true = exp(phi) R), are

    dp' = dv,   dv' = -[f_n x] phi - R (e_a,true - e_a),   phi' = -R (e_g,true - e_g)

(Savage; Sola 2017 eq. 262 ff. in the navigation frame). The sensitivity Y = d x / d W obeys
Y' = (A(t) - K C) Y + Psi(t) with the regressor Psi = [0; -R (x) Pi^T; -R (x) Pi^T]; the innovation is
e = C Y (W_true - W) + (a decaying state error). All 24 output weights and the initial attitude and
velocity errors (nuisance parameters, so that an initial error is not taken for a bias) learn by recursive
least squares on this regression, i.e. a Kalman filter on the weights (the classic way to train a recurrent
network's output layer: Puskorius and Feldkamp, IEEE TNN 5(2), 1994), with a forgetting factor on all of
them (memory ``forgetting_s``) and a random walk on the node weights (``net_accel_walk``,
``net_gyro_walk`` per sqrt(s)): the bias weights hold what stays constant, the node weights follow what
varies, with time (a bias step or drift) or with the inputs (a rate-dependent scale error). The node
weights are projected onto |W| <= ``max_weight_accel`` / ``max_weight_gyro``. The wavelet parameters
(d, t, r) learn by a normalised gradient of the innovation, their sensitivity columns of Y driven by
dPi_j / d theta (real-time recurrent learning through the memory term, Williams and Zipser 1989), each
step bounded by ``max_hidden_rate``, d in [-2, 2], t in [-1, 2] and |r| small enough that the memory is a
contraction. Because Y carries the phase of the dynamics, biases modulated by a rotating platform are
demodulated correctly, which a gradient of the raw innovation is not. On a still base (``zupt`` aiding)
the mean rate is also a direct measurement of the gyro error, as the Kalman filter's ZARU.
``network=False`` keeps only the bias weights (the node weights stay 0): the same observer without the
network, for comparison.

Gain K (applied at the aiding times, the discrete form of L): position aiding, per axis dp += 3 w h e,
dv += 3 w^2 h e; velocity aiding dv += 2 w h e; and the attitude is turned by k_att h f_n x a_c / |f_n|^2 with
a_c the acceleration correction (3 w^2 e or 2 w e), heading from the horizontal specific force only,
regularised by ``f_h_reg``. With k_att = w / 3 the level channel has all three roots at -w
(:func:`observer_matrix`). The kernel takes these gains from :func:`observer_gains`, so the matrix tested
for Hurwitz is the one the kernel applies.

The compiled observer (:func:`rwnn_kernel`) reads its settings as a named record (:class:`RwnnSettings`)
and runs named steps per sample: the network's forward pass, at each aiding the least-squares learning of
the output weights (with the zero-rate update on a still base), the wavelets' gradient step and the state
correction, then the strapdown and the sensitivity's propagation.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, Field

from imuslam.ins.aiding import AidingKind
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
    network: bool = Field(
        True, description="learn the wavelet nodes (False: the bias weights only, for comparison)"
    )
    net_accel_std: float = Field(
        0.02, ge=0, description="prior 1-sigma of an accelerometer node weight, m/s^2"
    )
    net_gyro_std: float = Field(
        0.002, ge=0, description="prior 1-sigma of a gyro node weight, rad/s"
    )
    net_accel_walk: float = Field(
        0.002, ge=0, description="random walk of an accelerometer node weight, m/s^2/sqrt(s)"
    )
    net_gyro_walk: float = Field(
        1e-4, ge=0, description="random walk of a gyro node weight, rad/s/sqrt(s)"
    )
    max_weight_accel: float = Field(
        1.0, gt=0, description="bound on an accelerometer node weight's magnitude, m/s^2"
    )
    max_weight_gyro: float = Field(
        0.1, gt=0, description="bound on a gyro node weight's magnitude, rad/s"
    )
    eta_hidden: float = Field(
        0.5, ge=0, description="learning rate of the wavelet dilations, translations, recurrences"
    )
    max_hidden_rate: float = Field(
        0.2, gt=0, description="bound on a wavelet parameter's change per second"
    )


@numba.njit(cache=True)
def observer_gains(omega: float, position: bool) -> tuple[float, float, float]:  # pragma: no cover
    """The gains the kernel applies per aiding: (l_p, l_v, k_att). The position (velocity) correction is
    l_p h e (l_v h e) for an innovation e, the acceleration correction a_c = l_v e turns the attitude by
    k_att h f_n x a_c / |f_n|^2. Position aiding: l_p = 3 w, l_v = 3 w^2, k_att = w / 3; velocity aiding:
    l_p = 0, l_v = 2 w, k_att = w / 2."""
    if position:
        return 3.0 * omega, 3.0 * omega * omega, omega / 3.0
    return 0.0, 2.0 * omega, omega / 2.0


def observer_matrix(omega: float, position: bool) -> FloatArray:
    """A - K C of one level axis built from :func:`observer_gains` (the kernel's gains), x = [p, v, tilt * g]
    (position aiding) or [v, tilt * g]; with these gains every eigenvalue is at -omega."""
    l_p, l_v, k = observer_gains(omega, position)
    if position:
        return np.array([[-l_p, 1.0, 0.0], [-l_v, 0.0, -1.0], [k * l_v, 0.0, 0.0]])
    return np.array([[-l_v, -1.0], [k * l_v, 0.0]])


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
def _mexican_hat(x: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """sigma(x) = (1 - x^2) exp(-x^2 / 2) and its derivative x (x^2 - 3) exp(-x^2 / 2)."""
    e = np.exp(-0.5 * x * x)
    return (1.0 - x * x) * e, x * (x * x - 3.0) * e


class RwnnSettings(NamedTuple):
    """The observer's settings as the compiled kernel reads them (a named record, built from
    :class:`RwnnConfig` by :meth:`from_config`; the fields' meaning is the config's)."""

    omega: float
    f_h_reg: float
    accel_error_std: float
    gyro_error_std: float
    forgetting_s: float
    network: bool
    net_accel_std: float
    net_gyro_std: float
    net_accel_walk: float
    net_gyro_walk: float
    max_weight_accel: float
    max_weight_gyro: float
    eta_hidden: float
    max_hidden_rate: float
    attitude_std: float
    velocity_std: float

    @classmethod
    def from_config(cls, c: RwnnConfig) -> RwnnSettings:
        return cls(float(c.omega), float(c.f_h_reg), float(c.accel_error_std), float(c.gyro_error_std),
                   float(c.forgetting_s), bool(c.network), float(c.net_accel_std), float(c.net_gyro_std),
                   float(c.net_accel_walk), float(c.net_gyro_walk), float(c.max_weight_accel),
                   float(c.max_weight_gyro), float(c.eta_hidden), float(c.max_hidden_rate),
                   float(c.attitude_std), float(c.velocity_std))  # fmt: skip


N_IN = 9  # network inputs: v_n (3), f_b (3), omega_b (3)
N_LIN = 30  # 24 output weights (6 outputs x [1, Pi_1, Pi_2, Pi_3]) + initial attitude and velocity errors
N_HID = N_IN * 3 * 3  # d, t, r of each (input, node)
MAX_SIGMA_SLOPE = 1.38  # max |sigma'(x)| of the Mexican hat (at |x| = 0.74)


@numba.njit(cache=True)
def _initial_learning(
    s: RwnnSettings,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:  # pragma: no cover - compiled
    """The learning's start: wavelet parameters th (9, 3, 3: d, t, r), the least-squares covariance Pb
    (30, 30) of the 24 output weights and the initial attitude and velocity errors, the node weights'
    random walk q_node (30,) and the sensitivity Y (9, n_par) of [dp, dv, phi] to the parameters."""
    th = np.zeros((N_IN, 3, 3))
    for i in range(N_IN):
        for j in range(3):
            th[i, j, 1] = 0.5 * j
            th[i, j, 2] = 0.1
    sa0, sg0, sna, sng = s.accel_error_std, s.gyro_error_std, s.net_accel_std, s.net_gyro_std
    qa, qg = s.net_accel_walk, s.net_gyro_walk
    Pb = np.zeros((N_LIN, N_LIN))
    q_node = np.zeros(N_LIN)
    for o in range(6):
        Pb[o * 4, o * 4] = sa0 * sa0 if o < 3 else sg0 * sg0
        if s.network:
            for c in range(1, 4):
                Pb[o * 4 + c, o * 4 + c] = sna * sna if o < 3 else sng * sng
                q_node[o * 4 + c] = qa * qa if o < 3 else qg * qg
    for i in range(3):
        Pb[24 + i, 24 + i] = s.attitude_std * s.attitude_std
        Pb[27 + i, 27 + i] = s.velocity_std * s.velocity_std
    Y = np.zeros((9, N_LIN + N_HID))
    for i in range(3):
        Y[6 + i, 24 + i] = 1.0
        Y[3 + i, 27 + i] = 1.0
    return th, Pb, q_node, Y


@numba.njit(cache=True)
def _network_forward(
    z: FloatArray,
    th: FloatArray,
    phi_prev: FloatArray,
    dphi_prev: FloatArray,
    phi: FloatArray,
    dphi: FloatArray,
    gpi: FloatArray,
    Pi: FloatArray,
    pre: FloatArray,
    suf: FloatArray,
) -> None:  # pragma: no cover - compiled
    """The network's forward pass on the normalised inputs z (9,): the wavelets phi (9, 3) with their
    derivatives dphi (9, 3, 3) through the memory (RTRL), the product nodes Pi[1:] and d Pi_j / d theta_ij
    gpi (9, 3, 3); the memory phi_prev, dphi_prev moves on. Every array is written in place."""
    ln2 = np.log(2.0)
    for i in range(N_IN):
        for j in range(3):
            d_, t_, r_ = th[i, j, 0], th[i, j, 1], th[i, j, 2]
            sc = 2.0**d_
            amp = 2.0 ** (0.5 * d_)
            s_in = z[i] + r_ * phi_prev[i, j]
            sg, dsg = _mexican_hat(sc * s_in - t_)
            ph = amp * sg
            sl = amp * dsg  # d phi / d (argument)
            dphi[i, j, 0] = 0.5 * ln2 * ph + sl * (ln2 * sc * s_in + sc * r_ * dphi_prev[i, j, 0])
            dphi[i, j, 1] = sl * (-1.0 + sc * r_ * dphi_prev[i, j, 1])
            dphi[i, j, 2] = sl * sc * (phi_prev[i, j] + r_ * dphi_prev[i, j, 2])
            phi[i, j] = ph
    for j in range(3):
        pre[0] = 1.0
        for i in range(N_IN):
            pre[i + 1] = pre[i] * phi[i, j]
        suf[N_IN] = 1.0
        for i in range(N_IN - 1, -1, -1):
            suf[i] = suf[i + 1] * phi[i, j]
        Pi[1 + j] = pre[N_IN]
        for i in range(N_IN):
            ex = pre[i] * suf[i + 1]  # product of the other inputs' wavelets
            for q in range(3):
                gpi[i, j, q] = ex * dphi[i, j, q]
    phi_prev[:, :] = phi
    dphi_prev[:, :, :] = dphi


@numba.njit(cache=True)
def _learn_output_weights(
    Pb: FloatArray,
    q_node: FloatArray,
    Hb: FloatArray,
    innov: FloatArray,
    meas_var: float,
    h_a: float,
    t_forget: float,
) -> tuple[bool, FloatArray, FloatArray, FloatArray]:  # pragma: no cover - compiled
    """Recursive least squares of the output weights and initial errors on one innovation (3,), with
    forgetting and the node weights' random walk over h_a s. Returns (finite, Pb, S^-1, dtheta (n_par,));
    on a non-finite innovation covariance, (False, Pb, S, zeros)."""
    lam = max(1.0 - h_a / t_forget, 0.5)
    Pb = Pb / lam
    for c in range(N_LIN):
        Pb[c, c] += q_node[c] * h_a
    S = Hb @ Pb @ Hb.T
    for i in range(3):
        S[i, i] += meas_var
    dtheta = np.zeros(N_LIN + N_HID)
    if not (np.all(np.isfinite(S)) and np.all(np.isfinite(innov))):
        return False, Pb, np.asfortranarray(S), dtheta  # the layout of inv's result: one type
    Si = np.linalg.inv(S)
    Kb = Pb @ Hb.T @ Si
    dtheta[:N_LIN] = Kb @ innov
    Pb = Pb - Kb @ Hb @ Pb
    Pb = 0.5 * (Pb + Pb.T)
    return True, Pb, Si, dtheta  # type: ignore[return-value]  # inv: float64 here


@numba.njit(cache=True)
def _zero_rate_update(
    Pb: FloatArray,
    dtheta: FloatArray,
    W: FloatArray,
    Pi: FloatArray,
    w_sum: FloatArray,
    w_sq: FloatArray,
    n_sum: int,
) -> FloatArray:  # pragma: no cover - compiled
    """Still: the mean rate of the block measures the gyro error directly (one scalar update per axis,
    its variance that of the block's mean). Updates dtheta in place, returns Pb."""
    wm = w_sum / n_sum
    for i in range(3):
        var = max((w_sq[i] - n_sum * wm[i] * wm[i]) / (n_sum - 1), 1e-12) / n_sum
        o = 3 + i
        hrow = np.zeros(N_LIN)
        cur = 0.0
        for c in range(4):
            hrow[o * 4 + c] = Pi[c]
            cur += (W[o, c] + dtheta[o * 4 + c]) * Pi[c]
        ph_ = Pb @ hrow
        kk = ph_ / (hrow @ ph_ + var)
        dtheta[:N_LIN] += kk * (wm[i] - cur)
        Pb = Pb - np.outer(kk, ph_)
    return Pb


@numba.njit(cache=True)
def _learn_wavelets(
    H: FloatArray,
    Si: FloatArray,
    innov: FloatArray,
    dtheta: FloatArray,
    th: FloatArray,
    eta_h: float,
    max_hr: float,
    h_a: float,
) -> None:  # pragma: no cover - compiled
    """The wavelet parameters' step: a normalised gradient of the innovation through their
    sensitivities, bounded per second and to the box that keeps the memory a contraction. Updates
    dtheta and th in place."""
    n_par = N_LIN + N_HID
    Sin = Si @ innov
    for c in range(N_LIN, n_par):
        hc0, hc1, hc2 = H[0, c], H[1, c], H[2, c]
        grad = hc0 * Sin[0] + hc1 * Sin[1] + hc2 * Sin[2]
        hsh = 0.0
        for a_ in range(3):
            hsh += H[a_, c] * (Si[a_, 0] * hc0 + Si[a_, 1] * hc1 + Si[a_, 2] * hc2)
        step = eta_h * h_a * grad / (1.0 + hsh)
        dtheta[c] = max(-max_hr * h_a, min(max_hr * h_a, step))
    for i in range(N_IN):
        for j in range(3):
            c = N_LIN + (i * 3 + j) * 3
            d_new = max(-2.0, min(2.0, th[i, j, 0] + dtheta[c]))
            t_new = max(-1.0, min(2.0, th[i, j, 1] + dtheta[c + 1]))
            # |r| 2^(3d/2) max|sigma'| < 0.9: the memory is a contraction
            r_max = 0.9 / (MAX_SIGMA_SLOPE * 2.0 ** (1.5 * d_new))
            r_new = max(-r_max, min(r_max, th[i, j, 2] + dtheta[c + 2]))
            dtheta[c] = d_new - th[i, j, 0]
            dtheta[c + 1] = t_new - th[i, j, 1]
            dtheta[c + 2] = r_new - th[i, j, 2]
            th[i, j, 0], th[i, j, 1], th[i, j, 2] = d_new, t_new, r_new


@numba.njit(cache=True)
def _correct_state(
    Y: FloatArray,
    dtheta: FloatArray,
    innov: FloatArray,
    ri: int,
    gains: tuple[float, float, float],
    h_a: float,
    f_bar: FloatArray,
    f_h_reg: float,
    p: FloatArray,
    v: FloatArray,
    R: FloatArray,
    W: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray]:  # pragma: no cover - compiled
    """The state correction: what the new parameters explain, then the observer's gain on the rest;
    the output weights W take their step and the sensitivity Y becomes (I - K C) Y (both in place).
    Returns the corrected p, v, R."""
    l_p, l_v, k_att = gains
    dx = Y @ dtheta
    res = innov - (dx[ri : ri + 3])
    dx[0:3] += l_p * h_a * res
    dx[3:6] += l_v * h_a * res
    a_c = l_v * res
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
    Y[0:3, :] -= l_p * h_a * Hc
    Y[3:6, :] -= l_v * h_a * Hc
    Y[6:9, :] -= (M * l_v) @ Hc
    return p, v, R


@numba.njit(cache=True)
def _propagate_sensitivity(
    Y: FloatArray,
    h: float,
    f_bar: FloatArray,
    R: FloatArray,
    W: FloatArray,
    Pi: FloatArray,
    gpi: FloatArray,
    network: bool,
) -> None:  # pragma: no cover - compiled
    """One step of Y' = A(t) Y + Psi(t), A with the block-mean specific force (Y in place)."""
    n_par = N_LIN + N_HID
    RW = np.zeros((3, 6))  # R times the node weights' columns: accel (0-2) and gyro (3-5) per node
    if network:
        for j in range(3):
            for i in range(3):
                sa_ = 0.0
                sg_ = 0.0
                for o in range(3):
                    sa_ += R[i, o] * W[o, 1 + j]
                    sg_ += R[i, o] * W[3 + o, 1 + j]
                RW[i, j] = sa_
                RW[i, 3 + j] = sg_
    for c in range(n_par):
        if c >= N_LIN and not network:
            break
        for i in range(3):
            Y[i, c] += h * Y[3 + i, c]
        ph0, ph1, ph2 = Y[6, c], Y[7, c], Y[8, c]
        Y[3, c] += h * (ph1 * f_bar[2] - ph2 * f_bar[1])
        Y[4, c] += h * (ph2 * f_bar[0] - ph0 * f_bar[2])
        Y[5, c] += h * (ph0 * f_bar[1] - ph1 * f_bar[0])
        if c < 24:
            # Y = d x / d W: an accelerometer weight drives v' by -R e_o Pi_c, a gyro weight turns the
            # attitude by -R e_o Pi_c
            o = c // 4
            pc = Pi[c % 4]
            if o < 3:
                for i in range(3):
                    Y[3 + i, c] -= h * R[i, o] * pc
            else:
                for i in range(3):
                    Y[6 + i, c] -= h * R[i, o - 3] * pc
        elif c >= N_LIN:
            # a wavelet parameter of (input i, node j) moves every output of node j by W[:, j] dPi_j
            q_ = c - N_LIN
            i_, j_ = q_ // 9, (q_ // 3) % 3
            gp = gpi[i_, j_, q_ % 3]
            for i in range(3):
                Y[3 + i, c] -= h * RW[i, j_] * gp
                Y[6 + i, c] -= h * RW[i, 3 + j_] * gp
        # c in 24..29: the initial-state columns only follow the dynamics


@numba.njit(cache=True)
def _error_std(Pb: FloatArray, Pi: FloatArray, out: FloatArray) -> None:  # pragma: no cover
    """1-sigma (6,) of the error estimates W Pi from the least-squares covariance Pb (into out)."""
    for o in range(6):
        var_o = 0.0
        for c in range(4):
            for c2 in range(4):
                var_o += Pi[c] * Pb[o * 4 + c, o * 4 + c2] * Pi[c2]
        out[o] = np.sqrt(max(var_o, 0.0))


@numba.njit(cache=True)
def rwnn_kernel(
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
    s: RwnnSettings,
) -> tuple[
    FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray
]:  # pragma: no cover - compiled
    """The compiled observer of :func:`run_rwnn` over the log, positional arrays in and out. ``kind``
    0 position, 1 velocity, 2 zupt (zero velocity and rate). Returns accel error (N, 3), gyro error
    (N, 3), p (N, 3), v (N, 3), R (N, 3, 3), the 1-sigma of the error estimates (N, 6) from the
    least-squares covariance, the network's part of the error (N, 6) and the final wavelet parameters
    (9, 3, 3: d, t, r)."""
    position = kind == 0
    gains = observer_gains(s.omega, position)
    n = t.shape[0]
    scale_in = np.array([5.0, 5.0, 5.0, 2 * 9.81, 2 * 9.81, 2 * 9.81, 5.0, 5.0, 5.0])
    th, Pb, q_node, Y = _initial_learning(s)
    phi_prev, dphi_prev = np.zeros((N_IN, 3)), np.zeros((N_IN, 3, 3))
    phi, dphi = np.zeros((N_IN, 3)), np.zeros((N_IN, 3, 3))
    gpi = np.zeros((N_IN, 3, 3))  # d Pi_j / d theta_ij
    W = np.zeros((6, 4))
    p, v, R = p0.copy(), v0.copy(), R0.copy()
    g_n = np.array([0.0, 0.0, -g])
    no_earth_rate = np.zeros(3)
    ea_out, eg_out = np.zeros((n, 3)), np.zeros((n, 3))
    sd_out, net_out = np.zeros((n, 6)), np.zeros((n, 6))
    P, V, Rs = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3, 3))
    Pi = np.zeros(4)
    Pi[0] = 1.0
    f_bar = np.array([0.0, 0.0, g])
    f_sum, w_sum, w_sq = np.zeros(3), np.zeros(3), np.zeros(3)
    n_sum = 0
    t_last = t[0]
    m = 0
    ri = 0 if position else 3  # first row of Y the aiding sees: dp or dv
    z = np.empty(N_IN)
    pre, suf = np.empty(N_IN + 1), np.empty(N_IN + 1)
    for k in range(n):
        if s.network:  # forward pass on the normalised state estimate and sensor output
            for i in range(3):
                z[i] = 0.5 + 0.5 * max(-1.0, min(1.0, v[i] / scale_in[i]))
                z[3 + i] = 0.5 + 0.5 * max(-1.0, min(1.0, accel[k, i] / scale_in[3 + i]))
                z[6 + i] = 0.5 + 0.5 * max(-1.0, min(1.0, gyro[k, i] / scale_in[6 + i]))
            _network_forward(z, th, phi_prev, dphi_prev, phi, dphi, gpi, Pi, pre, suf)
        du = W @ Pi
        e_a, e_g = du[0:3], du[3:6]
        # aiding: output injection and learning at the aiding times
        while m < aid_idx.shape[0] and aid_idx[m] <= k:
            h_a = min(max(aid_t[m] - t_last, 0.0), 1.0)
            t_last = aid_t[m]
            if n_sum > 0:
                f_bar = f_sum / n_sum
            innov = aid_val[m] - (p if position else v)
            H = Y[ri : ri + 3, :]  # (3, n_par)
            Hb = np.ascontiguousarray(H[:, :N_LIN])
            ok, Pb, Si, dtheta = _learn_output_weights(
                Pb, q_node, Hb, innov, meas_var, h_a, s.forgetting_s
            )
            if not ok:
                ea_out[k:] = np.nan  # diverged: the caller reports the first non-finite sample
                P[k:] = np.nan
                return ea_out, eg_out, P, V, Rs, sd_out, net_out, th
            if kind == 2 and n_sum > 1:  # still: the mean rate measures the gyro error directly
                Pb = _zero_rate_update(Pb, dtheta, W, Pi, w_sum, w_sq, n_sum)
            # projection of the node weights onto their bounds
            for o in range(6):
                mw = s.max_weight_accel if o < 3 else s.max_weight_gyro
                for c in range(1, 4):
                    col = o * 4 + c
                    dtheta[col] = max(-mw, min(mw, W[o, c] + dtheta[col])) - W[o, c]
            if s.network and s.eta_hidden > 0:
                _learn_wavelets(H, Si, innov, dtheta, th, s.eta_hidden, s.max_hidden_rate, h_a)
            p, v, R = _correct_state(Y, dtheta, innov, ri, gains, h_a, f_bar, s.f_h_reg, p, v, R, W)
            du = W @ Pi
            e_a, e_g = du[0:3], du[3:6]
            f_sum[:] = 0.0
            w_sum[:] = 0.0
            w_sq[:] = 0.0
            n_sum = 0
            m += 1
        ea_out[k], eg_out[k] = e_a, e_g
        _error_std(Pb, Pi, sd_out[k])
        for o in range(6):
            net_out[k, o] = du[o] - W[o, 0]
        P[k], V[k], Rs[k] = p, v, R
        if k + 1 == n:
            break
        # strapdown of the corrected sensor (trapezoidal, as ins/strapdown.py)
        h = t[k + 1] - t[k]
        pn, vn, Rn, a0 = strapdown_step(p, v, R, accel[k] - e_a, accel[k + 1] - e_a, gyro[k] - e_g,
                                        gyro[k + 1] - e_g, h, g_n, no_earth_rate)  # fmt: skip
        p = pn
        _propagate_sensitivity(Y, h, f_bar, R, W, Pi, gpi, s.network)
        v, R = vn, Rn
        f_sum += a0
        for i in range(3):
            w_sum[i] += gyro[k, i]
            w_sq[i] += gyro[k, i] * gyro[k, i]
        n_sum += 1
    return ea_out, eg_out, P, V, Rs, sd_out, net_out, th


@dataclass
class RwnnResult:
    """Accelerometer and gyro error estimates (N, 3) (body frame, measured = true + error), their
    least-squares 1-sigma (N, 3) each, the observer's p, v (N, 3), R_n_b (N, 3, 3), the network's part of
    the error estimates (the node weights' output, N, 3 each; zero with ``network=False``) and the final
    wavelet parameters (9 inputs, 3 nodes, [d, t, r])."""

    accel_error: FloatArray
    gyro_error: FloatArray
    accel_error_std: FloatArray
    gyro_error_std: FloatArray
    p_n: FloatArray
    v_n: FloatArray
    R_n_b: FloatArray
    network_accel: FloatArray
    network_gyro: FloatArray
    wavelet_params: FloatArray


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
    if aid_kind not in tuple(AidingKind):
        raise ValueError(f"aiding kind '{aid_kind}'; expected position, velocity or zupt")
    if not (np.isfinite(aid_std) and aid_std > 0):
        raise ValueError(f"aiding 1-sigma must be positive, got {aid_std}")
    if not (np.isfinite(accel_noise) and accel_noise >= 0):
        raise ValueError(f"accelerometer noise density must be >= 0, got {accel_noise}")
    c = config or RwnnConfig()
    settings = RwnnSettings.from_config(c)
    t = np.asarray(t_s, float)
    at = np.asarray(aid_t, float)
    idx = np.searchsorted(t, at).astype(np.int64)
    ok = idx < len(t)
    vals = np.ascontiguousarray(aid_values, float)[ok]
    if aid_kind == "zupt":
        vals = np.zeros_like(vals)
    h_a = float(np.median(np.diff(at))) if len(at) > 1 else 0.1
    var = innovation_variance(c.omega, aid_kind == "position", aid_std, accel_noise, h_a)
    ea, eg, P, V, R, sd, net, th = rwnn_kernel(
        t, np.ascontiguousarray(accel, float), np.ascontiguousarray(gyro, float), idx[ok], at[ok], vals,
        var, AidingKind(aid_kind).code, np.asarray(p0, float), np.asarray(v0, float),
        np.ascontiguousarray(R0, float), g, settings,
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
    return RwnnResult(ea, eg, sd[:, 0:3], sd[:, 3:6], P, V, R, net[:, 0:3], net[:, 3:6], th)
