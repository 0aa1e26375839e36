"""The inertial nominal state and its error-state layout, with the one boxplus / boxminus.

The error state is addressed by NAMED slices of an :class:`ErrorLayout`, rotation first as everywhere in
imuslam (:mod:`imuslam.geometry`): ``[dtheta, dp, dv, db_a, db_g, dg]``; the attitude error is on the
right, in the body frame, ``R_true = R exp(dtheta)`` (see :mod:`imuslam.ins.core`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np
from numpy.typing import NDArray

from imuslam.geometry.so3_nb import exp_nb, log_nb
from imuslam.interfaces.nav import ImuBias, NavState

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass(frozen=True)
class ErrorLayout:
    """Which blocks the error state has and where: always TH (attitude), P, V; optionally BA, BG, G.

    Blocks are 3 wide and in the order TH, P, V, BA, BG, G. ``offsets`` (6,) int64 gives each block's
    first index or -1 (for compiled kernels). ``extra`` states follow them (from index ``base_dim``):
    the propagation leaves them unchanged (identity transition, no process noise) and ``boxplus``
    ignores them, so their owner keeps their nominal values (e.g. a stochastic clone of an earlier
    pose, whose covariance with the current state the propagation carries along)."""

    accel_bias: bool = True
    gyro_bias: bool = True
    gravity: bool = False
    extra: int = 0

    @property
    def offsets(self) -> IntArray:
        off = []
        i = 0
        for present in (True, True, True, self.accel_bias, self.gyro_bias, self.gravity):
            off.append(i if present else -1)
            i += 3 if present else 0
        return np.array(off, dtype=np.int64)

    @property
    def base_dim(self) -> int:
        """The inertial blocks' dimension (without ``extra``)."""
        return 9 + 3 * (int(self.accel_bias) + int(self.gyro_bias) + int(self.gravity))

    @property
    def dim(self) -> int:
        return self.base_dim + self.extra

    def _slice(self, k: int, name: str) -> slice:
        o = int(self.offsets[k])
        if o < 0:
            raise KeyError(f"the error state {self.dim} has no {name} block")
        return slice(o, o + 3)

    @property
    def TH(self) -> slice:
        return self._slice(0, "attitude")

    @property
    def P(self) -> slice:
        return self._slice(1, "position")

    @property
    def V(self) -> slice:
        return self._slice(2, "velocity")

    @property
    def BA(self) -> slice:
        return self._slice(3, "accelerometer bias")

    @property
    def BG(self) -> slice:
        return self._slice(4, "gyro bias")

    @property
    def G(self) -> slice:
        return self._slice(5, "gravity")

    @classmethod
    def full(cls, gravity: bool = False) -> ErrorLayout:
        """15 states [dtheta, dp, dv, db_a, db_g] (18 with dg)."""
        return cls(True, True, gravity)

    @classmethod
    def reduced(cls) -> ErrorLayout:
        """12 states [dtheta, dp, dv, dg]: no biases (a LIO on a corrected IMU)."""
        return cls(False, False, True)

    def diag(self, *, theta: float, p: float, v: float, ba: float = 0.0, bg: float = 0.0,
             g: float = 0.0) -> FloatArray:  # fmt: skip
        """A covariance diagonal (dim,) from per-block variances, e.g. ``layout.diag(theta=0.05**2, ...)``."""
        d = np.zeros(self.dim)
        for k, val in enumerate((theta, p, v, ba, bg, g)):
            o = int(self.offsets[k])
            if o >= 0:
                d[o : o + 3] = val
        return d


@dataclass
class InsState:
    """Nominal state: p_n (3,) m, v_n (3,) m/s, R_n_b (3, 3), accel_bias (3,) m/s^2, gyro_bias (3,) rad/s
    (measured = true + bias), g_n (3,) m/s^2 gravity in n."""

    p_n: FloatArray
    v_n: FloatArray
    R_n_b: FloatArray
    accel_bias: FloatArray = field(default_factory=lambda: np.zeros(3))
    gyro_bias: FloatArray = field(default_factory=lambda: np.zeros(3))
    g_n: FloatArray = field(default_factory=lambda: np.array([0.0, 0.0, -9.80665]))

    @classmethod
    def from_nav(cls, nav: NavState, bias: ImuBias | None = None, g: float = 9.80665) -> InsState:
        b = bias or ImuBias()
        return cls(np.array(nav.p_n, float), np.array(nav.v_n, float), np.array(nav.R_n_b, float),
                   np.array(b.accel_b, float), np.array(b.gyro_b, float), np.array([0.0, 0.0, -g]))  # fmt: skip

    @property
    def nav(self) -> NavState:
        return NavState(self.p_n, self.v_n, self.R_n_b)

    @property
    def bias(self) -> ImuBias:
        return ImuBias(self.accel_bias, self.gyro_bias)

    def copy(self) -> InsState:
        return InsState(self.p_n.copy(), self.v_n.copy(), self.R_n_b.copy(), self.accel_bias.copy(),
                        self.gyro_bias.copy(), self.g_n.copy())  # fmt: skip


@numba.njit(cache=True, inline="always")
def boxplus_attitude(
    R: FloatArray, dtheta: FloatArray
) -> FloatArray:  # pragma: no cover - compiled
    """``R exp(dtheta)``: the one attitude perturbation (right, body frame)."""
    return R @ exp_nb(dtheta)


def boxplus(x: InsState, dx: FloatArray, layout: ErrorLayout) -> InsState:
    """``x ⊞ dx``: vector blocks add, the attitude is perturbed on the right."""
    o = layout.offsets
    y = x.copy()
    y.R_n_b = boxplus_attitude(
        np.ascontiguousarray(x.R_n_b), np.ascontiguousarray(dx[o[0] : o[0] + 3])
    )
    y.p_n = x.p_n + dx[o[1] : o[1] + 3]
    y.v_n = x.v_n + dx[o[2] : o[2] + 3]
    if o[3] >= 0:
        y.accel_bias = x.accel_bias + dx[o[3] : o[3] + 3]
    if o[4] >= 0:
        y.gyro_bias = x.gyro_bias + dx[o[4] : o[4] + 3]
    if o[5] >= 0:
        y.g_n = x.g_n + dx[o[5] : o[5] + 3]
    return y


def boxminus(x1: InsState, x0: InsState, layout: ErrorLayout) -> FloatArray:
    """``x1 ⊟ x0``: the dx with ``x0 ⊞ dx = x1`` (attitude ``log(R0^T R1)``)."""
    o = layout.offsets
    dx = np.zeros(layout.dim)
    dx[o[0] : o[0] + 3] = log_nb(np.ascontiguousarray(x0.R_n_b.T @ x1.R_n_b))
    dx[o[1] : o[1] + 3] = x1.p_n - x0.p_n
    dx[o[2] : o[2] + 3] = x1.v_n - x0.v_n
    if o[3] >= 0:
        dx[o[3] : o[3] + 3] = x1.accel_bias - x0.accel_bias
    if o[4] >= 0:
        dx[o[4] : o[4] + 3] = x1.gyro_bias - x0.gyro_bias
    if o[5] >= 0:
        dx[o[5] : o[5] + 3] = x1.g_n - x0.g_n
    return dx
