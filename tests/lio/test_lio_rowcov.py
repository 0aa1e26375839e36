"""The LiDAR rows' noise model with the frozen map's shared point noise (``lio.rowcov``,
``filter.lidar_model: plane``)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from imuslam.lio.matcher import LocalMap, MatchParams
from imuslam.lio.residuals import fit_planes_reference
from imuslam.lio.rowcov import SensorOrigins, associate_shared, whitened_system


def test_whitened_system_is_the_generalised_least_squares_one() -> None:
    """U^T U = J^T R^-1 J and U^T z = J^T R^-1 r with R = diag(D) + G G^T, against a dense inverse."""
    rng = np.random.default_rng(3)
    M, N = 40, 15
    J, r = rng.normal(size=(M, 6)), rng.normal(size=M)
    D = rng.uniform(0.5, 2.0, M)
    Gd = np.where(rng.uniform(size=(M, N)) < 0.2, rng.normal(size=(M, N)), 0.0)
    U, z = whitened_system(r, J, D, sp.csr_matrix(Gd))
    Rinv = np.linalg.inv(np.diag(D) + Gd @ Gd.T)
    np.testing.assert_allclose(U.T @ U, J.T @ Rinv @ J, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(U.T @ z, J.T @ Rinv @ r, rtol=1e-9, atol=1e-9)


def test_plane_fit_error_and_its_sharing_match_monte_carlo() -> None:
    """Two scan points fitted to the same 5 map points on the plane z = 0, each map point measured by
    a beam from 10 m above with 2 cm range noise: the first-order covariance of the two rows' plane-fit
    errors (G G^T) against 20000 draws of the points' noise refitted by eigen-decomposition. The
    sampled variances' relative 1-sigma is sqrt(2 / n) = 1 %; bound 5 %, which also covers the
    first-order model's neglect of the noise's tilt of the fit (2 cm over 0.4 m)."""
    pts = np.array([[0.0, 0.0, 0.0], [0.4, 0.05, 0.0], [-0.35, 0.3, 0.0], [0.1, -0.4, 0.0],
                    [-0.2, -0.25, 0.0]])  # fmt: skip
    lmap = LocalMap(0.5, 100.0, 5, "ivox", MatchParams(k=5))
    lmap.insert(pts, np.zeros((0, 3)), np.eye(3), np.zeros(3), tag=0)
    origins = SensorOrigins()
    origins.record(0, np.array([0.0, 0.0, 10.0]))
    q = np.array([[0.05, 0.02, 0.0], [0.3, -0.1, 0.0]])
    sigma = 0.02
    corr, s, G = associate_shared(lmap, q, np.zeros((0, 3)), np.eye(3), np.zeros(3), 0.1,
                                  np.array([0.0, 0.0, 10.0]), origins, sigma)  # fmt: skip
    assert len(corr) == 2 and G.shape == (2, 5)
    np.testing.assert_allclose(s, sigma, rtol=1e-3)  # the beam nearly along the normal
    C_pred = (G @ G.T).toarray()
    rng = np.random.default_rng(1)
    n_draw = 20000
    b = (pts - [0.0, 0.0, 10.0]) / np.linalg.norm(pts - [0.0, 0.0, 10.0], axis=1)[:, None]
    noisy = pts[None] + rng.normal(size=(n_draw, 5, 1)) * sigma * b[None]
    n, c = fit_planes_reference(np.arange(n_draw * 5).reshape(n_draw, 5), noisy.reshape(-1, 3))
    r = np.stack([np.einsum("mk,mk->m", n, qi - c) for qi in q], axis=1)
    C_mc = np.cov(r.T)
    assert C_pred[0, 1] > 0.2 * np.sqrt(C_pred[0, 0] * C_pred[1, 1])  # shared: strongly correlated
    np.testing.assert_allclose(np.diag(C_mc), np.diag(C_pred), rtol=0.05)
    corr_mc = C_mc[0, 1] / np.sqrt(C_mc[0, 0] * C_mc[1, 1])
    corr_pred = C_pred[0, 1] / np.sqrt(C_pred[0, 0] * C_pred[1, 1])
    assert corr_mc == pytest.approx(corr_pred, abs=0.03)
