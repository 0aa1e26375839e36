"""The simulator against its own ground truth: IMU, LiDARs, stereo, odometry and the exported bag."""

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from imuslam.geometry import exp
from imuslam.io.load import load_imu
from imuslam.io.trajectory import read_tum
from imuslam.sim.imu import ImuErrorSpec, simulate_imu
from imuslam.sim.lidar import (
    Lidar2dConfig,
    Lidar3dConfig,
    cast_rays,
    cast_rays_reference,
    simulate_lidar2d_scan,
    simulate_lidar3d_scan,
)
from imuslam.sim.odometry import WheelConfig, simulate_wheels
from imuslam.sim.scenario import run_scenario
from imuslam.sim.stereo import R_B_C_FORWARD, StereoConfig, observe, triangulate
from imuslam.sim.trajectory import CarLoop, DiffDriveFigureEight, Handheld, Static
from imuslam.sim.world import (
    World,
    distance_to_surfaces,
    room_8x8,
    sample_surface_points,
    urban_block,
)

G = 9.80665


def test_ideal_imu_strapdown_reproduces_trajectory() -> None:
    """Trapezoidal integration of ideal samples at 400 Hz over 10 s. Its global velocity error is about
    T dt^2 / 12 max|a''| = 10 * 6.3e-6 / 12 * 5 = 3e-5 m/s, so position stays well within 1 mm; attitude by
    per-step rotation vectors of the mean rate is second-order: within 1e-5 rad."""
    traj = Handheld()
    rate = 400.0
    log, truth = simulate_imu(traj, 10.0, np.random.default_rng(0), ImuErrorSpec.ideal(), rate, g=G)
    dt = 1.0 / rate
    n = len(log)
    R = truth.R_w_i[0].copy()
    v = truth.vel_w[0].copy()
    p = truth.p_w[0].copy()
    g_w = np.array([0.0, 0.0, -G])
    Rs = np.empty((n, 3, 3))
    Rs[0] = R
    for k in range(n - 1):
        Rs[k + 1] = Rs[k] @ exp(0.5 * (log.gyro[k] + log.gyro[k + 1]) * dt)
    a_w = np.einsum("nij,nj->ni", Rs, log.accel) + g_w
    for k in range(n - 1):
        v_next = v + 0.5 * (a_w[k] + a_w[k + 1]) * dt
        p = p + 0.5 * (v + v_next) * dt
        v = v_next
    ang = np.linalg.norm(
        np.array([np.arccos(np.clip((np.trace(Rs[-1].T @ truth.R_w_i[-1]) - 1) / 2, -1, 1))])
    )
    assert ang < 1e-5
    assert np.linalg.norm(v - truth.vel_w[-1]) < 1e-3
    assert np.linalg.norm(p - truth.p_w[-1]) < 1e-3


def test_specific_force_at_rest_is_plus_g_up() -> None:
    log, _ = simulate_imu(Static(), 1.0, np.random.default_rng(0), rate_hz=100.0, g=G)
    np.testing.assert_allclose(log.accel, np.tile([0.0, 0.0, G], (len(log), 1)), atol=1e-12)
    np.testing.assert_allclose(log.gyro, 0.0, atol=1e-15)


def test_rotating_platform_modulates_a_constant_bias() -> None:
    """On a platform turning at 10 Hz about z, a constant sensor-frame gyro and accelerometer bias (measured
    = true + b) appears in the body frame as R_b_i b: its x/y part turns with the platform (amplitude
    |b_xy| at every sample) and averages to zero over whole turns, its z part stays; the platform rate itself
    appears on the sensor's z."""
    from imuslam.sim.imu_errors import TriadErrors

    b_g = np.array([0.01, -0.02, 0.005])
    b_a = np.array([0.05, 0.03, -0.04])
    spec = ImuErrorSpec(
        TriadErrors(np.eye(3), np.ones(3), b_a, "minus"),
        TriadErrors(np.eye(3), np.ones(3), b_g, "minus"),
    )
    log, truth = simulate_imu(
        Static(), 1.0, np.random.default_rng(0), spec, 1000.0, rotating_platform_hz=10.0
    )
    w_p = 2 * np.pi * 10
    assert np.mean(log.gyro[:-1, 2]) == pytest.approx(w_p + b_g[2], rel=1e-9)
    turns = slice(0, len(log) - 1)  # 1000 samples: exactly 10 turns
    for meas, b, true_b in (
        (log.gyro, b_g, np.array([0.0, 0.0, w_p])),
        (log.accel, b_a, [0.0, 0.0, G]),
    ):
        err_b = (
            np.einsum("nij,nj->ni", truth.R_b_i, meas) - true_b
        )  # the bias seen in the body frame
        np.testing.assert_allclose(
            np.linalg.norm(err_b[:, :2], axis=1), np.hypot(b[0], b[1]), rtol=1e-9
        )
        np.testing.assert_allclose(err_b[:, 2], b[2], atol=1e-12)
        np.testing.assert_allclose(err_b[turns, :2].mean(axis=0), 0.0, atol=1e-12)
        assert np.ptp(err_b[:, 0]) > 1.9 * np.hypot(b[0], b[1])  # modulated, not constant


def test_numba_ray_caster_matches_reference() -> None:
    world = urban_block()
    rng = np.random.default_rng(1)
    o = rng.uniform(-40, 40, size=(300, 3)) * [1, 1, 0] + [0, 0, 1.5]
    d = rng.normal(size=(300, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    a, ha = cast_rays(o, d, world.centre, world.u, world.v, world.half, 100.0)
    b, hb = cast_rays_reference(o, d, world, 100.0)
    np.testing.assert_array_equal(ha, hb)
    np.testing.assert_allclose(a[np.isfinite(a)], b[np.isfinite(b)], rtol=1e-12)


def _cast_rays_plain(
    o: np.ndarray, d: np.ndarray, world: World, max_range: float
) -> tuple[np.ndarray, np.ndarray]:
    """Every ray against every rectangle in index order, in Python floats: the arithmetic of
    :func:`cast_rays`' test of one ray against one rectangle."""
    c, u, v, h = (a.tolist() for a in (world.centre, world.u, world.v, world.half))
    dist, hit = np.full(len(o), np.inf), np.full(len(o), -1)
    for r, ((ox, oy, oz), (dx, dy, dz)) in enumerate(zip(o.tolist(), d.tolist(), strict=True)):
        best, bq = max_range, -1
        for q in range(len(c)):
            nx = u[q][1] * v[q][2] - u[q][2] * v[q][1]
            ny = u[q][2] * v[q][0] - u[q][0] * v[q][2]
            nz = u[q][0] * v[q][1] - u[q][1] * v[q][0]
            den = dx * nx + dy * ny + dz * nz
            if abs(den) < 1e-12:
                continue
            cx, cy, cz = c[q][0] - ox, c[q][1] - oy, c[q][2] - oz
            t = (cx * nx + cy * ny + cz * nz) / den
            if t <= 1e-9 or t >= best:
                continue
            px, py, pz = dx * t - cx, dy * t - cy, dz * t - cz
            if abs(px * u[q][0] + py * u[q][1] + pz * u[q][2]) > h[q][0]:
                continue
            if abs(px * v[q][0] + py * v[q][1] + pz * v[q][2]) > h[q][1]:
                continue
            best, bq = t, q
        if bq >= 0:
            dist[r], hit[r] = best, bq
    return dist, hit


@pytest.mark.parametrize("make_world", [room_8x8, urban_block])
def test_ray_caster_keeps_every_hit_of_all_rectangles_bit_for_bit(
    make_world: Callable[[], World],
) -> None:
    """:func:`cast_rays` tests only the rectangles within reach of each bundle of rays; its distances
    and rectangles equal testing every rectangle exactly: on LiDAR-like columns (16 beams from one
    origin, the origin moving), on rays aimed at rectangle corners and edge midpoints (equal
    distances to two rectangles), on random rays and with a short range."""
    world = make_world()
    rng = np.random.default_rng(2)
    el = np.deg2rad(np.arange(-15.0, 15.1, 2.0))
    az = np.linspace(0.0, 2 * np.pi, 24, endpoint=False)
    d_col = np.stack(
        [np.outer(np.cos(az), np.cos(el)), np.outer(np.sin(az), np.cos(el)),
         np.broadcast_to(np.sin(el), (az.size, el.size))], axis=-1,
    ).reshape(-1, 3)  # fmt: skip
    o_col = np.repeat(np.array([0.5, -0.3, 1.2]) + 0.05 * np.arange(az.size)[:, None], el.size, 0)
    o = rng.uniform(-3, 3, size=(160, 3)) * [1, 1, 0.3] + [0, 0, 1.2]
    q = rng.integers(0, len(world), 160)
    s = rng.choice([-1.0, 0.0, 1.0], size=(160, 2))
    corner = world.centre[q] + s[:, :1] * world.half[q, :1] * world.u[q]
    corner += s[:, 1:] * world.half[q, 1:] * world.v[q]
    d_aim = corner - o
    d_rand = rng.normal(size=(160, 3))
    origins = np.concatenate([o_col, o, o])
    dirs = np.concatenate([d_col, d_aim, d_rand])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    for max_range in (100.0, 4.0):
        a, ha = cast_rays(origins, dirs, world.centre, world.u, world.v, world.half, max_range)
        b, hb = _cast_rays_plain(origins, dirs, world, max_range)
        assert np.isfinite(b).sum() > 100
        np.testing.assert_array_equal(ha, hb)
        np.testing.assert_array_equal(a, b)


def _pose_fn(traj, dz: float):  # type: ignore[no-untyped-def]
    def pose(t):  # type: ignore[no-untyped-def]
        st = traj.state(t)
        return st.R_w_b, st.p_w + st.R_w_b @ np.array([0.0, 0.0, dz])

    return pose


def test_lidar_points_lie_on_surfaces_with_motion_distortion() -> None:
    """Noise-free: every point, moved to the world with the pose at its firing time, is on a surface;
    moved with the scan-start pose instead, points are off by up to the motion over one turn."""
    world = urban_block()
    traj = CarLoop()
    pose = _pose_fn(traj, 0.2)
    cfg = Lidar3dConfig(range_noise_std=0.0, columns=900)
    scan = simulate_lidar3d_scan(world, pose, 3.0, cfg, np.random.default_rng(0))
    assert len(scan.points_l) > 5000
    R, p = pose(3.0 + scan.t_offset_s.astype(float))
    pw = np.einsum("nij,nj->ni", R, scan.points_l.astype(float)) + p
    d = distance_to_surfaces(world, pw)
    # float32 points at up to 100 m carry ~4e-6 relative rounding
    assert np.median(d) < 1e-3 and np.max(d) < 1e-3
    R0, p0 = pose(np.array([3.0]))
    naive = scan.points_l.astype(float) @ R0[0].T + p0[0]
    speed = np.linalg.norm(traj.state([3.0]).vel_w)
    err = np.linalg.norm(naive - pw, axis=1)
    # a point fired late in the turn is displaced by up to speed * scan time (plus the turn's rotation)
    assert np.max(err) > 0.5 * speed * 0.1
    assert set(np.unique(scan.ring)) <= set(range(16))
    r = np.linalg.norm(scan.points_l, axis=1)
    assert r.min() >= cfg.min_range and r.max() <= cfg.max_range


def test_2d_scan_on_surfaces() -> None:
    world = room_8x8()
    traj = DiffDriveFigureEight()
    pose = _pose_fn(traj, 0.3)
    cfg = Lidar2dConfig(range_noise_std=0.0)
    s = simulate_lidar2d_scan(world, pose, 5.0, cfg, np.random.default_rng(0))
    assert len(s.ranges) == 800
    ok = np.isfinite(s.ranges)
    assert ok.mean() > 0.9  # the room is closed
    ang = s.angle_min + np.arange(len(s.ranges)) * s.angle_increment
    t = 5.0 + np.arange(len(s.ranges)) * s.time_increment
    R, p = pose(t)
    pl = np.stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)], axis=1) * s.ranges[
        :, None
    ].astype(float)
    pw = np.einsum("nij,nj->ni", R, pl) + p
    assert np.median(distance_to_surfaces(world, pw[ok])) < 1e-3


def test_stereo_observations_reproject_to_landmarks() -> None:
    world = room_8x8()
    rng = np.random.default_rng(2)
    lm, _ = sample_surface_points(world, 3000, rng)
    st = Handheld().state([4.0])
    R_w_c = st.R_w_b[0] @ R_B_C_FORWARD
    cfg = StereoConfig(pixel_noise=0.0)
    f = observe(lm, R_w_c, st.p_w[0], world, cfg, rng)
    assert len(f.ids) > 50
    pc = triangulate(f.uv_left, f.uv_right, cfg)
    np.testing.assert_allclose(pc @ R_w_c.T + st.p_w[0], lm[f.ids], atol=1e-9)
    z = pc[:, 2]
    np.testing.assert_allclose(
        f.uv_left[:, 0] - f.uv_right[:, 0], cfg.fx * cfg.baseline / z, rtol=1e-12
    )


def test_wheel_odometry_without_errors_follows_the_path() -> None:
    """Ideal encoders (no slip, no scale error): dead reckoning over 20 s stays within 2 cm (tick
    quantisation 0.24 mm per tick and the midpoint heading rule)."""
    traj = DiffDriveFigureEight()
    cfg = WheelConfig(scale_error=(0.0, 0.0), slip_std=0.0, ticks_per_rev=20000)
    wo = simulate_wheels(traj, 20.0, np.random.default_rng(0), cfg)
    st = traj.state(wo.t_s)
    assert np.max(np.linalg.norm(wo.pose_xy_yaw[:, :2] - st.p_w[:, :2], axis=1)) < 0.02


@pytest.mark.parametrize("scenario", ["room", "handheld", "gimbal", "street"])
def test_scenario_bag_reads_back(tmp_path: Path, scenario: str) -> None:
    dur = 1.0 if scenario == "street" else 3.0
    res = run_scenario(scenario, dur, tmp_path, seed=1, progress=False)
    with AnyReader([tmp_path / "bag"]) as r:
        topics = {c.topic: c for c in r.connections}
        assert "/imu/data" in topics and "/ground_truth" in topics
        for c, _, raw in r.messages(connections=[topics["/ground_truth"]]):
            assert r.deserialize(raw, c.msgtype).header.frame_id == "map"
            break
        if scenario == "street":
            c = topics["/points"]
            for _, _, raw in r.messages(connections=[c]):
                m = r.deserialize(raw, c.msgtype)
                assert [f.name for f in m.fields] == ["x", "y", "z", "intensity", "t", "ring"]
                assert [f.datatype for f in m.fields] == [7, 7, 7, 7, 7, 4]
                assert m.header.frame_id == "lidar_link" and m.width * m.point_step == len(m.data)
                break
        if scenario == "room":
            c = topics["/scan"]
            for _, _, raw in r.messages(connections=[c]):
                m = r.deserialize(raw, c.msgtype)
                assert m.range_max == pytest.approx(12.0) and m.angle_increment == pytest.approx(
                    np.deg2rad(0.45)
                )
                break
    imu = load_imu(tmp_path / "bag", topic="/imu/data")
    # units m/s^2: the typical specific-force magnitude is g (within the 0.3 % scale errors and motion)
    assert np.median(np.linalg.norm(imu.accel, axis=1)) == pytest.approx(G, rel=0.05)
    gt = read_tum(tmp_path / "ground_truth.tum")
    assert len(gt) > 10 and res.counts["messages"] > len(imu)
    assert (tmp_path / "sim.npz").exists()
