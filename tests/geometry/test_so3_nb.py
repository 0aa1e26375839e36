"""The compiled SO(3) kernels against the vectorised numpy ones (the slow reference)."""

from __future__ import annotations

import numpy as np

from imuslam.geometry import so3
from imuslam.geometry.so3_nb import exp_nb, hat_nb, log_nb, right_jacobian_nb


def test_numba_kernels_equal_numpy() -> None:
    rng = np.random.default_rng(3)
    w = rng.normal(size=(500, 3))
    w /= np.linalg.norm(w, axis=1)[:, None]
    # angles from 0 to just below pi, including the Taylor branches
    ang = np.concatenate([[0.0, 1e-12, 1e-9, 1e-7, 1e-5, 1e-3], rng.uniform(0, np.pi - 1e-6, 494)])
    w *= ang[:, None]
    for k in range(len(w)):
        R = so3.exp(w[k])
        np.testing.assert_allclose(exp_nb(w[k]), R, atol=1e-15)
        np.testing.assert_allclose(hat_nb(w[k]), so3.hat(w[k]), atol=0)
        np.testing.assert_allclose(log_nb(R), so3.log(R), atol=1e-12)
        np.testing.assert_allclose(right_jacobian_nb(w[k]), so3.right_jacobian(w[k]), atol=1e-14)
    # near pi the log still recovers the axis (up to the sign ambiguity at exactly pi)
    a = np.array([0.3, -0.5, 0.81])
    a *= (np.pi - 1e-9) / np.linalg.norm(a)
    np.testing.assert_allclose(log_nb(so3.exp(a)), a, atol=1e-7)
