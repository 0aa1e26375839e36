"""``vo_model: relative``: each VO pair read against a clone of the pose at its start (stochastic
cloning). The measurements' Jacobians against finite differences over the current and the cloned
error states (the Python reference's, vio_reference.py, and the compiled models of vio/kernels.py
against them), and the filter on VO made from the simulator's truth plus white noise of a known
covariance: consistent (NIS) and better than the VO alone."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2
from vio_reference import (
    VoClone,
    VoRelativeRotation,
    VoRelativeTranslation,
    VoRelativeTranslationGivenRotation,
)

from imuslam.eval.vio_compare import compare_tracks
from imuslam.geometry import exp, log
from imuslam.ins.core import ErrorLayout, InsState
from imuslam.sim.stereo_run import SimStereoRun, StereoRunConfig
from imuslam.vio.config import VioConfig
from imuslam.vio.kernels import relative_rotation, relative_translation
from imuslam.vio.pipeline import run_vio
from imuslam.vio.simvo import truth_vo_run


def _perturbed(
    x: InsState, c: VoClone, lay: ErrorLayout, dx: np.ndarray
) -> tuple[InsState, VoClone]:
    o = c.offset
    x2 = InsState(x.p_n + dx[lay.P], x.v_n + dx[lay.V], x.R_n_b @ exp(dx[lay.TH]), x.accel_bias,
                  x.gyro_bias + dx[lay.BG], x.g_n)  # fmt: skip
    return x2, VoClone(c.R_n_b @ exp(dx[o : o + 3]), c.p_n + dx[o + 3 : o + 6], o)


def test_relative_measurement_jacobians() -> None:
    """Each residual falls by ``H dx`` for a small error ``dx`` of any state it reads, the clone's
    included, and reads no other."""
    rng = np.random.default_rng(11)
    lay = ErrorLayout(True, True, False, extra=6)
    assert lay.dim == 21 and lay.base_dim == 15
    x = InsState(rng.normal(size=3), rng.normal(size=3), exp(rng.normal(size=3)), np.zeros(3),
                 rng.normal(size=3) * 0.01, np.array([0.0, 0.0, -9.81]))  # fmt: skip
    clone = VoClone(x.R_n_b @ exp(rng.normal(size=3) * 0.05), x.p_n - rng.normal(size=3) * 0.1, 15)
    # measurements near the states' prediction (residuals of the size VO noise makes: the Jacobians
    # are first order in the residual)
    dt = 0.2
    w = log(clone.R_n_b.T @ x.R_n_b) / dt + rng.normal(size=3) * 1e-4
    v = exp(-0.5 * w * dt) @ clone.R_n_b.T @ (x.p_n - clone.p_n) / dt + rng.normal(size=3) * 1e-3
    A = rng.normal(size=(6, 6))
    C = A @ A.T * 1e-4 + np.eye(6) * 1e-5
    meas = [
        VoRelativeRotation(w, C[:3, :3], dt, clone),
        VoRelativeTranslation(v, C[3:, 3:], w, dt, clone),
        VoRelativeTranslationGivenRotation(v, w, C[:3, :3], C[:3, 3:], C[3:, 3:], dt, clone),
    ]
    eps = 1e-7
    for m in meas:
        r, H, Rm = m.linearize(x, lay)
        assert np.all(np.linalg.eigvalsh(Rm) > 0)
        for j in range(lay.dim):
            dx = np.zeros(lay.dim)
            dx[j] = eps
            x2, c2 = _perturbed(x, clone, lay, dx)
            m.clone = c2
            r2 = m.linearize(x2, lay)[0]
            m.clone = clone
            np.testing.assert_allclose(
                (r - r2) / eps, H[:, j], atol=2e-3, err_msg=f"{m.kind} col {j}"
            )
    # the compiled models: the same residuals and Jacobian blocks
    r_w, H_w, Rm_w = meas[0].linearize(x, lay)
    r_v, H_v, _ = meas[1].linearize(x, lay)
    r, H_th, H_cth, Jr = relative_rotation(w, dt, clone.R_n_b, np.ascontiguousarray(x.R_n_b))
    np.testing.assert_allclose(r, r_w, rtol=0, atol=1e-12)
    np.testing.assert_allclose(H_th, H_w[:, lay.TH], rtol=0, atol=1e-12)
    np.testing.assert_allclose(H_cth, H_w[:, 15:18], rtol=0, atol=1e-12)
    np.testing.assert_allclose(Jr @ C[:3, :3] @ Jr.T, Rm_w, rtol=1e-12, atol=0)
    r, H_p, H_cth = relative_translation(v, w, dt, clone.R_n_b, clone.p_n, x.p_n)
    np.testing.assert_allclose(r, r_v, rtol=0, atol=1e-12)
    np.testing.assert_allclose(H_p, H_v[:, lay.P], rtol=0, atol=1e-12)
    np.testing.assert_allclose(-H_p, H_v[:, 18:21], rtol=0, atol=1e-12)
    np.testing.assert_allclose(H_cth, H_v[:, 15:18], rtol=0, atol=1e-12)


@pytest.fixture(scope="module")
def white_vo_case():  # type: ignore[no-untyped-def]
    run = SimStereoRun(StereoRunConfig(duration_s=30.0, image_hz=10.0, seed=7))
    return run, truth_vo_run(run, 0.01, 0.003, seed=4)


@pytest.mark.parametrize("nhc", [False, True])
def test_relative_filter_is_consistent(white_vo_case, nhc) -> None:  # type: ignore[no-untyped-def]
    """White VO noise of the covariance the filter is told: the mean NIS of both VO kinds inside the
    99 % chi-square band of their mean (3 dof over n accepted updates), at most one good measurement
    rejected (the gate's 0.01 % of some 270), and the track within 5 cm of the truth."""
    run, vo_run = white_vo_case
    res = run_vio(run, VioConfig(vo_model="relative", nhc=nhc, nhc_std=0.002), vo_run=vo_run)
    for kind in ("vo_rate", "vo_velocity"):
        st = res.gating[kind]
        nis = np.asarray(st.nis)[np.asarray(st.accepted_mask, bool)]
        n = len(nis)
        lo, hi = chi2.ppf([0.005, 0.995], 3 * n) / n
        assert lo <= nis.mean() <= hi, (kind, nis.mean(), lo, hi)
        assert st.rejected <= 1
    ev = compare_tracks(run.truth(), {"fused": res.fused}, run.t_frames_ns)
    assert ev["fused"].ape_trans.rmse < 0.05
