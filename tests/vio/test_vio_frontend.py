"""Stereo VO front end: ZNCC kernels against references, calibration and rectification, the EuRoC
reader's counts and errors, and the VO's velocity against rendered ground truth."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from imuslam.errors import InputError
from imuslam.io.camcalib import Rectification, read_calibration, read_kalibr_camchain
from imuslam.io.stereosets import EurocStereo
from imuslam.sim.render import CameraRig, render_stereo
from imuslam.sim.stereo_run import SimStereoRun, StereoRunConfig
from imuslam.sim.world import room_8x8
from imuslam.vio.frontend import StereoVO, VoConfig
from imuslam.vio.zncc import (
    _zncc_pair,
    disparity_slopes,
    slanted_disparity,
    stereo_match,
    stereo_match_ref,
    track,
    zncc_ref,
)

EUROC = "euroc_V1_01_micro_kimera"


def _texture(rng: np.random.Generator, h: int = 120, w: int = 200) -> np.ndarray:
    import cv2

    img = rng.uniform(0, 255, size=(h // 4, w // 4)).astype(np.float32)
    return cv2.resize(img, (w, h), interpolation=cv2.INTER_CUBIC)


def test_stereo_match_equals_reference_and_true_shift() -> None:
    rng = np.random.default_rng(0)
    left = _texture(rng)
    shift = 17
    right = np.zeros_like(left)
    right[:, :-shift] = left[:, shift:]  # right(u) = left(u + d): disparity d
    uv = np.array([[100.0, 40.0], [150.0, 60.0], [80.0, 90.0]])
    d, s = stereo_match(left, right, uv, 5, np.full(3, 2.0), np.full(3, 40.0), 0.5, 0.99)
    assert np.allclose(d, shift, atol=0.05)
    for (u, v), di, si in zip(uv.astype(int), d, s, strict=True):
        bd, bs = stereo_match_ref(left, right, int(u), int(v), 5, 2, 40)
        assert bd == round(di)
        assert bs == pytest.approx(si, abs=1e-5)
    patch = left[10:21, 30:41]
    assert zncc_ref(patch, 3.0 * patch + 7.0) == pytest.approx(1.0)


def test_subpixel_zncc_pair_equals_reference() -> None:
    """The compiled sub-pixel ZNCC (bilinear weights once per patch) against scipy's order-1
    interpolation of both patches and the numpy ZNCC."""
    from scipy.ndimage import map_coordinates

    rng = np.random.default_rng(7)
    a = rng.uniform(0, 255, (40, 50)).astype(np.float32)
    b = rng.uniform(0, 255, (40, 50)).astype(np.float32)
    h = 5
    d = np.arange(-h, h + 1)
    for _ in range(50):
        ua, va, ub, vb = rng.uniform(8, 30, 4)
        pa = map_coordinates(
            a.astype(float), [va + d[:, None] + 0 * d, ua + d[None] + 0 * d[:, None]], order=1
        )
        pb = map_coordinates(
            b.astype(float), [vb + d[:, None] + 0 * d, ub + d[None] + 0 * d[:, None]], order=1
        )
        assert _zncc_pair(a, ua, va, b, ub, vb, h) == pytest.approx(zncc_ref(pa, pb), abs=1e-9)
        assert _zncc_pair(a, ua, va, a, ua, va, h) == pytest.approx(1.0, abs=1e-12)


def test_track_recovers_a_known_shift() -> None:
    import cv2

    rng = np.random.default_rng(1)
    prev = _texture(rng, 160, 240)
    du, dv = 9, -6
    cur = np.roll(np.roll(prev, dv, axis=0), du, axis=1)
    uv = np.array([[100.0, 70.0], [140.3, 90.6], [60.0, 100.0]])
    out, score = track(
        prev, cv2.pyrDown(prev), cur, cv2.pyrDown(cur), uv, uv.copy(), 5, 3, 8, 2, 0.8
    )
    assert np.all(score > 0.95)
    assert np.allclose(out - uv, [du, dv], atol=0.1)


def test_track_through_a_known_affine_map() -> None:
    """A patch that grows by 12 % and shears between the frames (what a near floor patch does when the
    robot drives toward it): given the affine map, the tracker compares the patches in one geometry and
    lands within 0.03 px of the true position (the sub-pixel bias on exact shifts is up to 0.02 px);
    as a pure shift it is off by several times that."""
    import cv2

    rng = np.random.default_rng(11)
    prev = _texture(rng, 240, 320)
    A = np.array([[1.12, 0.06], [-0.03, 1.10]])
    c = np.array([-14.0, -11.0])
    # cur(A p + c) = prev(p)
    cur = cv2.warpAffine(prev, np.c_[A, c], (320, 240), flags=cv2.INTER_CUBIC)
    uv = np.stack([rng.uniform(90, 230, 40), rng.uniform(70, 160, 40)], axis=1)
    true = uv @ A.T + c
    args = (prev, cv2.pyrDown(prev), cur, cv2.pyrDown(cur), uv, true.round(), 5, 3, 8, 2, 0.5)
    warped, _ = track(*args, np.broadcast_to(A, (40, 2, 2)))
    shifted, _ = track(*args)
    err_w = np.linalg.norm(warped - true, axis=1)
    err_s = np.linalg.norm(shifted - true, axis=1)
    assert np.all(np.isfinite(err_w)) and np.sqrt(np.mean(err_w**2)) < 0.03
    assert np.sqrt(np.nanmean(err_s**2)) > 3 * np.sqrt(np.mean(err_w**2))


def test_affine_map_is_the_planes_homography_jacobian() -> None:
    """The front end's per-point map from previous to current pixel offsets equals the motion of
    neighbouring points of the surface, carried through 3D by hand (back-project onto the plane,
    move, project)."""
    rig = CameraRig()
    rect = Rectification(rig.K, rig.baseline, rig.width, rig.height, np.eye(3), np.zeros(3))
    vo = StereoVO(rect, VoConfig())
    th = 0.05
    R = np.array([[np.cos(th), 0, np.sin(th)], [0, 1, 0], [-np.sin(th), 0, np.cos(th)]])
    T = np.eye(4)
    # T_{r_k, r_k-1}: turning, driving forward
    T[:3, :3], T[:3, 3] = R, [0.02, -0.01, -0.15]
    # a floor 0.4 m below, a slanted wall
    m = np.array([[0.0, 1 / 0.4, 0.0], [0.1, -0.05, 1 / 3.0]])
    uv = np.array([[300.0, 400.0], [420.0, 200.0]])
    A = vo._affine(uv, m, T)
    assert A is not None
    Kinv = np.linalg.inv(rig.K)

    def move(p: np.ndarray, mi: np.ndarray) -> np.ndarray:
        ray = Kinv @ np.r_[p, 1.0]
        X = ray / (mi @ ray)
        y = rig.K @ (R @ X + T[:3, 3])
        return y[:2] / y[2]

    for i in range(2):
        eps = 1e-3
        J = np.stack([(move(uv[i] + e, m[i]) - move(uv[i] - e, m[i])) / (2 * eps)
                      for e in (np.array([eps, 0.0]), np.array([0.0, eps]))], axis=1)  # fmt: skip
        assert np.allclose(A[i], J, atol=1e-6)
        assert np.abs(A[i] - np.eye(2)).max() > 0.02  # the maps are not close to a pure shift


def _floor_view(noise: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The rendered robot's stereo pair at 0.7 s (the floor fills the rows below 280), blurred as the
    VO blurs it, with the exact depth; and f b."""
    import cv2

    run = SimStereoRun(StereoRunConfig(duration_s=2.0, image_hz=5.0, seed=5))
    rig = CameraRig(noise=noise)
    st = run.traj.state(np.array([0.7]))
    R = st.R_w_b[0] @ run.R_b_c
    left, right, depth = render_stereo(run.world, rig, R, st.p_w[0] + st.R_w_b[0] @ run.p_b_c,
                                       np.random.default_rng(5))  # fmt: skip
    lf, rf = (cv2.GaussianBlur(x.astype(np.float32), (0, 0), 1.0) for x in (left, right))
    return lf, rf, depth, rig.fx * rig.baseline


def test_slanted_window_removes_the_floors_disparity_error() -> None:
    """On the floor ahead the disparity grows by about 0.2 px per row, so a straight 11 x 11 window
    matches a sheared patch. Noise-free, with the exact slopes, the slanted window's median error falls
    from above 0.2 px to below 0.05; with the image noise (2 grey levels) and the slopes measured by
    :func:`disparity_slopes` it still falls by a quarter or more."""
    rng = np.random.default_rng(6)
    uv = np.stack([rng.uniform(100, 650, 400), rng.uniform(280, 400, 400)], axis=1).round()
    iu, iv = uv[:, 0].astype(int), uv[:, 1].astype(int)
    for noise in (0.0, 2.0):
        lf, rf, depth, fb = _floor_view(noise)
        d_true = fb / depth[iv, iu]
        true = np.stack([(fb / depth[iv, iu + 3] - fb / depth[iv, iu - 3]) / 6,
                         (fb / depth[iv + 3, iu] - fb / depth[iv - 3, iu]) / 6], axis=1)  # fmt: skip
        d, _ = stereo_match(lf, rf, uv, 5, np.maximum(d_true - 10, 2), d_true + 10, 0.8, 0.97)
        ok = np.isfinite(d)
        assert ok.sum() > 100 and np.median(true[ok, 1]) > 0.15
        straight = np.median(np.abs(d[ok] - d_true[ok]))
        slopes = disparity_slopes(lf, rf, uv, d, 5, 3)
        if noise == 0.0:
            exact = slanted_disparity(lf, rf, uv, d, true, 5)
            print(f"noise-free: median |error| straight {straight:.3f} px, slanted by the exact "
                  f"slopes {np.nanmedian(np.abs(exact - d_true)):.3f} px")  # fmt: skip
            assert straight > 0.2
            assert np.nanmedian(np.abs(exact - d_true)) < 0.05
        else:
            fin = ok & np.isfinite(slopes).all(axis=1)
            assert fin.sum() > 0.7 * ok.sum()
            assert np.median(np.abs(slopes[fin] - true[fin])) < 0.1
            slanted = slanted_disparity(lf, rf, uv, d, slopes, 5)
            print(f"noise 2: median |error| straight {straight:.3f} px, slanted by the measured "
                  f"slopes {np.nanmedian(np.abs(slanted[ok] - d_true[ok])):.3f} px")  # fmt: skip
            assert np.nanmedian(np.abs(slanted[ok] - d_true[ok])) < 0.75 * straight


def test_rendered_disparity_matches_depth() -> None:
    """On a rendered pair (noise 2 grey levels, blurred with sigma 1 px as the VO does) the matched
    disparity equals f b / z of the exact depth: median error below 0.03 px (no half-pixel pull), 90 %
    within 0.25 px."""
    import cv2

    rig = CameraRig(noise=2.0)
    R_w_c = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    left, right, depth = render_stereo(room_8x8(), rig, R_w_c, np.array([-1.0, 0.3, 1.2]),
                                       np.random.default_rng(2))  # fmt: skip
    rng = np.random.default_rng(3)
    uv = np.stack([rng.uniform(150, 700, 200), rng.uniform(30, 450, 200)], axis=1).round()
    lf, rf = (cv2.GaussianBlur(x.astype(np.float32), (0, 0), 1.0) for x in (left, right))
    d, _ = stereo_match(lf, rf, uv, 5, np.full(200, 2.0), np.full(200, 120.0), 0.9, 0.97)
    z = depth[uv[:, 1].astype(int), uv[:, 0].astype(int)]
    ok = np.isfinite(d)
    assert ok.sum() > 100
    err = d[ok] - rig.fx * rig.baseline / z[ok]
    assert abs(np.median(err)) < 0.03
    assert np.mean(np.abs(err) < 0.25) > 0.9


def test_euroc_calibration_rectifies_epipolar_lines_to_rows(shared_data: Path) -> None:
    import cv2

    cal = read_calibration(shared_data / EUROC)
    rect = cal.rectification()
    assert rect.baseline == pytest.approx(0.110, abs=0.002)  # EuRoC's VI-sensor, about 11 cm
    # project random points with the raw (distorted) cameras, rectify the pixels: same row in both
    rng = np.random.default_rng(4)
    p_c0 = np.stack([rng.uniform(-1, 1, 50), rng.uniform(-0.7, 0.7, 50), rng.uniform(2, 6, 50)], 1)
    T_c1_c0 = np.linalg.inv(cal.right.T_b_c) @ cal.left.T_b_c
    rows = []
    for cam, T in ((cal.left, np.eye(4)), (cal.right, T_c1_c0)):
        rv, _ = cv2.Rodrigues(T[:3, :3])
        px, _ = cv2.projectPoints(p_c0, rv, T[:3, 3].copy(), cam.K, cam.dist)
        rows.append(px.reshape(-1, 2))
    import cv2 as _cv

    T = T_c1_c0
    R1, R2, P1, P2, *_ = _cv.stereoRectify(cal.left.K, cal.left.dist, cal.right.K, cal.right.dist,
                                          (752, 480), T[:3, :3].copy(), T[:3, 3].reshape(3, 1).copy(),
                                          flags=_cv.CALIB_ZERO_DISPARITY, alpha=0)  # fmt: skip
    ul = _cv.undistortPoints(rows[0].reshape(-1, 1, 2), cal.left.K, cal.left.dist, R=R1, P=P1)
    ur = _cv.undistortPoints(rows[1].reshape(-1, 1, 2), cal.right.K, cal.right.dist, R=R2, P=P2)
    assert np.max(np.abs(ul[:, 0, 1] - ur[:, 0, 1])) < 0.05
    assert np.allclose(P1[:, :3], rect.K)
    # rectified left z-depth from disparity equals the true depth rotated into the rectified frame
    z_r = (p_c0 @ R1.T)[:, 2]
    disp = ul[:, 0, 0] - ur[:, 0, 0]
    assert np.allclose(rect.f * rect.baseline / disp, z_r, rtol=2e-3)  # undistortPoints iterates


def test_kalibr_camchain_matches_euroc(shared_data: Path, tmp_path: Path) -> None:
    cal = read_calibration(shared_data / EUROC)

    def entry(cam, T_cam_imu: np.ndarray) -> dict:  # type: ignore[no-untyped-def]
        return {
            "camera_model": "pinhole", "intrinsics": [float(x) for x in (cam.fx, cam.fy, cam.cx, cam.cy)],
            "distortion_model": "radtan", "distortion_coeffs": cam.dist.tolist(),
            "resolution": [cam.width, cam.height], "T_cam_imu": T_cam_imu.tolist(),
        }  # fmt: skip

    T0 = np.linalg.inv(cal.left.T_b_c)
    T1 = np.linalg.inv(cal.right.T_b_c)
    chain = {"cam0": entry(cal.left, T0), "cam1": entry(cal.right, T1)}
    p = tmp_path / "camchain-imucam.yaml"
    p.write_text(yaml.safe_dump(chain))
    k = read_kalibr_camchain(p).rectification()
    r = cal.rectification()
    assert np.allclose(k.K, r.K) and k.baseline == pytest.approx(r.baseline)
    assert np.allclose(k.R_b_r, r.R_b_r, atol=1e-9)
    # cam1 given relative to cam0 (T_cn_cnm1) gives the same
    c1 = entry(cal.right, T1)
    del c1["T_cam_imu"]
    c1["T_cn_cnm1"] = (T1 @ np.linalg.inv(T0)).tolist()
    p.write_text(yaml.safe_dump({"cam0": chain["cam0"], "cam1": c1}))
    assert read_kalibr_camchain(p).rectification().baseline == pytest.approx(r.baseline)
    # a camchain without the second camera is a one-line error naming the file and cam1
    p.write_text(yaml.safe_dump({"cam0": chain["cam0"]}))
    with pytest.raises(InputError, match=r"camchain-imucam.yaml: no 'cam1' entry"):
        read_kalibr_camchain(p)


def test_euroc_reader_counts_missing_and_unreadable(shared_data: Path, tmp_path: Path) -> None:
    ds = EurocStereo(shared_data / EUROC)
    assert len(ds) == 95 and ds.counts.listed == 99 and ds.counts.missing == 4
    # a small copy: 6 pairs, one PNG corrupted, one deleted, one of the wrong size
    import cv2

    src = shared_data / EUROC / "mav0"
    dst = tmp_path / "mav0"
    for cam in ("cam0", "cam1"):
        (dst / cam / "data").mkdir(parents=True)
        shutil.copy(src / cam / "sensor.yaml", dst / cam / "sensor.yaml")
        lines = [
            ln for ln in (src / cam / "data.csv").read_text().splitlines() if not ln.startswith("#")
        ][:6]
        (dst / cam / "data.csv").write_text("#timestamp [ns],filename\n" + "\n".join(lines) + "\n")
        for ln in lines:
            shutil.copy(src / cam / "data" / ln.split(",")[1], dst / cam / "data")
    (dst / "imu0").mkdir()
    shutil.copy(src / "imu0" / "data.csv", dst / "imu0" / "data.csv")
    names = sorted((dst / "cam0" / "data").iterdir())
    names[1].write_bytes(b"not a png")
    names[2].unlink()
    ds = EurocStereo(tmp_path)
    assert len(ds) == 5 and ds.counts.missing == 1
    frames = list(ds.frames())
    assert ds.counts.unreadable == 1 and sum(a is None for _, a, _ in frames) == 1
    cv2.imwrite(str(names[3]), np.zeros((240, 376), np.uint8))
    with pytest.raises(InputError, match=r"image is 376x240; the calibration .* says 752x480"):
        list(EurocStereo(tmp_path).frames())
    shutil.rmtree(dst / "cam1")
    with pytest.raises(InputError, match="no cam1 folder"):
        EurocStereo(tmp_path)


def test_vo_velocity_on_rendered_images_within_its_covariance() -> None:
    """2 s of rendered 20 Hz stereo on the figure-eight robot: every frame pair gives a measurement; the
    errors against the exact body velocity and rate are consistent with the reported covariance (mean
    NEES of 6 dof between 1.5 and 9: not overconfident, not uselessly loose) and small in absolute terms
    (speed 0.3-0.5 m/s: velocity RMS below 0.06 m/s, rate RMS below 0.02 rad/s)."""
    run = SimStereoRun(StereoRunConfig(duration_s=2.0, image_hz=20.0, seed=5))
    vo = StereoVO(run.rectification(), VoConfig())
    ms = [m for t, a, b in run.frames() if a is not None and (m := vo.process(t, a, b)) is not None]
    assert len(ms) == len(run) - 1 and vo.stats.skipped_few_features == 0
    tm = np.array([m.t_mid_ns for m in ms])
    vb, wb = run.velocity_b(tm)
    e = np.array(
        [np.concatenate([m.omega_b - w, m.vel_b - v]) for m, w, v in zip(ms, wb, vb, strict=True)]
    )
    nees = np.array([x @ np.linalg.solve(m.cov, x) for x, m in zip(e, ms, strict=True)])
    assert 1.5 < nees.mean() < 9.0
    assert np.sqrt(np.mean(e[:, 3:] ** 2)) < 0.06
    assert np.sqrt(np.mean(e[:, :3] ** 2)) < 0.02


def test_bag_stereo_equals_the_euroc_folder(shared_data: Path, tmp_path: Path) -> None:
    """A ROS 2 MCAP with the excerpt's first 12 pairs (left as mono8 Image, right as PNG CompressedImage)
    and its IMU gives the same images and the same VO measurements as the folder; one right image is
    dropped (counted missing)."""
    import cv2
    from rosbags.rosbag2 import StoragePlugin, Writer

    from imuslam.io import rosmsg
    from imuslam.io.stereosets import BagStereo

    ds = EurocStereo(shared_data / EUROC)
    pairs = list(ds.frames())[:12]
    ts = rosmsg.typestore("ros2")
    bag = tmp_path / "stereo.mcap"
    with Writer(bag, version=8, storage_plugin=StoragePlugin.MCAP) as w:
        cl = w.add_connection("/cam0/image_raw", rosmsg.IMAGE, typestore=ts)
        cr = w.add_connection("/cam1/image_raw/compressed", rosmsg.COMPRESSED_IMAGE, typestore=ts)
        ci = w.add_connection("/imu0", rosmsg.IMU, typestore=ts)
        sel = (ds.imu().t_ns >= pairs[0][0] - 10**8) & (ds.imu().t_ns <= pairs[-1][0] + 10**8)
        events = [
            (int(t), "imu", i) for i, t in zip(np.flatnonzero(sel), ds.imu().t_ns[sel], strict=True)
        ]
        events += [(t, "img", k) for k, (t, _, _) in enumerate(pairs)]
        for t, kind, k in sorted(events):
            if kind == "imu":
                m = rosmsg.imu_message(t, ds.imu().accel[k], ds.imu().gyro[k])
                w.write(ci, t, ts.serialize_cdr(m, rosmsg.IMU))
                continue
            _, a, b = pairs[k]
            w.write(cl, t, ts.serialize_cdr(rosmsg.image_message(t, a), rosmsg.IMAGE))
            if k == 7:
                continue  # the right image of pair 7 is lost
            T = ts.types[rosmsg.COMPRESSED_IMAGE]
            ok, png = cv2.imencode(".png", b)
            cm = T(
                header=rosmsg.header(t, "cam1"),
                format="png",
                data=np.frombuffer(png.tobytes(), np.uint8),
            )
            w.write(cr, t, ts.serialize_cdr(cm, rosmsg.COMPRESSED_IMAGE))
    bs = BagStereo(bag, ds.calibration, "/cam0/image_raw", "/cam1/image_raw/compressed", "/imu0")
    got = list(bs.frames())
    assert len(got) == 11 and bs.counts.missing == 1
    want = [p for k, p in enumerate(pairs) if k != 7]
    for (t, a, b), (tw, aw, bw) in zip(got, want, strict=True):
        assert t == tw and np.array_equal(a, aw) and np.array_equal(b, bw)
    assert len(bs.imu()) == int(sel.sum())


def test_fit_drops_tracks_that_ransac_let_through() -> None:
    """200 points seen after a known motion with 0.1 px of noise; 10 of them 1.5 px off, inside
    RANSAC's 2 px. The weighted fit that trusts them (at the prior sigma of 0.25 px they are 6 sigma
    off) is pulled away; the refit drops exactly those 10 and lands within a few standard deviations
    of its own covariance, a fraction of the plain fit's error."""
    rig = CameraRig()
    rect = Rectification(rig.K, rig.baseline, rig.width, rig.height, np.eye(3), np.zeros(3))
    rng = np.random.default_rng(8)
    X = np.stack([rng.uniform(-3, 3, 200), rng.uniform(-1.5, 1.5, 200), rng.uniform(2, 8, 200)], 1)
    th = 0.03
    R = np.array([[np.cos(th), 0, np.sin(th)], [0, 1, 0], [-np.sin(th), 0, np.cos(th)]])
    t = np.array([0.01, 0.0, -0.1])
    Y = X @ R.T + t
    uv = Y[:, :2] / Y[:, 2:] * [rig.fx, rig.fy] + [rig.cx, rig.cy] + rng.normal(0, 0.1, (200, 2))
    bad = rng.choice(200, 10, replace=False)
    ang = rng.uniform(0, 2 * np.pi, 10)
    uv[bad] += 1.5 * np.stack([np.cos(ang), np.sin(ang)], 1)
    covX = np.broadcast_to(1e-8 * np.eye(3), (200, 3, 3)).copy()
    ii = np.arange(200)
    errs = {}
    for refit in (False, True):
        vo = StereoVO(rect, VoConfig(refit=refit, refit_huber_k=0.0))
        R1, t1, cov, _, kept = vo._fit(X, covX, uv, ii, np.eye(3), np.zeros(3))
        errs[refit] = np.linalg.norm(t1 - t)
        if refit:
            assert set(ii) - set(kept) == set(bad)
            sd = np.sqrt(np.trace(cov[3:, 3:]))
            assert errs[True] < 3 * sd
    assert errs[True] < 0.5 * errs[False]


def test_refit_tests_each_residual_against_what_the_fit_leaves_of_it() -> None:
    """150 far points (5-9 m) and two near ones (0.9-1.0 m) after a known 8 cm step, 0.1 px of noise,
    the triangulation covariance of the front end (0.25 px on u, v, d). The near points carry the
    translation; one of them is tracked 2 px off. The fit bends to it, so its residual under C is small
    and the plain test keeps it: the translation is then off by more than the 99.9 % chi-square(3)
    quantile of its own covariance. Tested against its own covariance C - J A^-1 J^T (data snooping),
    exactly that point is dropped and the translation is within that quantile."""
    from scipy.stats import chi2

    rig = CameraRig()
    rect = Rectification(rig.K, rig.baseline, rig.width, rig.height, np.eye(3), np.zeros(3))
    rng = np.random.default_rng(3)
    Xf = np.stack([rng.uniform(-4, 4, 150), rng.uniform(-2, 1, 150), rng.uniform(5, 9, 150)], 1)
    X = np.r_[Xf, [[-0.3, 0.45, 0.9], [0.2, 0.5, 1.0]]]
    n = len(X)
    th = 0.01
    R = np.array([[np.cos(th), 0, np.sin(th)], [0, 1, 0], [-np.sin(th), 0, np.cos(th)]])
    t = np.array([0.0, 0.0, -0.08])
    Y = X @ R.T + t
    uv = Y[:, :2] / Y[:, 2:] * [rig.fx, rig.fy] + [rig.cx, rig.cy] + rng.normal(0, 0.1, (n, 2))
    uv[-1, 0] += 2.0
    f, b = rig.fx, rig.baseline
    d = f * b / X[:, 2]
    u = X[:, 0] / X[:, 2] * f + rig.cx
    v = X[:, 1] / X[:, 2] * rig.fy + rig.cy
    J = np.zeros((n, 3, 3))
    J[:, 0, 0] = J[:, 1, 1] = b / d
    J[:, 0, 2] = -(u - rig.cx) * b / d**2
    J[:, 1, 2] = -(v - rig.cy) * b / d**2
    J[:, 2, 2] = -f * b / d**2
    covX = J @ np.diag([0.0625, 0.0625, 0.125]) @ np.swapaxes(J, 1, 2)
    limit = chi2.ppf(0.999, 3)
    out = {}
    for snoop in (False, True):
        vo = StereoVO(rect, VoConfig(refit_snooping=snoop))
        _, t1, cov, _, kept = vo._fit(X, covX, uv, np.arange(n), np.eye(3), np.zeros(3))
        e = t1 - t
        out[snoop] = (
            set(range(n)) - set(kept.tolist()),
            float(e @ np.linalg.solve(cov[3:, 3:], e)),
        )
        print(f"snooping {snoop}: dropped {sorted(out[snoop][0])}, translation error "
              f"{np.round(e * 1e3, 2)} mm, chi-square {out[snoop][1]:.1f} (limit {limit:.1f})")  # fmt: skip
    assert n - 1 not in out[False][0] and out[False][1] > limit
    assert out[True][0] == {n - 1} and out[True][1] < limit


def test_compiled_fit_terms_equal_numpy() -> None:
    """The compiled Gauss-Newton terms of the motion fit (:mod:`imuslam.vio.motion_nb`) against the same
    quantities written with numpy from their definitions: residual ``r = uv - pi(R X + t)``, covariance
    ``C = s2 I + (Jp R) covX (Jp R)^T``, Jacobian ``[-Jp hat(Y), Jp]`` in the left perturbation (checked
    by finite differences of the projection), ``A = sum J^T C^-1 J``, ``g = sum J^T C^-1 r``,
    ``q = r^T C^-1 r`` and the snooped ``r^T (C - J A^-1 J^T)^-1 r``, to 1e-9 relative."""
    from imuslam.geometry import exp as exp_so3
    from imuslam.geometry import hat
    from imuslam.vio.motion_nb import normal_terms, snooped_q

    rng = np.random.default_rng(5)
    n = 40
    X = np.stack([rng.uniform(-3, 3, n), rng.uniform(-1, 1, n), rng.uniform(1, 8, n)], 1)
    L = rng.normal(0, 0.02, (n, 3, 3))
    covX = L @ np.swapaxes(L, 1, 2) + 1e-6 * np.eye(3)
    R = exp_so3(np.array([0.02, -0.05, 0.01]))
    t = np.array([0.03, -0.01, -0.12])
    fx, fy, cx, cy, s2 = 460.0, 455.0, 370.0, 245.0, 0.0625

    def project(Rm: np.ndarray, tv: np.ndarray) -> np.ndarray:
        Y = X @ Rm.T + tv
        return np.c_[fx * Y[:, 0] / Y[:, 2] + cx, fy * Y[:, 1] / Y[:, 2] + cy]

    uv = project(R, t) + rng.normal(0, 0.5, (n, 2))
    A, g, q, C, Jd, res = normal_terms(X, covX, uv, R, t, fx, fy, cx, cy, s2)

    Y = X @ R.T + t
    z = Y[:, 2]
    Jp = np.zeros((n, 2, 3))
    Jp[:, 0, 0], Jp[:, 0, 2] = fx / z, -fx * Y[:, 0] / z**2
    Jp[:, 1, 1], Jp[:, 1, 2] = fy / z, -fy * Y[:, 1] / z**2
    JR = Jp @ R
    C_ref = s2 * np.eye(2) + JR @ covX @ np.swapaxes(JR, 1, 2)
    J_ref = np.concatenate([Jp @ -np.stack([hat(y) for y in Y]), Jp], axis=2)
    # the Jacobian is the projection's derivative in the left perturbation
    eps = 1e-7
    for j in range(6):
        d = np.zeros(6)
        d[j] = eps
        dR = exp_so3(d[:3])
        num = (project(dR @ R, dR @ t + d[3:]) - project(R, t)) / eps
        assert np.allclose(num, J_ref[:, :, j], rtol=1e-4, atol=1e-3)
    W = np.linalg.inv(C_ref)
    res_ref = uv - project(R, t)
    A_ref = np.einsum("nji,njk,nkl->il", J_ref, W, J_ref)
    g_ref = np.einsum("nji,njk,nk->i", J_ref, W, res_ref)
    q_ref = np.einsum("ni,nij,nj->n", res_ref, W, res_ref)
    for got, want in ((C, C_ref), (Jd, J_ref), (res, res_ref), (A, A_ref), (g, g_ref), (q, q_ref)):
        assert np.allclose(got, want, rtol=1e-9, atol=1e-12 * np.abs(want).max())
    cov = np.linalg.inv(A_ref)
    Qv = C_ref - J_ref @ cov @ np.swapaxes(J_ref, 1, 2)
    qs_ref = np.einsum("ni,nij,nj->n", res_ref, np.linalg.inv(Qv), res_ref)
    assert np.allclose(snooped_q(C, Jd, res, cov), qs_ref, rtol=1e-9)
    # a point whose covariance is all the fit's (nothing left to test) is tested against C itself
    Cz = C.copy()
    Cz[1] = (Jd @ cov @ np.swapaxes(Jd, 1, 2))[1]
    qz = snooped_q(Cz, Jd, res, cov)
    assert np.isclose(qz[1], res[1] @ np.linalg.solve(Cz[1], res[1]), rtol=1e-9)
    assert np.allclose(np.delete(qz, 1), np.delete(qs_ref, 1), rtol=1e-9)


def test_huber_terms_equal_numpy() -> None:
    """The compiled Huber-weighted terms against numpy from their definitions: ``w = min(1, k /
    sqrt(q))``, ``A = sum w J^T C^-1 J``, ``g = sum w J^T C^-1 r``, ``B = sum w^2 J^T C^-1 J``; at a
    ``k`` above every residual they are the plain fit's ``A`` and ``g``."""
    from imuslam.vio.motion_nb import huber_terms, normal_terms

    rng = np.random.default_rng(6)
    n = 50
    X = np.stack([rng.uniform(-3, 3, n), rng.uniform(-1, 1, n), rng.uniform(1, 8, n)], 1)
    L = rng.normal(0, 0.002, (n, 3, 3))
    covX = L @ np.swapaxes(L, 1, 2) + 1e-8 * np.eye(3)
    R, t = np.eye(3), np.array([0.02, 0.0, -0.1])
    Y = X @ R.T + t
    uv = Y[:, :2] / Y[:, 2:] * 460.0 + [370.0, 245.0] + rng.normal(0, 0.6, (n, 2))
    A0, g0, q, C, Jd, res = normal_terms(X, covX, uv, R, t, 460.0, 460.0, 370.0, 245.0, 0.0625)
    k = 1.5
    A, g, B = huber_terms(C, Jd, res, q, k)
    w = np.minimum(1.0, k / np.sqrt(q))
    assert 0.1 < np.mean(w < 1) < 0.9  # both kinds of point are in the test
    W = np.linalg.inv(C)
    A_ref = np.einsum("n,nji,njk,nkl->il", w, Jd, W, Jd)
    g_ref = np.einsum("n,nji,njk,nk->i", w, Jd, W, res)
    B_ref = np.einsum("n,nji,njk,nkl->il", w**2, Jd, W, Jd)
    for got, want in ((A, A_ref), (g, g_ref), (B, B_ref)):
        assert np.allclose(got, want, rtol=1e-9, atol=1e-12 * np.abs(want).max())
    A1, g1, B1 = huber_terms(C, Jd, res, q, 1e6)
    assert np.allclose(A1, A0, rtol=1e-12) and np.allclose(g1, g0, rtol=1e-12)
    assert np.allclose(B1, A0, rtol=1e-12)


def _scene(rng: np.random.Generator, n: int = 200) -> tuple[np.ndarray, ...]:
    """n points 2-8 m ahead and their exact pixels after a known 3 cm / 1.7 deg step."""
    rig = CameraRig()
    X = np.stack([rng.uniform(-3, 3, n), rng.uniform(-1.5, 1.5, n), rng.uniform(2, 8, n)], 1)
    th = 0.03
    R = np.array([[np.cos(th), 0, np.sin(th)], [0, 1, 0], [-np.sin(th), 0, np.cos(th)]])
    t = np.array([0.01, 0.0, -0.03])
    Y = X @ R.T + t
    uv = Y[:, :2] / Y[:, 2:] * [rig.fx, rig.fy] + [rig.cx, rig.cy]
    return X, uv, R, t


def test_huber_fit_covariance_is_right_on_gaussian_tracks() -> None:
    """200 trials of 200 points tracked with Gaussian errors of exactly the prior sigma (0.25 px): the
    Huber-weighted fit (k = 2 weighs down about 14 % of these good points) with its sandwich covariance
    ``A^-1 B A^-1``. The motion error's NEES (6 dof) has mean 6: inside the 95 % chi-square band of the
    mean of 200."""
    from scipy.stats import chi2

    from imuslam.geometry import log

    rig = CameraRig()
    rect = Rectification(rig.K, rig.baseline, rig.width, rig.height, np.eye(3), np.zeros(3))
    vo = StereoVO(rect, VoConfig(refit=False, refit_huber_k=2.0))
    rng = np.random.default_rng(11)
    trials = 200
    nees = []
    for _ in range(trials):
        X, uv, R, t = _scene(rng)
        uv = uv + rng.normal(0, 0.25, uv.shape)
        covX = np.broadcast_to(1e-10 * np.eye(3), (len(X), 3, 3)).copy()
        R1, t1, cov, _, _ = vo._fit(X, covX, uv, np.arange(len(X)), np.eye(3), np.zeros(3))
        # the error in the fit's left perturbation: R1 = exp(dth) R, t1 = exp(dth) t + dt
        dth = log(R1 @ R.T)
        e = np.r_[dth, t1 - R1 @ R.T @ t]
        nees.append(float(e @ np.linalg.solve(cov, e)))
    lo, hi = chi2.ppf([0.025, 0.975], 6 * trials) / trials
    print(f"Huber fit on Gaussian tracks: mean NEES {np.mean(nees):.2f} (band {lo:.2f}-{hi:.2f})")
    assert lo <= np.mean(nees) <= hi


def test_huber_fit_beats_the_plain_fit_on_tracks_of_mixed_quality() -> None:
    """300 trials of 200 points, 80 % tracked with 0.1 px of error and 20 % with 0.35 px (patches that
    track worse), all at the front end's prior sigma of 0.25 px: most of the worse ones pass the
    refit's test, and the plain refit weighs them like the rest. The Huber-weighted fit (the default,
    k = 2) weighs those beyond 2 sigmas down. On the same trials its translation error is smaller in
    mean square, and smaller on more trials than a coin would give (binomial(300, 1/2): more than 60 %
    has a chance below 0.03 % if neither fit were better)."""
    rig = CameraRig()
    rect = Rectification(rig.K, rig.baseline, rig.width, rig.height, np.eye(3), np.zeros(3))
    fits = {k: StereoVO(rect, VoConfig(refit_huber_k=k)) for k in (0.0, 2.0)}
    rng = np.random.default_rng(12)
    se: dict[float, list[float]] = {0.0: [], 2.0: []}
    for _ in range(300):
        X, uv, R, t = _scene(rng)
        sigma = np.where(rng.random(len(X)) < 0.2, 0.35, 0.1)[:, None]
        uv = uv + sigma * rng.normal(0, 1, uv.shape)
        covX = np.broadcast_to(1e-10 * np.eye(3), (len(X), 3, 3)).copy()
        for k, vo in fits.items():
            R1, t1, *_ = vo._fit(X, covX, uv, np.arange(len(X)), np.eye(3), np.zeros(3))
            se[k].append(float(np.sum((t1 - R1 @ R.T @ t) ** 2)))
    a, b = np.array(se[0.0]), np.array(se[2.0])
    print(f"translation mean squared error, Huber over plain: {b.mean() / a.mean():.2f}; Huber "
          f"better on {100 * np.mean(b < a):.0f} % of the trials")  # fmt: skip
    assert b.mean() < a.mean()
    assert np.mean(b < a) > 0.6
