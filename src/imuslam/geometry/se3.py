"""SE(3): rigid transforms ``T_a_b`` (..., 4, 4), with the tangent ordered rotation first,
``xi = [theta, rho]`` (6,) (see :mod:`imuslam.geometry`).

exp / log after Sola, Deray, Atchuthan, "A micro Lie theory for state estimation in robotics" (2018),
eqs. 172-174 (``t = V(theta) rho`` with ``V`` the left Jacobian of SO(3)); Jacobians after Barfoot,
"State Estimation for Robotics" (2017), eqs. 7.83-7.86 (the ``Q`` block), reordered to rotation first.
Every function accepts a single element or a stack with leading batch dimensions.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imuslam.geometry import so3
from imuslam.geometry.rigid import act, between, compose, inverse

FloatArray = NDArray[np.float64]

__all__ = [
    "act",
    "adjoint",
    "between",
    "compose",
    "exp",
    "from_Rt",
    "hat",
    "inverse",
    "left_jacobian",
    "log",
    "right_jacobian",
    "rminus",
    "rplus",
    "vee",
]


def from_Rt(R: ArrayLike, t: ArrayLike) -> FloatArray:
    """(..., 3, 3) rotations and (..., 3) translations -> (..., 4, 4) transforms."""
    Ra = np.asarray(R, dtype=float)
    ta = np.asarray(t, dtype=float)
    shape = np.broadcast_shapes(Ra.shape[:-2], ta.shape[:-1])
    T = np.zeros(shape + (4, 4))
    T[..., :3, :3] = Ra
    T[..., :3, 3] = ta
    T[..., 3, 3] = 1.0
    return T


def hat(xi: ArrayLike) -> FloatArray:
    """[theta, rho] (..., 6) -> the Lie algebra matrix (..., 4, 4)."""
    x = np.asarray(xi, dtype=float)
    out = np.zeros(x.shape[:-1] + (4, 4))
    out[..., :3, :3] = so3.hat(x[..., :3])
    out[..., :3, 3] = x[..., 3:]
    return out


def vee(xi_hat: ArrayLike) -> FloatArray:
    """Inverse of :func:`hat`: (..., 4, 4) -> [theta, rho] (..., 6)."""
    m = np.asarray(xi_hat, dtype=float)
    return np.concatenate([so3.vee(m[..., :3, :3]), m[..., :3, 3]], axis=-1)


def exp(xi: ArrayLike) -> FloatArray:
    """[theta, rho] (..., 6) -> T (..., 4, 4): ``R = exp(theta)``, ``t = J_l(theta) rho``. Sola eq. 172."""
    x = np.asarray(xi, dtype=float)
    th, rho = x[..., :3], x[..., 3:]
    V = so3.left_jacobian(th)
    return from_Rt(so3.exp(th), np.einsum("...ij,...j->...i", V, rho))


def log(T: ArrayLike) -> FloatArray:
    """T (..., 4, 4) -> [theta, rho] (..., 6): ``rho = J_l(theta)^-1 t``. Sola eq. 173."""
    M = np.asarray(T, dtype=float)
    th = so3.log(M[..., :3, :3])
    V = so3.left_jacobian(th)
    rho = np.linalg.solve(V, M[..., :3, 3][..., None])[..., 0]
    return np.concatenate([th, rho], axis=-1)


def rplus(T: ArrayLike, xi: ArrayLike) -> FloatArray:
    """Right perturbation ``T exp(xi)``."""
    return compose(T, exp(xi))


def rminus(T1: ArrayLike, T2: ArrayLike) -> FloatArray:
    """``log(T2^-1 T1)``: the tangent taking T2 to T1 on the right."""
    return log(between(T2, T1))


def adjoint(T: ArrayLike) -> FloatArray:
    """Adjoint (..., 6, 6) for [theta, rho]: ``T exp(xi) T^-1 = exp(Ad xi)``; Ad = [[R, 0], [t^ R, R]]."""
    M = np.asarray(T, dtype=float)
    R, t = M[..., :3, :3], M[..., :3, 3]
    out = np.zeros(M.shape[:-2] + (6, 6))
    out[..., :3, :3] = R
    out[..., 3:, 3:] = R
    out[..., 3:, :3] = so3.hat(t) @ R
    return out


def _q_block(theta: FloatArray, rho: FloatArray) -> FloatArray:
    """Barfoot 2017, eq. 7.86: the coupling block of the left Jacobian of SE(3)."""
    ang = np.linalg.norm(theta, axis=-1)[..., None, None]
    small = ang < 1e-4
    a = np.where(small, 1.0, ang)
    P, Rh = so3.hat(theta), so3.hat(rho)
    c1 = 0.5
    c2 = np.where(small, 1.0 / 6.0 - ang**2 / 120.0, (a - np.sin(a)) / a**3)
    c3 = np.where(small, 1.0 / 24.0 - ang**2 / 720.0, (a**2 + 2 * np.cos(a) - 2) / (2 * a**4))
    c4 = np.where(
        small,
        1.0 / 120.0 - ang**2 / 2520.0,
        0.5 * ((2 * a - 3 * np.sin(a) + a * np.cos(a)) / a**5),
    )
    PR, RP = P @ Rh, Rh @ P
    PRP = P @ Rh @ P
    return (
        c1 * Rh + c2 * (PR + RP + PRP) + c3 * (P @ PR + RP @ P - 3 * PRP) + c4 * (PRP @ P + P @ PRP)
    )


def left_jacobian(xi: ArrayLike) -> FloatArray:
    """Left Jacobian (..., 6, 6) for [theta, rho]: ``exp(xi + d) ~ exp(J_l d) exp(xi)``."""
    x = np.asarray(xi, dtype=float)
    th, rho = x[..., :3], x[..., 3:]
    J = so3.left_jacobian(th)
    out = np.zeros(x.shape[:-1] + (6, 6))
    out[..., :3, :3] = J
    out[..., 3:, 3:] = J
    out[..., 3:, :3] = _q_block(th, rho)
    return out


def right_jacobian(xi: ArrayLike) -> FloatArray:
    """Right Jacobian (..., 6, 6): ``exp(xi + d) ~ exp(xi) exp(J_r d)``; ``J_r(xi) = J_l(-xi)``."""
    return left_jacobian(-np.asarray(xi, dtype=float))
