"""The VO covariance's shape, learnt on a run with known truth.

The front end's covariance of ``[omega_b, vel_b]`` comes from the motion fit, ``(J^T W J)^-1`` at the
prior pixel sigma: right in its per-frame geometry (which directions the features constrain), but not
in every direction's size. Against the truth of the rendered robot, the errors whitened by that
covariance (``w = L^-1 e``, ``L L^T = C``) have a second-moment matrix with eigenvalues from 0.3 to 3:
the forward and sideways velocity errors are twice their reported variance, the rate errors below it
(errors common to all points of a frame, sub-pixel and disparity biases, move the pose without
showing in the residuals). A scale per block can match the mean NIS of one run but not the shape, and
the run-to-run spread of the mean NIS grows with that mismatch (the NIS is then no chi-square).

:func:`learn_vo_cov_correction` estimates ``M = E[w w^T]`` (6, 6) from a calibration run; the filter
then uses ``L M L^T`` per frame (``VioConfig.vo_cov_correction``): the per-frame geometry of the fit,
the sizes measured against a truth. This is the classical residual-based covariance matching of
Mehra (1972, "Approaches to adaptive filtering", IEEE TAC 17(5)) done offline against the truth instead
of the innovations.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import EstimatorError
from imuslam.geometry import exp, log
from imuslam.io.trajectory import Trajectory
from imuslam.vio.frontend import VoMeasurement

FloatArray = NDArray[np.float64]


def vo_errors(
    measurements: list[VoMeasurement], truth_at: Callable[[NDArray[np.int64]], Trajectory]
) -> tuple[FloatArray, FloatArray]:
    """VO errors ``[omega_b, vel_b]`` - truth (N, 6) and the reported covariances (N, 6, 6).

    ``truth_at(t_ns)`` returns the true body poses at the given times; the true measurement is the
    relative rotation's log over the interval and the displacement seen from mid-interval, as the front
    end defines them."""
    if not measurements:
        return np.zeros((0, 6)), np.zeros((0, 6, 6))
    t = np.array([[m.t0_ns, m.t1_ns] for m in measurements], dtype=np.int64)
    tr = truth_at(t.ravel())
    R = tr.R_w_b.reshape(-1, 2, 3, 3)
    p = tr.p_w.reshape(-1, 2, 3)
    E = np.empty((len(measurements), 6))
    for k, m in enumerate(measurements):  # one per frame pair (hundreds), not per sample
        R01 = R[k, 0].T @ R[k, 1]
        rot = log(R01)
        vel = exp(-0.5 * rot) @ (R[k, 0].T @ (p[k, 1] - p[k, 0])) / m.dt
        E[k, :3] = m.omega_b - rot / m.dt
        E[k, 3:] = m.vel_b - vel
    return E, np.array([m.cov for m in measurements])


def learn_vo_cov_correction(errors: FloatArray, covs: FloatArray) -> FloatArray:
    """``M = mean(w w^T)`` (6, 6) of the errors (N, 6) whitened by the Cholesky factors of ``covs``
    (N, 6, 6); raises when there are too few frames (fewer than 60: 21 numbers to estimate)."""
    n = len(errors)
    if n < 60:
        raise EstimatorError(
            f"VO covariance correction: {n} VO measurements with truth; expected at least 60"
        )
    L = np.linalg.cholesky(covs)
    w = np.linalg.solve(L, errors[..., None])[..., 0]
    M = w.T @ w / n
    return np.asarray(0.5 * (M + M.T), dtype=np.float64)


def apply_vo_cov_correction(cov: FloatArray, M: FloatArray) -> FloatArray:
    """``L M L^T`` with ``L L^T = cov`` (6, 6)."""
    L = np.linalg.cholesky(cov)
    return np.asarray(L @ M @ L.T, dtype=np.float64)


def fit_vo_error(
    errors: FloatArray, dt: float, max_lag: int = 4
) -> tuple[tuple[float, float, float], float]:
    """A first-order Gauss-Markov model of the slowly varying part of the VO velocity errors: per body
    axis its 1-sigma (m/s) and one shared time constant (s), from the errors' autocovariance at lags
    1..``max_lag`` (in frame pairs of ``dt`` s) of ``errors`` (N, 6) ``[omega_b, vel_b]`` against a
    truth (:func:`vo_errors`, consecutive measurements). The white part shows at lag 0 only; an AR(1)
    part of variance ``s^2`` and lag-one correlation ``rho`` gives ``s^2 rho^L`` at lag L: ``rho`` on a
    grid shared by the three axes, ``s^2`` per axis in closed form (least squares, clipped at 0)."""
    if len(errors) < 10 * max_lag:
        raise EstimatorError(
            f"VO error model: {len(errors)} VO measurements with truth; expected at least {10 * max_lag}"
        )
    e = errors[:, 3:] - errors[:, 3:].mean(axis=0)
    lags = np.arange(1, max_lag + 1)
    c = np.array([np.mean(e[L:] * e[:-L], axis=0) for L in lags])  # (max_lag, 3)
    best = (np.inf, 0.5, np.zeros(3))
    for rho in np.linspace(0.2, 0.95, 76):  # a slow part outlives a frame pair
        g = rho**lags
        s2 = np.maximum(g @ c / (g @ g), 0.0)
        cost = float(np.sum((c - np.outer(g, s2)) ** 2))
        if cost < best[0]:
            best = (cost, float(rho), s2)
    _, rho, s2 = best
    sd = np.sqrt(s2)
    return (float(sd[0]), float(sd[1]), float(sd[2])), float(-dt / np.log(rho))
