"""The inertial core: boxplus / boxminus, the error-state transition against numerical Jacobians of
the propagation kernel, chi-square gating against its stated probability, and the iterated update
against the maximum a posteriori solution found by scipy."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
from scipy.optimize import least_squares

from imuslam.geometry import exp
from imuslam.ins.core import (
    ErrorLayout,
    Eskf,
    InsState,
    KfNoise,
    PositionMeasurement,
    boxminus,
    boxplus,
    gate,
    integrate_nominal,
    propagate_covariance,
)

LAYOUTS = [ErrorLayout.full(), ErrorLayout.full(gravity=True), ErrorLayout.reduced()]


def _state(rng: np.random.Generator) -> InsState:
    return InsState(rng.normal(size=3), rng.normal(size=3), exp(rng.normal(size=3)),
                    rng.normal(size=3) * 0.1, rng.normal(size=3) * 0.01,
                    np.array([0.0, 0.0, -9.81]) + rng.normal(size=3) * 0.01)  # fmt: skip


@pytest.mark.parametrize("layout", LAYOUTS, ids=lambda lay: str(lay.dim))
def test_boxplus_boxminus_round_trip_and_named_slices(layout: ErrorLayout) -> None:
    rng = np.random.default_rng(1)
    x = _state(rng)
    dx = rng.normal(size=layout.dim) * 0.3
    y = boxplus(x, dx, layout)
    np.testing.assert_allclose(boxminus(y, x, layout), dx, atol=1e-12)
    # the attitude perturbation is on the right: R_y = R_x exp(dtheta)
    np.testing.assert_allclose(y.R_n_b, x.R_n_b @ exp(dx[layout.TH]), atol=1e-14)
    np.testing.assert_allclose(y.p_n - x.p_n, dx[layout.P])
    assert layout.TH == slice(0, 3)  # rotation first, as geometry's tangent order
    if not layout.accel_bias:
        with pytest.raises(KeyError):
            _ = layout.BA
        np.testing.assert_array_equal(y.accel_bias, x.accel_bias)


@pytest.mark.parametrize("layout", LAYOUTS, ids=lambda lay: str(lay.dim))
def test_error_transition_matches_numerical_jacobian_of_the_kernel(layout: ErrorLayout) -> None:
    """One 200 Hz interval: Phi Phi^T from the covariance kernel (P = I, no noise) against J J^T with J
    the finite-difference Jacobian of the nominal kernel in boxplus coordinates. Phi is first order in
    h (except the exact attitude block) and uses the first sample's specific force, so the two differ by
    O(h^2 |F|^2) + O(h |df|): tolerance 2e-3 for h = 5 ms, far below the entries (h |f| ~ 0.05)."""
    rng = np.random.default_rng(2)
    x = _state(rng)
    h = 0.005
    acc = np.array([[0.3, -0.2, 9.9], [0.31, -0.19, 9.88]])
    gyr = np.array([[0.5, -0.3, 0.2], [0.52, -0.31, 0.21]])
    z = np.zeros(3)

    def step(s: InsState) -> InsState:
        P, V, R = integrate_nominal(acc, gyr, np.array([h]), s.p_n, s.v_n, s.R_n_b, s.accel_bias,
                                    s.gyro_bias, s.g_n, z)  # fmt: skip
        return InsState(P[1], V[1], R[1], s.accel_bias, s.gyro_bias, s.g_n)

    x1 = step(x)
    m = layout.dim
    J = np.zeros((m, m))
    eps = 1e-7
    for i in range(m):
        d = np.zeros(m)
        d[i] = eps
        J[:, i] = boxminus(step(boxplus(x, d, layout)), x1, layout) / eps
    _, _, Rs = integrate_nominal(acc, gyr, np.array([h]), x.p_n, x.v_n, x.R_n_b, x.accel_bias,
                                 x.gyro_bias, x.g_n, z)  # fmt: skip
    fn = Rs[0] @ (acc[0] - x.accel_bias)
    P1, Q = propagate_covariance(np.eye(m), Rs, gyr, x.gyro_bias, np.array([h]), fn, np.zeros(4),
                                 layout.offsets)  # fmt: skip
    np.testing.assert_allclose(P1, J @ J.T, atol=2e-3)
    assert np.all(Q == 0)
    if layout.gravity:  # gravity error drives the velocity
        assert np.allclose(J[layout.V, layout.G], np.eye(3) * h, atol=1e-6)


def test_gate_accepts_the_stated_fraction() -> None:
    """Innovations drawn from their own covariance: the 95 % gate accepts 95 % of them (2000 draws,
    binomial 1-sigma 0.5 %, tolerance 4 sigma), and every accepted nis is below chi2(0.95, 3) = 7.815."""
    rng = np.random.default_rng(3)
    P = np.diag([0.2, 0.3, 0.1, 0.05, 0.05, 0.05])
    H = rng.normal(size=(3, 6))
    R = np.eye(3) * 0.01
    S = H @ P @ H.T + R
    L = np.linalg.cholesky(S)
    res = [gate(L @ rng.normal(size=3), H, R, P, 0.95) for _ in range(2000)]
    frac = np.mean([a for a, _ in res])
    assert abs(frac - 0.95) < 4 * np.sqrt(0.95 * 0.05 / 2000)
    assert max(n for a, n in res if a) <= 7.8148
    assert min(n for a, n in res if not a) > 7.8147


def test_update_rejects_an_outlier_and_reports_it() -> None:
    x = InsState(np.zeros(3), np.zeros(3), np.eye(3))
    kf = Eskf(x, P=np.eye(15) * 0.01)
    out = kf.update(PositionMeasurement(np.array([5.0, 0.0, 0.0]), 0.01), gate_prob=0.99)
    assert not out.accepted and out.nis > 100 and np.all(kf.p == 0)
    ok = kf.update(PositionMeasurement(np.array([0.05, 0.0, 0.0]), 0.01), gate_prob=0.99)
    assert ok.accepted and 0 < kf.p[0] < 0.05


def _beacon_ranges(
    seed: int,
) -> tuple[
    np.ndarray, np.ndarray, float, Callable[[InsState], tuple[np.ndarray, np.ndarray, np.ndarray]]
]:
    """Ranges to four beacons from (1, 0.5, -0.3) m with 1 cm noise: the beacons, the ranges, their
    sigma and the linearisation (innovation, H on the position, R) of the full error layout."""
    rng = np.random.default_rng(seed)
    beacons = np.array([[10.0, 0, 0], [0, 8.0, 0], [-6.0, -5.0, 1.0], [1.0, 1.0, 9.0]])
    std = 0.01
    z = np.linalg.norm(beacons - np.array([1.0, 0.5, -0.3]), axis=1) + rng.normal(size=4) * std
    layout = ErrorLayout.full()

    def lin(x: InsState) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        d = x.p_n - beacons
        rng_ = np.linalg.norm(d, axis=1)
        H = np.zeros((4, 15))
        H[:, layout.P] = d / rng_[:, None]
        return z - rng_, H, np.eye(4) * std**2

    return beacons, z, std, lin


def test_iterated_update_reaches_the_map_estimate() -> None:
    """Ranges to four beacons (nonlinear in position) with a 1 m prior: the IEKF's fixed point is the
    maximum a posteriori position (the prior on p is independent of the other states), which scipy's
    least squares finds on the same cost; a single EKF update stops short of it."""
    beacons, z, std, lin = _beacon_ranges(4)
    x0 = InsState(np.zeros(3), np.zeros(3), np.eye(3))
    P0 = np.eye(15)
    kf = Eskf(x0, P=P0)
    res = kf.iterated_update(lin, max_iter=20, eps=1e-10)
    map_ = least_squares(lambda p: np.concatenate([(np.linalg.norm(beacons - p, axis=1) - z) / std, p]),
                         np.zeros(3), xtol=1e-15, ftol=1e-15, gtol=1e-15).x  # fmt: skip
    np.testing.assert_allclose(kf.p, map_, atol=1e-8)
    assert 1 < res.iterations < 20
    one = Eskf(x0, P=P0)
    one.iterated_update(lin, max_iter=1)
    assert np.linalg.norm(one.p - map_) > 1e-4


def test_iterated_update_from_another_start_reaches_the_same_estimate() -> None:
    """The IEKF is Gauss-Newton on the posterior cost, so iterations started at another iterate
    (``x_start``: the LIO's coarse-gate result) converge to the same maximum a posteriori position;
    ``commit=False`` leaves the filter untouched and reports the iterate's offset from the prior."""
    _, _, _, lin = _beacon_ranges(5)
    x0 = InsState(np.zeros(3), np.zeros(3), np.eye(3))
    layout = ErrorLayout.full()
    ref = Eskf(x0, P=np.eye(15))
    ref.iterated_update(lin, max_iter=30, eps=1e-12)
    kf = Eskf(x0, P=np.eye(15))
    trial = kf.iterated_update(lin, max_iter=30, eps=1e-12, commit=False)
    assert np.all(kf.p == 0) and np.allclose(kf.P, np.eye(15))
    np.testing.assert_allclose(trial.dx[layout.P], ref.p, atol=1e-9)
    start = InsState(np.array([2.0, -1.0, 0.5]), np.zeros(3), np.eye(3))
    kf.iterated_update(lin, max_iter=30, eps=1e-12, x_start=start)
    np.testing.assert_allclose(kf.p, ref.p, atol=1e-8)
    np.testing.assert_allclose(kf.P, ref.P, atol=1e-10)


def test_reduced_layout_predicts_with_gravity_state() -> None:
    """12 states [dtheta, dp, dv, dg]: prediction couples gravity into velocity, P stays positive."""
    layout = ErrorLayout.reduced()
    kf = Eskf(InsState(np.zeros(3), np.zeros(3), np.eye(3)), P=np.eye(12) * 1e-2, layout=layout,
              noise=KfNoise())  # fmt: skip
    n = 201
    acc = np.tile([0.0, 0.0, 9.80665], (n, 1))
    Ps, _, _ = kf.predict(acc, np.zeros((n, 3)), np.arange(n) * 0.005)
    assert Ps.shape == (n, 3) and np.allclose(Ps, 0, atol=1e-12)
    assert np.all(np.abs(kf.P[layout.V, layout.G].diagonal()) > 1e-3)
