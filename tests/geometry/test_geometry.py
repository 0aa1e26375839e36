"""Round trips and identities of the SO(3) and quaternion maths against independent references."""

import numpy as np
from scipy.spatial.transform import Rotation

from imuslam.geometry import (
    exp,
    hat,
    log,
    quat_from_matrix,
    quat_from_rotvec,
    quat_mul,
    quat_to_matrix,
    quat_to_rotvec,
    right_jacobian,
    vee,
)


def _rotvecs(rng: np.random.Generator, n: int) -> np.ndarray:
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    angle = rng.uniform(0.0, np.pi - 1e-6, size=(n, 1))
    angle[:5] = np.array([[0.0], [1e-10], [1e-6], [np.pi - 1e-9], [1e-3]])
    return axis * angle


def test_exp_matches_scipy_and_log_inverts() -> None:
    rng = np.random.default_rng(0)
    th = _rotvecs(rng, 500)
    R = exp(th)
    np.testing.assert_allclose(R, Rotation.from_rotvec(th).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(log(R), th, atol=1e-7)


def test_hat_vee_cross() -> None:
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(2, 100, 3))
    np.testing.assert_allclose((hat(a) @ b[..., None])[..., 0], np.cross(a, b), atol=1e-14)
    np.testing.assert_allclose(vee(hat(a)), a, atol=1e-15)


def test_quaternion_matches_scipy() -> None:
    rng = np.random.default_rng(2)
    th1, th2 = _rotvecs(rng, 200), _rotvecs(rng, 200)
    q1, q2 = quat_from_rotvec(th1), quat_from_rotvec(th2)
    r1, r2 = Rotation.from_rotvec(th1), Rotation.from_rotvec(th2)
    np.testing.assert_allclose(quat_to_matrix(quat_mul(q1, q2)), (r1 * r2).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(quat_to_matrix(q1), r1.as_matrix(), atol=1e-12)
    q_back = quat_from_matrix(r1.as_matrix())
    np.testing.assert_allclose(np.abs(np.sum(q_back * q1, axis=1)), 1.0, atol=1e-12)
    np.testing.assert_allclose(quat_to_rotvec(q1), th1, atol=1e-7)


def test_right_jacobian_first_order() -> None:
    """exp(th + d) ~= exp(th) exp(Jr(th) d) for a small d."""
    rng = np.random.default_rng(3)
    th = _rotvecs(rng, 50) * 0.9
    d = rng.normal(size=(50, 3)) * 1e-6
    lhs = exp(th + d)
    rhs = exp(th) @ exp((right_jacobian(th) @ d[..., None])[..., 0])
    assert np.max(np.abs(lhs - rhs)) < 1e-11
