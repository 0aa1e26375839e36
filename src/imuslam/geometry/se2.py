"""SE(2): planar transforms ``T_a_b`` (..., 3, 3), with the tangent ordered rotation first,
``xi = [theta, rho_x, rho_y]`` (3,) like SE(3)'s (see :mod:`imuslam.geometry`).

exp / log and Jacobians after Sola, Deray, Atchuthan, "A micro Lie theory for state estimation in
robotics" (2018), eqs. 156-164 (there ordered [rho, theta]; reordered here). ``to_xy_yaw`` /
``from_xy_yaw`` convert to the (..., 3) [x, y, yaw] pose vectors of odometry messages.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imuslam.geometry.rigid import act, between, compose, inverse

FloatArray = NDArray[np.float64]

__all__ = [
    "act",
    "adjoint",
    "between",
    "compose",
    "exp",
    "from_xy_yaw",
    "hat",
    "inverse",
    "left_jacobian",
    "log",
    "right_jacobian",
    "rminus",
    "rplus",
    "to_xy_yaw",
    "vee",
]


def _rot(yaw: FloatArray) -> FloatArray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def from_xy_yaw(pose: ArrayLike) -> FloatArray:
    """[x, y, yaw] (..., 3) -> T (..., 3, 3)."""
    v = np.asarray(pose, dtype=float)
    T = np.zeros(v.shape[:-1] + (3, 3))
    T[..., :2, :2] = _rot(v[..., 2])
    T[..., :2, 2] = v[..., :2]
    T[..., 2, 2] = 1.0
    return T


def to_xy_yaw(T: ArrayLike) -> FloatArray:
    """T (..., 3, 3) -> [x, y, yaw] (..., 3), yaw in (-pi, pi]."""
    M = np.asarray(T, dtype=float)
    return np.stack([M[..., 0, 2], M[..., 1, 2], np.arctan2(M[..., 1, 0], M[..., 0, 0])], -1)


def hat(xi: ArrayLike) -> FloatArray:
    """[theta, rho_x, rho_y] (..., 3) -> (..., 3, 3) Lie algebra matrix."""
    x = np.asarray(xi, dtype=float)
    out = np.zeros(x.shape[:-1] + (3, 3))
    out[..., 0, 1] = -x[..., 0]
    out[..., 1, 0] = x[..., 0]
    out[..., :2, 2] = x[..., 1:]
    return out


def vee(xi_hat: ArrayLike) -> FloatArray:
    """Inverse of :func:`hat`."""
    m = np.asarray(xi_hat, dtype=float)
    return np.stack([0.5 * (m[..., 1, 0] - m[..., 0, 1]), m[..., 0, 2], m[..., 1, 2]], -1)


def _v_coeffs(th: FloatArray) -> tuple[FloatArray, FloatArray]:
    """sin(th)/th and (1 - cos(th))/th = (th/2) sinc^2(th/2), both without cancellation near zero."""
    a = np.sinc(th / np.pi)
    b = 0.5 * th * np.sinc(th / (2.0 * np.pi)) ** 2
    return a, b


def exp(xi: ArrayLike) -> FloatArray:
    """[theta, rho] (..., 3) -> T: ``t = V(theta) rho``, V = [[a, -b], [b, a]]. Sola eq. 156."""
    x = np.asarray(xi, dtype=float)
    th = x[..., 0]
    a, b = _v_coeffs(th)
    t = np.stack([a * x[..., 1] - b * x[..., 2], b * x[..., 1] + a * x[..., 2]], -1)
    return from_xy_yaw(np.concatenate([t, th[..., None]], -1))


def log(T: ArrayLike) -> FloatArray:
    """T (..., 3, 3) -> [theta, rho] (..., 3), theta in (-pi, pi]. Sola eq. 157."""
    M = np.asarray(T, dtype=float)
    th = np.arctan2(M[..., 1, 0], M[..., 0, 0])
    a, b = _v_coeffs(th)
    det = a * a + b * b
    tx, ty = M[..., 0, 2], M[..., 1, 2]
    return np.stack([th, (a * tx + b * ty) / det, (-b * tx + a * ty) / det], -1)


def rplus(T: ArrayLike, xi: ArrayLike) -> FloatArray:
    """Right perturbation ``T exp(xi)``."""
    return compose(T, exp(xi))


def rminus(T1: ArrayLike, T2: ArrayLike) -> FloatArray:
    """``log(T2^-1 T1)``."""
    return log(between(T2, T1))


def adjoint(T: ArrayLike) -> FloatArray:
    """Adjoint (..., 3, 3) for [theta, rho]: [[1, 0], [[t_y, -t_x]^T, R]]. Sola eq. 159, reordered."""
    M = np.asarray(T, dtype=float)
    out = np.zeros(M.shape)
    out[..., 0, 0] = 1.0
    out[..., 1, 0] = M[..., 1, 2]
    out[..., 2, 0] = -M[..., 0, 2]
    out[..., 1:, 1:] = M[..., :2, :2]
    return out


def right_jacobian(xi: ArrayLike) -> FloatArray:
    """Right Jacobian (..., 3, 3): ``exp(xi + d) ~ exp(xi) exp(J_r d)``. Sola eq. 163, reordered."""
    x = np.asarray(xi, dtype=float)
    th, r1, r2 = x[..., 0], x[..., 1], x[..., 2]
    a, b = _v_coeffs(th)
    # the d/dtheta column (Sola's third): c1 = r1 f - r2 g, c2 = r1 g + r2 f with
    # f = (th - sin th) / th^2 (its series below 1e-3 rad) and g = (1 - cos th) / th^2
    small = np.abs(th) < 1e-3
    safe = np.where(small, 1.0, th)
    f = np.where(small, th / 6.0 - th**3 / 120.0, (safe - np.sin(safe)) / safe**2)
    g = 0.5 * np.sinc(th / (2.0 * np.pi)) ** 2
    c1 = r1 * f - r2 * g
    c2 = r1 * g + r2 * f
    out = np.zeros(x.shape[:-1] + (3, 3))
    out[..., 0, 0] = 1.0
    out[..., 1, 0] = c1
    out[..., 2, 0] = c2
    out[..., 1, 1] = a
    out[..., 1, 2] = b
    out[..., 2, 1] = -b
    out[..., 2, 2] = a
    return out


def left_jacobian(xi: ArrayLike) -> FloatArray:
    """Left Jacobian: ``J_l(xi) = J_r(-xi)``."""
    return right_jacobian(-np.asarray(xi, dtype=float))
