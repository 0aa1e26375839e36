"""Alignment by an observer with a recurrent wavelet neural network (RWNN) estimating the IMU's error
(seed 001, module 1; MISSION.md part B.1).

Observer (second order on position, fed by velocity or position aiding y):

    x = [p, v] in n,   x' = A x + B (u + du) + L (y - C x)
    A = [[0, I], [0, 0]],  B = [0, I]^T,  u = R_n_b (f_b - e_a) + g_n

with C = [I, 0] (position aiding) or [0, I] (velocity aiding). L = [2 zeta w I, w^2 I]^T for position
aiding puts both eigenvalues of A - L C at -zeta w +- i w sqrt(1 - zeta^2) (Hurwitz for zeta, w > 0); for
velocity aiding L = [0, k I]^T with eigenvalue -k.

RWNN (choices the seed leaves open are stated here):
- inputs, each normalised to [0, 1] by fixed ranges: the velocity innovation (3, +-1 m/s) and the specific
  force and rate (6, +-2 g and +-5 rad/s);
- recurrent wavelet layer: each input i through 3 Mexican-hat wavelets
  sigma(mu) = (1 - mu^2) exp(-mu^2 / 2), scaled and shifted sigma_{d,t}(mu) = 2^(d/2) sigma(2^d mu - t)
  with d = 0, 1, 2 and t = 0, 0.5, 1, whose input is mu = z_i + r * phi_prev (memory of the previous step,
  r = 0.2);
- product layer: node j multiplies the j-th wavelet of every input, Pi_j = prod_i phi_ij (3 nodes);
- output layer: a weighted sum of [1, Pi_1, Pi_2, Pi_3] per output, giving the body-frame accelerometer
  error e_a (3) and gyro error e_g (3) (the "du" of the seed, applied to the sensor before the strapdown).
- online learning of the output weights by the gradient of the squared innovation through the observer:
  the accelerometer channel moves along -R^T (innovation), the gyro channel along the tilt that the
  innovation implies, -R^T (g_up x innovation) / |g|; rates are bounded (clipped) and weights are
  projected onto a ball; a small leakage (e-modification) keeps them bounded without persistent excitation.
The wavelet parameters are fixed: only the output layer learns, which makes the law linear in the
learned parameters (an adaptive observer) and keeps it stable with bounded rates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, Field

from imuslam.ins.strapdown import _exp3

FloatArray = NDArray[np.float64]


class RwnnConfig(BaseModel):
    """Gains of the RWNN observer."""

    omega: float = Field(
        1.0, gt=0, description="observer natural frequency (position aiding), rad/s"
    )
    zeta: float = Field(0.9, gt=0, description="observer damping (position aiding)")
    k_vel: float = Field(2.0, gt=0, description="observer gain (velocity aiding), 1/s")
    k_tilt: float = Field(
        0.2, ge=0, description="attitude correction from the innovation, rad/s per m/s"
    )
    eta_accel: float = Field(0.2, gt=0, description="learning rate of the accelerometer error")
    eta_gyro: float = Field(0.01, gt=0, description="learning rate of the gyro error")
    leakage: float = Field(1e-4, ge=0, description="e-modification leakage, 1/s")
    max_rate: float = Field(0.5, gt=0, description="bound on any weight's rate of change, 1/s")
    max_weight: float = Field(5.0, gt=0, description="bound on any weight's magnitude")
    recurrence: float = Field(
        0.2, ge=0, lt=1, description="memory gain of the recurrent wavelet layer"
    )


@numba.njit(cache=True, inline="always")
def _mexican_hat(mu: float) -> float:  # pragma: no cover - compiled
    return (1.0 - mu * mu) * np.exp(-0.5 * mu * mu)


@numba.njit(cache=True)
def _rwnn_observer(
    t: FloatArray,
    accel: FloatArray,
    gyro: FloatArray,
    aid_idx: NDArray[np.int64],
    aid_val: FloatArray,
    aid_pos: bool,
    p0: FloatArray,
    v0: FloatArray,
    R0: FloatArray,
    g: float,
    gains: FloatArray,
) -> tuple[
    FloatArray, FloatArray, FloatArray, FloatArray, FloatArray
]:  # pragma: no cover - compiled
    """Run the observer over the log. Returns accel error (N, 3), gyro error (N, 3), p (N, 3), v (N, 3),
    R (N, 3, 3). ``aid_idx`` (M,) sample index of each aiding value ``aid_val`` (M, 3)."""
    omega, zeta, kv, ktilt, eta_a, eta_g, leak, max_rate, max_w, rec = (
        gains[0],
        gains[1],
        gains[2],
        gains[3],
        gains[4],
        gains[5],
        gains[6],
        gains[7],
        gains[8],
        gains[9],
    )
    n = t.shape[0]
    n_in = 9
    d = np.array([0.0, 1.0, 2.0])
    sh = np.array([0.0, 0.5, 1.0])
    scale_in = np.array([1.0, 1.0, 1.0, 2 * 9.81, 2 * 9.81, 2 * 9.81, 5.0, 5.0, 5.0])
    phi_prev = np.zeros((n_in, 3))
    W = np.zeros((6, 4))  # outputs x [bias, Pi_1, Pi_2, Pi_3]
    p = p0.copy()
    v = v0.copy()
    R = R0.copy()
    g_n = np.array([0.0, 0.0, -g])
    up = np.array([0.0, 0.0, 1.0])
    ea_out = np.zeros((n, 3))
    eg_out = np.zeros((n, 3))
    P = np.zeros((n, 3))
    V = np.zeros((n, 3))
    Rs = np.zeros((n, 3, 3))
    innov = np.zeros(3)
    m = 0
    for k in range(n):
        # aiding innovation (held between aiding samples)
        while m < aid_idx.shape[0] and aid_idx[m] <= k:
            innov = aid_val[m] - (p if aid_pos else v)
            if aid_pos:
                p += (
                    2
                    * zeta
                    * omega
                    * innov
                    * (t[min(k + 1, n - 1)] - t[k] if k + 1 < n else 0.0)
                    * 0.0
                )
            m += 1
        # network forward pass
        z = np.empty(n_in)
        for i in range(3):
            z[i] = 0.5 + 0.5 * max(-1.0, min(1.0, innov[i] / scale_in[i]))
        for i in range(3):
            z[3 + i] = 0.5 + 0.5 * max(-1.0, min(1.0, accel[k, i] / scale_in[3 + i]))
            z[6 + i] = 0.5 + 0.5 * max(-1.0, min(1.0, gyro[k, i] / scale_in[6 + i]))
        Pi = np.ones(4)
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
        ea_out[k], eg_out[k] = e_a, e_g
        P[k], V[k], Rs[k] = p, v, R
        if k + 1 == n:
            break
        h = t[k + 1] - t[k]
        # observer step: corrected sensor, strapdown, output injection
        tilt = np.cross(up, innov)  # innovation implies a tilt about this nav axis
        w_c = gyro[k] - e_g + ktilt * (R.T @ tilt)
        R = R @ _exp3(w_c[0] * h, w_c[1] * h, w_c[2] * h)
        a_n = R @ (accel[k] - e_a) + g_n
        if aid_pos:
            p = p + h * (v + 2 * zeta * omega * innov)
            v = v + h * (a_n + omega * omega * innov)
        else:
            p = p + h * v
            v = v + h * (a_n + kv * innov)
        # learning: bounded gradient steps on the output weights, with leakage
        ga = -(R.T @ innov)
        gg = -(R.T @ tilt) / g
        for o in range(6):
            grad = ga[o] if o < 3 else gg[o - 3]
            eta = eta_a if o < 3 else eta_g
            for c in range(4):
                rate = eta * grad * Pi[c] - leak * W[o, c]
                rate = max(-max_rate, min(max_rate, rate))
                W[o, c] = max(-max_w, min(max_w, W[o, c] + h * rate))
    return ea_out, eg_out, P, V, Rs


@dataclass
class RwnnResult:
    """Accelerometer and gyro error estimates (N, 3) (body frame, measured = true + error), and the
    observer's p, v (N, 3), R_n_b (N, 3, 3)."""

    accel_error: FloatArray
    gyro_error: FloatArray
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
) -> RwnnResult:
    """Run the RWNN observer over a log (SI, body frame) with position or velocity aiding."""
    c = config or RwnnConfig()
    gains = np.array([c.omega, c.zeta, c.k_vel, c.k_tilt, c.eta_accel, c.eta_gyro, c.leakage, c.max_rate,
                      c.max_weight, c.recurrence])  # fmt: skip
    idx = np.searchsorted(t_s, aid_t).astype(np.int64)
    ok = idx < len(t_s)
    ea, eg, P, V, R = _rwnn_observer(
        np.asarray(t_s, float), np.ascontiguousarray(accel, float), np.ascontiguousarray(gyro, float), idx[ok],
        np.ascontiguousarray(aid_values[ok], float), aid_kind == "position", np.asarray(p0, float),
        np.asarray(v0, float), np.ascontiguousarray(R0, float), g, gains,
    )  # fmt: skip
    return RwnnResult(ea, eg, P, V, R)
