"""VO measurements made from a simulated run's truth (no rendering): the filter's input when the front end
is not what is being studied (filter speed, compiled against reference)."""

from __future__ import annotations

import numpy as np

from imuslam.geometry import exp, log
from imuslam.sim.stereo_run import SimStereoRun
from imuslam.vio.frontend import VoMeasurement, VoStats
from imuslam.vio.pipeline import VoRun


def truth_vo_run(
    run: SimStereoRun, sigma_v: float, sigma_w: float, seed: int, skip_every: int = 7
) -> VoRun:
    """Per frame pair of ``run``: the true mean body rate (rad/s) and mid-interval body velocity (m/s)
    plus white noise of 1-sigma ``sigma_w`` / ``sigma_v`` (that diagonal as covariance); every
    ``skip_every``-th frame gives None, as the front end does for a frame with too few features."""
    rng = np.random.default_rng(seed)
    tr = run.truth(run.t_frames_ns)
    frames: list[tuple[int, VoMeasurement | None]] = []
    cov = np.diag([sigma_w**2] * 3 + [sigma_v**2] * 3)
    for k, t in enumerate(run.t_frames_ns):
        if k == 0 or (skip_every > 0 and k % skip_every == 0):
            frames.append((int(t), None))
            continue
        t0 = int(run.t_frames_ns[k - 1])
        R01 = tr.R_w_b[k - 1].T @ tr.R_w_b[k]
        p01 = tr.R_w_b[k - 1].T @ (tr.p_w[k] - tr.p_w[k - 1])
        dt = (int(t) - t0) * 1e-9
        rot = log(R01)
        vel = exp(-0.5 * rot) @ p01 / dt  # displacement seen from mid-interval, as the front end
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R01, p01
        frames.append((int(t), VoMeasurement(
            t0, int(t), rot / dt + rng.normal(0, sigma_w, 3), vel + rng.normal(0, sigma_v, 3),
            cov.copy(), T, 50)))  # fmt: skip
    return VoRun(frames, VoStats(), len(frames), 0)
