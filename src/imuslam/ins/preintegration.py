"""IMU preintegration between keyframes (Forster, Carlone, Dellaert, Scaramuzza, "On-manifold
preintegration for real-time visual-inertial odometry", IEEE T-RO 33(1), 2017), as GTSAM's
``PreintegratedImuMeasurements``: the relative motion (dR, dv, dp) from keyframe i to j in i's body frame,
independent of the state at i, with its covariance and its first-order Jacobians in the biases, so a
factor graph re-uses it when the bias estimate changes.

Per sample k held over dt_k (Forster eqs. 35-37, with a_k, w_k bias-corrected):

    dR_k+1 = dR_k Exp(w_k dt),   dv_k+1 = dv_k + dR_k a_k dt,   dp_k+1 = dp_k + dv_k dt + dR_k a_k dt^2 / 2

Noise propagation (eq. 62 and appendix A) and bias Jacobians (appendix B). Covariance order is GTSAM's,
rotation first: ``[dtheta, dp, dv]`` (9 x 9). Prediction (eq. 44, bias update eq. 48):

    R_j = R_i dR Exp(J_R^bg dbg),   v_j = v_i + g dt_ij + R_i dv',   p_j = p_i + v_i dt_ij + g dt_ij^2 / 2 + R_i dp'
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np
from numpy.typing import NDArray

from imuslam.geometry.so3_nb import exp_nb, hat_nb, right_jacobian_nb
from imuslam.interfaces.nav import ImuBias, NavState

FloatArray = NDArray[np.float64]

__all__ = ["PreintegratedImu"]


@numba.njit(cache=True)
def _preintegrate(
    accel: FloatArray,
    gyro: FloatArray,
    dt: FloatArray,
    ba: FloatArray,
    bg: FloatArray,
    sig2_a: float,
    sig2_g: float,
    dR: FloatArray,
    dv: FloatArray,
    dp: FloatArray,
    C: FloatArray,
    J: FloatArray,
) -> tuple[
    FloatArray, FloatArray, FloatArray, FloatArray, FloatArray
]:  # pragma: no cover - compiled
    """Continue the preintegration over samples (N, 3) held over dt (N,). J (15, 3): rows 0-2 dR/dbg,
    3-5 dv/dba, 6-8 dv/dbg, 9-11 dp/dba, 12-14 dp/dbg. sig2_*: continuous densities squared."""
    for k in range(dt.shape[0]):
        h = dt[k]
        a = accel[k] - ba
        w = gyro[k] - bg
        dRk = exp_nb(w * h)
        Jr = right_jacobian_nb(w * h)
        ah = hat_nb(a)
        Ra = dR @ ah
        # noise: x = [dtheta, dp, dv], A x + B [eta_g, eta_a]
        A = np.eye(9)
        A[0:3, 0:3] = dRk.T
        A[3:6, 0:3] = -0.5 * Ra * h * h
        A[3:6, 6:9] = np.eye(3) * h
        A[6:9, 0:3] = -Ra * h
        B = np.zeros((9, 6))
        B[0:3, 0:3] = Jr * h
        B[3:6, 3:6] = 0.5 * dR * h * h
        B[6:9, 3:6] = dR * h
        Qd = np.zeros((6, 6))
        for i in range(3):
            Qd[i, i] = sig2_g / h
            Qd[3 + i, 3 + i] = sig2_a / h
        C = A @ C @ A.T + B @ Qd @ B.T
        # bias Jacobians (position first: it uses the velocity ones before this step)
        dRbg = J[0:3]
        J[9:12] = J[9:12] + J[3:6] * h - 0.5 * dR * h * h
        J[12:15] = J[12:15] + J[6:9] * h - 0.5 * Ra @ dRbg * h * h
        J[3:6] = J[3:6] - dR * h
        J[6:9] = J[6:9] - Ra @ dRbg * h
        J[0:3] = dRk.T @ dRbg - Jr * h
        # the deltas
        dp = dp + dv * h + 0.5 * (dR @ a) * h * h
        dv = dv + (dR @ a) * h
        dR = dR @ dRk
    return dR, dv, dp, C, J


@dataclass
class PreintegratedImu:
    """Preintegrated IMU between two keyframes at the linearisation bias ``bias``; ``accel_noise`` and
    ``gyro_noise`` are white-noise densities (m/s^2/sqrt(Hz), rad/s/sqrt(Hz))."""

    bias: ImuBias = field(default_factory=ImuBias)
    accel_noise: float = 3e-3
    gyro_noise: float = 2e-4
    dR: FloatArray = field(default_factory=lambda: np.eye(3))
    dv: FloatArray = field(default_factory=lambda: np.zeros(3))
    dp: FloatArray = field(default_factory=lambda: np.zeros(3))
    dt_ij: float = 0.0
    cov: FloatArray = field(default_factory=lambda: np.zeros((9, 9)))
    jac_bias: FloatArray = field(default_factory=lambda: np.zeros((15, 3)))

    def integrate(self, accel: FloatArray, gyro: FloatArray, dt: FloatArray) -> None:
        """Add samples (N, 3) m/s^2 and rad/s (body frame), each held over dt (N,) s."""
        a = np.ascontiguousarray(accel, dtype=float).reshape(-1, 3)
        w = np.ascontiguousarray(gyro, dtype=float).reshape(-1, 3)
        h = np.atleast_1d(np.asarray(dt, dtype=float))
        if len(a) != len(w) or len(a) != len(h) or np.any(~(h > 0)):
            raise ValueError(
                f"preintegration: {len(a)} accel, {len(w)} gyro samples and {len(h)} positive dt expected"
            )
        self.dR, self.dv, self.dp, self.cov, self.jac_bias = _preintegrate(
            a, w, h, np.asarray(self.bias.accel_b, float), np.asarray(self.bias.gyro_b, float),
            self.accel_noise**2, self.gyro_noise**2, self.dR, self.dv, self.dp, self.cov,
            self.jac_bias.copy(),
        )  # fmt: skip
        self.dt_ij += float(h.sum())

    def corrected_deltas(
        self, bias: ImuBias | None = None
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(dR, dv, dp) for another bias estimate, to first order (Forster eq. 44)."""
        if bias is None:
            return self.dR, self.dv, self.dp
        dba = np.asarray(bias.accel_b, float) - self.bias.accel_b
        dbg = np.asarray(bias.gyro_b, float) - self.bias.gyro_b
        J = self.jac_bias
        dR = self.dR @ exp_nb(np.ascontiguousarray(J[0:3] @ dbg))
        dv = self.dv + J[3:6] @ dba + J[6:9] @ dbg
        dp = self.dp + J[9:12] @ dba + J[12:15] @ dbg
        return dR, dv, dp

    def predict(self, nav_i: NavState, g_n: FloatArray, bias: ImuBias | None = None) -> NavState:
        """The state at keyframe j from the state at i (navigation frame with gravity g_n (3,))."""
        dR, dv, dp = self.corrected_deltas(bias)
        R, v, p = nav_i.R_n_b, nav_i.v_n, nav_i.p_n
        T = self.dt_ij
        g = np.asarray(g_n, float)
        return NavState(p + v * T + 0.5 * g * T * T + R @ dp, v + g * T + R @ dv, R @ dR)
