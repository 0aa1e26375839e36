"""IMU preintegration: prediction equals direct integration of the same samples, the first-order bias
correction agrees with re-integration to second order, and deltas and covariance equal GTSAM's
``PreintegratedImuMeasurements`` (the anchor) on the same samples."""

from __future__ import annotations

import numpy as np

from imuslam.geometry import exp, log, right_jacobian
from imuslam.ins.preintegration import PreintegratedImu
from imuslam.interfaces.nav import ImuBias, NavState

G = np.array([0.0, 0.0, -9.81])


def _samples(n: int = 400, seed: int = 5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.005
    acc = (
        np.column_stack([np.sin(3 * t), np.cos(2 * t), 9.81 + 0.5 * np.sin(t)])
        + rng.normal(size=(n, 3)) * 0.05
    )
    gyr = (
        np.column_stack([0.3 * np.sin(2 * t), -0.2 * np.cos(t), 0.5 + 0.1 * t])
        + rng.normal(size=(n, 3)) * 0.01
    )
    return acc, gyr, np.full(n, 0.005)


def test_prediction_equals_direct_integration() -> None:
    """Two seconds at 200 Hz from a moving, rotated start: the preintegrated prediction against a direct
    Euler integration of the same samples in the navigation frame (the same discretisation, so equal to
    rounding: 1e-9 m, 1e-12 rad)."""
    acc, gyr, dt = _samples()
    bias = ImuBias(np.array([0.02, -0.01, 0.03]), np.array([0.001, -0.002, 0.0005]))
    pim = PreintegratedImu(bias)
    pim.integrate(
        acc[:150], gyr[:150], dt[:150]
    )  # in two blocks, as between keyframes with a pause
    pim.integrate(acc[150:], gyr[150:], dt[150:])
    nav0 = NavState(
        np.array([1.0, 2.0, 0.5]), np.array([0.3, -0.2, 0.1]), exp(np.array([0.1, -0.2, 0.7]))
    )
    pred = pim.predict(nav0, G)
    p, v, R = nav0.p_n.copy(), nav0.v_n.copy(), nav0.R_n_b.copy()
    for k in range(len(dt)):
        a_n = R @ (acc[k] - bias.accel_b) + G
        p = p + v * dt[k] + 0.5 * a_n * dt[k] ** 2
        v = v + a_n * dt[k]
        R = R @ exp((gyr[k] - bias.gyro_b) * dt[k])
    np.testing.assert_allclose(pred.p_n, p, atol=1e-9)
    np.testing.assert_allclose(pred.v_n, v, atol=1e-9)
    assert np.linalg.norm(log(pred.R_n_b.T @ R)) < 1e-12
    assert abs(pim.dt_ij - 2.0) < 1e-12


def test_bias_correction_is_first_order_exact() -> None:
    """A bias change of 1e-2 m/s^2 and 1e-3 rad/s: the Jacobian correction matches re-integration with
    the new bias to O(db^2) (errors below 1e-4 m, against 1e-2 m moved by the change itself)."""
    acc, gyr, dt = _samples()
    b0 = ImuBias(np.zeros(3), np.zeros(3))
    b1 = ImuBias(np.array([0.01, -0.01, 0.01]), np.array([1e-3, -1e-3, 1e-3]))
    pim = PreintegratedImu(b0)
    pim.integrate(acc, gyr, dt)
    ref = PreintegratedImu(b1)
    ref.integrate(acc, gyr, dt)
    dR, dv, dp = pim.corrected_deltas(b1)
    assert np.linalg.norm(dp - ref.dp) < 1e-4 < np.linalg.norm(pim.dp - ref.dp) / 10
    assert np.linalg.norm(dv - ref.dv) < 1e-4
    assert np.linalg.norm(log(dR.T @ ref.dR)) < 1e-5


def test_equals_gtsam_preintegrated_imu_measurements() -> None:
    import gtsam

    acc, gyr, dt = _samples(200)
    sa, sg = 0.02, 0.002
    bias = ImuBias(np.array([0.02, -0.01, 0.03]), np.array([0.001, -0.002, 0.0005]))
    params = gtsam.PreintegrationParams.MakeSharedU(9.81)
    params.setAccelerometerCovariance(np.eye(3) * sa**2)
    params.setGyroscopeCovariance(np.eye(3) * sg**2)
    params.setIntegrationCovariance(np.zeros((3, 3)))
    ref = gtsam.PreintegratedImuMeasurements(
        params, gtsam.imuBias.ConstantBias(bias.accel_b, bias.gyro_b)
    )
    for k in range(len(dt)):
        ref.integrateMeasurement(acc[k], gyr[k], dt[k])
    pim = PreintegratedImu(bias, sa, sg)
    pim.integrate(acc, gyr, dt)
    # GTSAM's default tangent-space preintegration truncates the inverse right Jacobian of SO(3) at
    # first order (an O(|theta|^2 |w| dt) difference per step from Exp composition): over this 1 s, 1.2 rad
    # turn that is a few 1e-6 rad, and what it moves the velocity and position by
    assert np.linalg.norm(log(pim.dR.T @ ref.deltaRij().matrix())) < 2e-5
    np.testing.assert_allclose(pim.dv, ref.deltaVij(), atol=1e-4)
    np.testing.assert_allclose(pim.dp, ref.deltaPij(), atol=5e-5)
    # GTSAM's tangent preintegration keeps the rotation error additive on theta = Log(dR); ours is on
    # the right of dR: d(theta) = J_r(theta)^-1 dtheta_right maps ours into its coordinates
    T = np.eye(9)
    T[0:3, 0:3] = np.linalg.inv(right_jacobian(log(pim.dR)))
    C = ref.preintMeasCov()
    np.testing.assert_allclose(T @ pim.cov @ T.T, C, rtol=2e-3, atol=2e-3 * np.abs(C).max())
