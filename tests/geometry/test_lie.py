"""SE(3), SE(2): round trips (exp/log, compose/inverse), Jacobians against finite differences, the
adjoint identity; Euler helpers; the one pose interpolation against scipy's Slerp."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from imuslam.geometry import se2, se3, so3
from imuslam.geometry.euler import euler_rates_to_body, euler_to_matrix, matrix_to_euler
from imuslam.geometry.interp import interpolate_linear, interpolate_poses

RNG = np.random.default_rng(7)


def _xi6(n: int, scale: float = 1.0) -> np.ndarray:
    xi = RNG.normal(size=(n, 6)) * scale
    xi[:, :3] *= 0.9  # angles well inside pi
    return xi


@pytest.mark.parametrize("scale", [1e-9, 1e-3, 1.0])
def test_se3_exp_log_round_trip(scale: float) -> None:
    xi = _xi6(200, scale)
    xi[:, :3] = np.clip(xi[:, :3], -1.7, 1.7)
    np.testing.assert_allclose(se3.log(se3.exp(xi)), xi, atol=1e-12 + 1e-10 * scale)
    T = se3.exp(xi)
    np.testing.assert_allclose(se3.exp(se3.log(T)), T, atol=1e-12)
    # the algebra: exp is the matrix exponential of hat(xi)
    from scipy.linalg import expm

    for k in range(5):
        np.testing.assert_allclose(se3.exp(xi[k]), expm(se3.hat(xi[k])), atol=1e-12)
    np.testing.assert_allclose(se3.vee(se3.hat(xi)), xi)


def test_se3_compose_inverse_between_act() -> None:
    A, B = se3.exp(_xi6(50)), se3.exp(_xi6(50))
    np.testing.assert_allclose(
        se3.compose(A, se3.inverse(A)), np.broadcast_to(np.eye(4), A.shape), atol=1e-12
    )
    np.testing.assert_allclose(se3.inverse(A), np.linalg.inv(A), atol=1e-12)
    np.testing.assert_allclose(se3.compose(A, se3.between(A, B)), B, atol=1e-12)
    p = RNG.normal(size=(50, 3))
    ph = np.concatenate([p, np.ones((50, 1))], 1)
    np.testing.assert_allclose(se3.act(A, p), np.einsum("nij,nj->ni", A, ph)[:, :3], atol=1e-12)
    np.testing.assert_allclose(se3.act(A[0], p), (A[0] @ ph.T).T[:, :3], atol=1e-12)
    xi = _xi6(50)
    np.testing.assert_allclose(se3.rminus(se3.rplus(A, xi), A), xi, atol=1e-10)


def test_se3_jacobians_and_adjoint_by_finite_differences() -> None:
    h = 1e-6
    small = np.array([2e-5, -1e-5, 1.5e-5, 0.3, -0.7, 1.1])  # the Taylor branch of the Q block
    for xi in [*_xi6(10), small]:
        Jr, Jl = se3.right_jacobian(xi), se3.left_jacobian(xi)
        T = se3.exp(xi)
        for j in range(6):
            d = np.zeros(6)
            d[j] = h
            col_r = se3.log(se3.inverse(T) @ se3.exp(xi + d)) / h
            col_l = se3.log(se3.exp(xi + d) @ se3.inverse(T)) / h
            np.testing.assert_allclose(col_r, Jr[:, j], atol=2e-6)
            np.testing.assert_allclose(col_l, Jl[:, j], atol=2e-6)
        tau = RNG.normal(size=6)
        np.testing.assert_allclose(
            T @ se3.exp(tau) @ se3.inverse(T), se3.exp(se3.adjoint(T) @ tau), atol=1e-10
        )


def test_se2_round_trips_jacobians_adjoint() -> None:
    xi = RNG.normal(size=(100, 3))
    xi[:, 0] = np.clip(xi[:, 0], -3.0, 3.0)
    np.testing.assert_allclose(se2.log(se2.exp(xi)), xi, atol=1e-12)
    np.testing.assert_allclose(se2.log(se2.exp(xi * 1e-9)), xi * 1e-9, atol=1e-20)
    from scipy.linalg import expm

    for k in range(5):
        np.testing.assert_allclose(se2.exp(xi[k]), expm(se2.hat(xi[k])), atol=1e-12)
    A, B = se2.exp(xi[:50]), se2.exp(xi[50:])
    np.testing.assert_allclose(se2.compose(A, se2.between(A, B)), B, atol=1e-12)
    np.testing.assert_allclose(se2.inverse(A), np.linalg.inv(A), atol=1e-12)
    pose = se2.to_xy_yaw(A)
    np.testing.assert_allclose(se2.from_xy_yaw(pose), A, atol=1e-12)
    h = 1e-6
    for x in list(xi[:8]) + [np.array([1e-8, 0.4, -0.2])]:
        Jr, Jl, T = se2.right_jacobian(x), se2.left_jacobian(x), se2.exp(x)
        for j in range(3):
            d = np.zeros(3)
            d[j] = h
            np.testing.assert_allclose(
                se2.log(se2.inverse(T) @ se2.exp(x + d)) / h, Jr[:, j], atol=2e-6
            )
            np.testing.assert_allclose(
                se2.log(se2.exp(x + d) @ se2.inverse(T)) / h, Jl[:, j], atol=2e-6
            )
        tau = RNG.normal(size=3)
        np.testing.assert_allclose(
            T @ se2.exp(tau) @ se2.inverse(T), se2.exp(se2.adjoint(T) @ tau), atol=1e-10
        )
    p = RNG.normal(size=(50, 2))
    np.testing.assert_allclose(se2.act(A[0], p), p @ A[0, :2, :2].T + A[0, :2, 2])


def test_euler_round_trip_and_rates() -> None:
    rpy = np.column_stack(
        [RNG.uniform(-3, 3, 200), RNG.uniform(-1.5, 1.5, 200), RNG.uniform(-3, 3, 200)]
    )
    R = euler_to_matrix(rpy)
    np.testing.assert_allclose(R, Rotation.from_euler("ZYX", rpy[:, ::-1]).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(matrix_to_euler(R), rpy, atol=1e-9)
    # body rate: R^T dR/dt = hat(omega_b), by central differences
    rates = RNG.normal(size=(200, 3))
    h = 1e-6
    dR = (euler_to_matrix(rpy + h * rates) - euler_to_matrix(rpy - h * rates)) / (2 * h)
    np.testing.assert_allclose(
        so3.vee(np.swapaxes(R, 1, 2) @ dR), euler_rates_to_body(rpy, rates), atol=1e-6
    )


def test_interpolation_equals_scipy_slerp_and_hits_the_knots() -> None:
    n = 50
    t_ns = 1_700_000_000_000_000_000 + np.cumsum(RNG.integers(5_000_000, 20_000_000, n))
    R = so3.exp(RNG.normal(size=(n, 3)))
    p = RNG.normal(size=(n, 3))
    tq = np.sort(RNG.integers(t_ns[0], t_ns[-1], 300))
    tq = np.concatenate([[t_ns[0]], tq, [t_ns[-1]], t_ns[10:12]])
    pq, Rq = interpolate_poses(t_ns, p, R, tq)
    ts, tqs = (t_ns - t_ns[0]) * 1e-9, (tq - t_ns[0]) * 1e-9
    np.testing.assert_allclose(Rq, Slerp(ts, Rotation.from_matrix(R))(tqs).as_matrix(), atol=1e-9)
    np.testing.assert_allclose(
        pq, np.stack([np.interp(tqs, ts, p[:, j]) for j in range(3)], 1), atol=1e-9
    )
    np.testing.assert_allclose(pq[-2:], p[10:12], atol=1e-15)
    np.testing.assert_allclose(interpolate_linear(t_ns, p, tq), pq, atol=1e-15)
