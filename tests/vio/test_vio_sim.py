"""VIO on the rendered ground robot (short runs; the 3-minute study is ``bench/vio.py sim``), the
renderer against a slow reference, and the wheel-odometry EKF on the real Husky bag against GPS."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from imuslam.eval.vio_compare import compare_tracks
from imuslam.sim.render import CameraRig, pixel_bbox, render_image, render_stereo
from imuslam.sim.stereo_run import SimStereoRun, StereoRunConfig
from imuslam.sim.world import room_8x8
from imuslam.vio.config import VioConfig
from imuslam.vio.frontend import VoConfig
from imuslam.vio.pipeline import compute_vo, run_vio


def _ray_depth_ref(
    world, rig: CameraRig, R_w_c: np.ndarray, p: np.ndarray, u: int, v: int
) -> float:  # type: ignore[no-untyped-def]
    """z-depth of pixel (u, v): the nearest rectangle hit along its ray, by plain numpy."""
    d = R_w_c @ np.array([(u - rig.cx) / rig.fx, (v - rig.cy) / rig.fy, 1.0])
    n = np.cross(world.u, world.v)
    den = n @ d
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.einsum("qk,qk->q", n, world.centre - p) / den
    h = p + t[:, None] * d - world.centre
    inside = (np.abs(np.einsum("qk,qk->q", h, world.u)) <= world.half[:, 0]) & (
        np.abs(np.einsum("qk,qk->q", h, world.v)) <= world.half[:, 1]
    )
    ok = inside & (t > 1e-6) & np.isfinite(t)
    return float(t[ok].min()) if ok.any() else np.inf


def test_renderer_depth_equals_reference() -> None:
    world, rig = room_8x8(), CameraRig()
    from imuslam.geometry import exp
    from imuslam.sim.stereo import R_B_C_FORWARD

    R = exp(np.array([0.1, -0.2, 0.7])) @ R_B_C_FORWARD  # a tilted forward-looking camera
    p = np.array([0.5, -1.0, 0.6])
    _, _, depth = render_stereo(world, rig, R, p)
    assert np.isfinite(depth).mean() > 0.5
    rng = np.random.default_rng(0)
    for u, v in zip(rng.integers(0, rig.width, 60), rng.integers(0, rig.height, 60), strict=True):
        assert depth[v, u] == pytest.approx(
            _ray_depth_ref(world, rig, R, p, int(u), int(v)), rel=1e-9
        )
    assert pixel_bbox(world, rig, R, p).shape == (len(world), 4) and render_image is not None


def _body_velocity(run: SimStereoRun, t_s: np.ndarray) -> np.ndarray:
    st = run.traj.state(t_s)
    return np.einsum("nji,nj->ni", st.R_w_b, st.vel_w)


def test_sim_robot_obeys_the_nhc_it_is_filtered_with() -> None:
    """The filter's NHC says the body origin (``vehicle_p_b`` 0, vehicle frame = body) has no lateral
    or vertical velocity. The ground-following robot obeys it to rounding; seed 000's figure eight,
    whose velocity stays horizontal while the body pitches by 0.005 rad, violates the vertical one by
    speed x pitch (about 0.4 m/s x 0.005 / sqrt(2) = 1.4e-3 m/s RMS): that robot fails this test."""
    t = np.arange(0.0, 180.0, 0.01)
    run = SimStereoRun(StereoRunConfig(duration_s=1.0))
    vb = _body_velocity(run, t)
    assert np.sqrt(np.mean(vb[:, 1:] ** 2, axis=0)).max() < 1e-9
    assert np.mean(vb[:, 0]) > 0.25  # it does drive forward
    # position, velocity and acceleration agree (central differences, step 1e-4 s: error ~1e-8)
    tt, h = t[::50] + 0.5, 1e-4
    s0, sp, sm = (run.traj.state(x) for x in (tt, tt + h, tt - h))
    np.testing.assert_allclose((sp.p_w - sm.p_w) / (2 * h), s0.vel_w, atol=1e-7)
    np.testing.assert_allclose((sp.vel_w - sm.vel_w) / (2 * h), s0.acc_w, atol=1e-6)
    assert np.ptp(s0.p_w[:, 2]) < 0.005  # the rise and sink stay millimetres
    flat = SimStereoRun(StereoRunConfig(duration_s=1.0, ground_following=False))
    vz = np.sqrt(np.mean(_body_velocity(flat, t)[:, 2] ** 2))
    assert 0.5e-3 < vz < 2e-3


@pytest.fixture(scope="module")
def short_run():  # type: ignore[no-untyped-def]
    run = SimStereoRun(StereoRunConfig(duration_s=3.0, image_hz=10.0, seed=3))
    return run, compute_vo(run, VoConfig())


def test_gate_rejects_injected_vo_outliers(short_run) -> None:  # type: ignore[no-untyped-def]
    """30 % of the VO measurements corrupted by 0.1-0.5 m/s and 0.02-0.1 rad/s: the 99.9 % gate rejects
    every corrupted velocity (the VO's sigma is below 0.01 m/s) and no good one (expected 0.001 x 29)."""
    run, vo_run = short_run
    res = run_vio(run, VioConfig(nhc=True, outlier_fraction=0.3, outlier_seed=1), vo_run=vo_run)
    o = res.summary()["outliers"]
    assert o["corrupted"] >= 5
    assert o["corrupted_rejected"] == o["corrupted"]
    assert o["good_rejected"] == 0


def test_vo_alone_reads_the_same_corrupted_measurements(short_run) -> None:  # type: ignore[no-untyped-def]
    """A corrupted VO measurement is one failure for every reader: the relative pose VO alone chains is
    the clean one moved by the injected rate and velocity errors over the pair (exp([dw dt, dv dt])), and
    the clean pairs are chained untouched (to rounding)."""
    from imuslam.geometry.se3 import exp as se3_exp

    run, vo_run = short_run
    res = run_vio(run, VioConfig(nhc=True, outlier_fraction=0.3, outlier_seed=1), vo_run=vo_run)
    clean = {m.t0_ns: m for _, m in vo_run.frames if m is not None}
    T = np.zeros((len(res.vo), 4, 4))
    T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = res.vo.R_w_b, res.vo.p_w, 1.0
    index = {int(t): i for i, t in enumerate(res.vo.t_ns)}
    checked = 0
    for m, bad in zip(res.vo_measurements, res.corrupted, strict=True):
        i0, i1 = index[m.t0_ns], index[m.t1_ns]
        rel = np.linalg.inv(T[i0]) @ T[i1]
        c = clean[m.t0_ns]
        want = c.T_b0_b1 @ se3_exp(np.r_[m.omega_b - c.omega_b, m.vel_b - c.vel_b] * m.dt)
        np.testing.assert_allclose(rel, want, atol=1e-9)
        if bad:
            assert np.linalg.norm(m.vel_b - c.vel_b) >= 0.1  # the injected velocity error, m/s
            checked += 1
    assert checked >= 5


def test_fused_follows_the_truth(short_run) -> None:  # type: ignore[no-untyped-def]
    """3 s at 0.3-0.4 m/s: the fused track stays within 2 cm of the truth (VO velocity noise ~1 cm/s
    integrated over 3 s), and beats the IMU alone (a 0.05 m/s^2 accelerometer bias)."""
    run, vo_run = short_run
    res = run_vio(run, VioConfig(nhc=True), vo_run=vo_run)
    ev = compare_tracks(
        run.truth(), {"fused": res.fused, "vo": res.vo, "imu": res.imu}, run.t_frames_ns
    )
    assert ev["fused"].ape_trans.rmse < 0.02
    assert ev["fused"].ape_trans.rmse < ev["imu"].ape_trans.rmse


@pytest.mark.slow
def test_wheel_ekf_on_the_husky_against_gps(shared_data: Path) -> None:
    """robot_localization's Husky (395 m, 989 GPS fixes): with the non-holonomic constraint the IMU +
    wheel EKF tracks GPS better than without it (the lateral velocity is otherwise free) and better
    than the wheel odometry alone (horizontal ATE, 4-DoF aligned; GPS itself has about 0.9 m sigma)."""
    from imuslam.vio.wheel import husky_study

    ate = husky_study(shared_data / "robot_localization_husky" / "test1.bag")
    with_nhc = ate["IMU + wheel EKF + NHC"]
    assert with_nhc < ate["IMU + wheel EKF"]
    assert with_nhc < ate["wheel odometry alone"]
