"""The numpy RK4 integrator, its analytic sensitivity and the small Levenberg-Marquardt solver, each
against a slow or independent reference."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from rk4_reference import rk4_integrate_gyro
from scipy.optimize import least_squares

from imuslam.geometry import exp, quat_to_matrix
from imuslam.imu.lm import levenberg_marquardt
from imuslam.imu.rk4 import (
    integrate_segments,
    integrate_segments_numpy,
    integrate_segments_sensitivity,
)


def test_reference_rk4_constant_rate_is_exact_and_batched() -> None:
    """The slow reference itself: a constant rate integrates to exp(omega * T); RK4's error at 100 Hz
    is far below 1e-9 rad."""
    rng = np.random.default_rng(4)
    omega = rng.normal(size=(7, 3))
    n = 301
    w = np.repeat(omega[:, None, :], n, axis=1)
    dt = np.full((7, n - 1), 0.01)
    q = rk4_integrate_gyro(w, dt)
    expected = exp(omega * 3.0)
    np.testing.assert_allclose(quat_to_matrix(q), expected, atol=1e-9)
    q0 = rk4_integrate_gyro(w[3], dt[3])
    np.testing.assert_allclose(q0, q[3], atol=1e-15)


def _motion(seed: int, n: int = 3000, rate_hz: float = 100.0) -> tuple[np.ndarray, np.ndarray]:
    """Smooth random body rates up to about 2 rad/s, with jittered sample times."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(np.full(n, 1.0 / rate_hz) * (1 + 0.05 * rng.uniform(-1, 1, n)))
    k = np.arange(n)[:, None]
    w = np.sin(2 * np.pi * k * rng.uniform(0.001, 0.01, 3) + rng.uniform(0, 6, 3)) * rng.uniform(
        0.5, 2.0, 3
    )
    return w, t


def _segments(seed: int, n: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    starts = np.sort(rng.choice(n - 400, 12, replace=False))
    lengths = rng.integers(0, 390, 12)  # includes zero-length and odd lengths
    lengths[0] = 0
    return np.stack([starts, starts + lengths], axis=1)


@pytest.mark.parametrize("seed", [0, 1])
def test_numpy_integration_equals_compiled_and_slow_reference(seed: int) -> None:
    w, t = _motion(seed)
    segs = _segments(seed, len(w))
    rng = np.random.default_rng(10 + seed)
    P = 3
    Ms = np.eye(3)[None] + 0.05 * rng.standard_normal((P, 3, 3))
    offs = 0.1 * rng.standard_normal((P, 3))
    Gs = 0.01 * rng.standard_normal((P, 3, 3))
    f = rng.standard_normal((len(w), 3))
    fast = integrate_segments_numpy(w, t, segs, Ms, offs, Gs, f)
    compiled = integrate_segments(w, t, segs, Ms, offs, Gs, f)
    # both evaluate the same RK4 recursion: they differ by rounding only
    assert np.abs(fast - compiled).max() < 1e-12
    # the slow reference (rk4_reference.rk4_integrate_gyro) on one parameter set, one segment at a time
    for s, (a, b) in enumerate(segs):
        rates = (w[a : b + 1] - offs[0]) @ Ms[0].T - f[a : b + 1] @ Gs[0].T
        q = rk4_integrate_gyro(rates, np.diff(t[a : b + 1]))
        assert np.abs(quat_to_matrix(q) - fast[0, s]).max() < 1e-12


def test_sensitivity_matches_finite_differences() -> None:
    w, t = _motion(3)
    segs = _segments(3, len(w))
    rng = np.random.default_rng(4)
    M = np.eye(3) + 0.05 * rng.standard_normal((3, 3))
    o = 0.05 * rng.standard_normal(3)
    R, Z, Y = integrate_segments_sensitivity(w, t, segs, M, o)
    assert np.abs(R - integrate_segments_numpy(w, t, segs, M[None], o[None])[0]).max() < 1e-13

    def rotvec_between(R0: np.ndarray, R1: np.ndarray) -> np.ndarray:
        from scipy.spatial.transform import Rotation

        return np.stack(
            [Rotation.from_matrix(a.T @ b).as_rotvec() for a, b in zip(R0, R1, strict=True)]
        )

    # central differences remove the second-order term; what is left is the sensitivity's own
    # approximation (each step a rotation about its mean rate): O(|h w|^2) = (0.01 * 2)^2 = 4e-4
    eps = 1e-6
    for a in range(3):
        for b in range(3):
            dM = np.zeros((3, 3))
            dM[a, b] = eps
            Rp = integrate_segments_numpy(w, t, segs, (M + dM)[None], o[None])[0]
            Rm = integrate_segments_numpy(w, t, segs, (M - dM)[None], o[None])[0]
            fd = 0.5 * (rotvec_between(R, Rp) - rotvec_between(R, Rm)) / eps
            scale = np.abs(fd).max()
            assert np.abs(Z[:, :, a, b] - fd).max() < 4e-4 * scale + 1e-9
    for i in range(3):
        do = np.zeros(3)
        do[i] = eps
        Rp = integrate_segments_numpy(w, t, segs, M[None], (o + do)[None])[0]
        Rm = integrate_segments_numpy(w, t, segs, M[None], (o - do)[None])[0]
        fd = 0.5 * (rotvec_between(R, Rp) - rotvec_between(R, Rm)) / eps
        pred = Y @ (-M[:, i])  # rates M (w - o): d rate / d o_i = -M e_i
        assert np.abs(pred - fd).max() < 4e-4 * np.abs(fd).max() + 1e-9


def _problem(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A small exponential-decay fit with noise: y = a exp(-b t) + c sin(d t)."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 10, 200)
    truth = np.array([2.0, 0.3, 0.5, 1.7])
    y = truth[0] * np.exp(-truth[1] * t) + truth[2] * np.sin(truth[3] * t)
    return t, y + 0.01 * rng.standard_normal(t.size), truth


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_lm_reaches_scipys_minimum(seed: int) -> None:
    t, y, truth = _problem(seed)

    def fun(x: np.ndarray) -> np.ndarray:
        return x[0] * np.exp(-x[1] * t) + x[2] * np.sin(x[3] * t) - y

    def jac(x: np.ndarray) -> np.ndarray:
        e = np.exp(-x[1] * t)
        return np.stack([e, -x[0] * t * e, np.sin(x[3] * t), x[2] * t * np.cos(x[3] * t)], axis=1)

    x0 = truth * np.array([1.3, 0.7, 1.4, 1.05])
    scale = np.array([1.0, 0.1, 1.0, 1.0])
    ours = levenberg_marquardt(fun, x0, jac, x_scale=scale)
    ref = least_squares(fun, x0, jac=jac, method="lm", x_scale=scale, xtol=1e-12, ftol=1e-12)
    assert ours.success, ours.message
    # the same minimum: far closer than the fit's own 1-sigma (noise 0.01 over 200 points)
    cov = 0.01**2 * np.linalg.inv(ref.jac.T @ ref.jac)
    assert np.all(np.abs(ours.x - ref.x) < 1e-6 * np.sqrt(np.diag(cov)))
    assert np.allclose(ours.fun, fun(ours.x)) and np.allclose(ours.jac, jac(ours.x))


def test_lm_reports_a_residual_that_is_not_finite() -> None:
    res = levenberg_marquardt(
        lambda x: np.array([np.nan, x[0]]), np.array([1.0]), lambda x: np.array([[0.0], [1.0]])
    )
    assert not res.success and "not finite" in res.message


def test_imutk_style_calibration_imports_neither_numba_nor_scipy_optimize() -> None:
    """One tedaldi fit runs on numpy alone: numba and scipy.optimize cost more to import than it takes."""
    code = (
        "import sys, numpy as np\n"
        "from imuslam.imu.calibrate import CalibrationConfig, calibrate\n"
        "from imuslam.sim.multipose import simulate_multipose, sphere_plan_deg\n"
        "rng = np.random.default_rng(1)\n"
        "log = simulate_multipose(sphere_plan_deg(40, rng), rng).log\n"
        "calibrate(log, CalibrationConfig(method='tedaldi'))\n"
        "print(sorted(m for m in ('numba', 'scipy.optimize', 'scipy.special') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr
