"""Scan matching: correlative search, Gauss-Newton refinement, branch and bound, peaks and the match
information, each against an exhaustive or numeric reference or a known offset."""

from __future__ import annotations

import numpy as np
import pytest
from slam2d_helpers import RES, _corridor, _scan_at

from imuslam.slam2d import pose2
from imuslam.slam2d.grid import ProbabilityGrid
from imuslam.slam2d.matching import (
    angular_step,
    bnb_match,
    correlative_search,
    make_index,
    refine_pose,
    refine_pose_reference,
)


def test_matcher_recovers_known_offset(room_grid: ProbabilityGrid) -> None:
    rng = np.random.default_rng(2)
    true = np.array([0.3, 0.2, 0.25])
    pts = _scan_at(true, rng)
    offset = np.array([0.11, -0.08, np.deg2rad(4.0)])
    prior = true + offset
    d_max = float(np.max(np.hypot(pts[:, 0], pts[:, 1])))
    step = angular_step(RES, d_max)
    g = room_grid
    init, _ = correlative_search(g.prob, g.x0, g.y0, RES, pts, prior, 4, int(np.ceil(np.deg2rad(8) / step)),
                                 step, 0.0, 0.0, 0.1)  # fmt: skip
    # the correlative lattice is one cell and one angular step: within half of each of the truth
    assert np.all(np.abs(init[:2] - true[:2]) <= RES / 2 + 1e-9)
    assert abs(init[2] - true[2]) <= step / 2 + 1e-9
    pose, score = refine_pose(g.prob, g.x0, g.y0, RES, pts, init, init, 1.0, 0.0, 0.0, 0.1, 30)
    # refinement on the interpolated grid: well inside the cell (range noise 1 cm over ~700 points)
    assert np.hypot(*(pose[:2] - true[:2])) < 0.25 * RES
    assert abs(pose[2] - true[2]) < np.deg2rad(0.25)
    assert score > 0.6


def test_refine_kernel_equals_scipy_reference(room_grid: ProbabilityGrid) -> None:
    rng = np.random.default_rng(3)
    true = np.array([-0.4, 0.1, -0.3])
    pts = _scan_at(true, rng)
    g = room_grid
    init = true + np.array([0.02, -0.015, 0.01])
    prior = init.copy()
    fast, _ = refine_pose(g.prob, g.x0, g.y0, RES, pts, init, prior, 1.0, 0.5, 0.5, 0.1, 50)
    slow = refine_pose_reference(g.prob, g.x0, g.y0, RES, pts, init, prior, 1.0, 0.5, 0.5, 0.1)
    assert np.allclose(fast[:2], slow[:2], atol=2e-3)
    assert abs(fast[2] - slow[2]) < np.deg2rad(0.1)


def test_bicubic_refine_kernel_equals_reference_and_recovers_offset(
    room_grid: ProbabilityGrid,
) -> None:
    """The bicubic (Catmull-Rom) refinement: the numba kernel lands where scipy's least squares on the
    numpy-written interpolant does, and, from a pose 3 cm / 1 deg off, within a quarter cell and
    0.25 deg of the truth (as the bilinear one must)."""
    rng = np.random.default_rng(13)
    true = np.array([-0.4, 0.1, -0.3])
    pts = _scan_at(true, rng)
    g = room_grid
    init = true + np.array([0.02, -0.015, 0.01])
    fast, _ = refine_pose(g.prob, g.x0, g.y0, RES, pts, init, init, 1.0, 0.5, 0.5, 0.1, 50, True)
    slow = refine_pose_reference(g.prob, g.x0, g.y0, RES, pts, init, init, 1.0, 0.5, 0.5, 0.1, True)
    assert np.allclose(fast[:2], slow[:2], atol=2e-3)
    assert abs(fast[2] - slow[2]) < np.deg2rad(0.1)
    start = true + np.array([0.03, 0.02, np.deg2rad(1.0)])
    pose, score = refine_pose(
        g.prob, g.x0, g.y0, RES, pts, start, start, 1.0, 0.0, 0.0, 0.1, 30, True
    )
    assert np.hypot(*(pose[:2] - true[:2])) < 0.25 * RES
    assert abs(pose[2] - true[2]) < np.deg2rad(0.25)
    assert score > 0.6


def test_branch_and_bound_equals_exhaustive_search(room_grid: ProbabilityGrid) -> None:
    rng = np.random.default_rng(4)
    true = np.array([0.5, -0.6, 1.0])
    pts = _scan_at(true, rng)[::3]
    g = room_grid
    prob, x0, y0 = g.cropped()
    idx = make_index(prob, x0, y0, RES, 4)
    start = true + np.array([0.3, -0.25, np.deg2rad(7.0)])
    pose, score = bnb_match(idx, pts, start, 0.5, np.deg2rad(10.0), 0.3)
    # exhaustive: the same lattice (angles of bnb_match, every cell of the window) scored on level 0
    step = angular_step(RES, float(np.max(np.hypot(pts[:, 0], pts[:, 1]))))
    n_ang = int(np.ceil(np.deg2rad(10.0) / step))
    best, best_pose = -1.0, None
    for a in range(-n_ang, n_ang + 1):
        th = start[2] + a * step
        w = pose2.act(np.array([start[0], start[1], th]), pts)
        cx = np.floor((w[:, 0] - x0) / RES).astype(int) + idx.pad
        cy = np.floor((w[:, 1] - y0) / RES).astype(int) + idx.pad
        lv = idx.levels[0]
        for dx in range(-10, 11):
            for dy in range(-10, 11):
                xx, yy = cx + dx, cy + dy
                ok = (xx >= 0) & (xx < lv.shape[1]) & (yy >= 0) & (yy < lv.shape[0])
                sc = lv[yy[ok], xx[ok]].astype(float).sum() / (255.0 * len(pts))
                if sc > best:
                    best, best_pose = sc, np.array([start[0] + dx * RES, start[1] + dy * RES, th])
    assert score == pytest.approx(best, abs=1e-12)
    assert best_pose is not None
    assert np.hypot(*(pose[:2] - true[:2])) < 1.5 * RES


def test_single_pose_fast_path_equals_se2() -> None:
    """pose2's one-pose compose/between (no matrices) against geometry.se2 on random poses."""
    from imuslam.geometry import se2

    rng = np.random.default_rng(1)
    for _ in range(200):
        a, b = rng.uniform([-5, -5, -4], [5, 5, 4], size=(2, 3))
        for fast, ref in (
            (pose2.compose(a, b), se2.compose(se2.from_xy_yaw(a), se2.from_xy_yaw(b))),
            (pose2.between(a, b), se2.between(se2.from_xy_yaw(a), se2.from_xy_yaw(b))),
        ):
            r = se2.to_xy_yaw(ref)
            assert np.allclose(fast[:2], r[:2], atol=1e-12)
            assert abs(pose2.wrap(fast[2] - r[2])) < 1e-12


def test_distinct_peak_search_equals_masked_exhaustive_search(room_grid: ProbabilityGrid) -> None:
    """The second branch and bound (poses near the best left out) finds the best lattice score of the
    poses farther than the peak radius or angle, as an exhaustive search over the same lattice does."""
    from imuslam.slam2d.matching import bnb_match_distinct

    rng = np.random.default_rng(14)
    true = np.array([0.5, -0.6, 1.0])
    pts = _scan_at(true, rng)[::3]
    prob, x0, y0 = room_grid.cropped()
    idx = make_index(prob, x0, y0, RES, 4)
    start = true + np.array([0.2, -0.15, np.deg2rad(4.0)])
    radius, ang = 0.2, np.deg2rad(3.0)
    # margin 1: the second search's threshold is 0, so it returns the best score away from the peak
    pose, score, second = bnb_match_distinct(
        idx, pts, start, 0.5, np.deg2rad(10.0), 0.3, np.inf, radius, ang, 1.0
    )
    step = angular_step(RES, float(np.max(np.hypot(pts[:, 0], pts[:, 1]))))
    n_ang = int(np.ceil(np.deg2rad(10.0) / step))
    lv = idx.levels[0]
    vol = np.zeros((2 * n_ang + 1, 21, 21))
    for a in range(-n_ang, n_ang + 1):
        w = pose2.act(np.array([start[0], start[1], start[2] + a * step]), pts)
        cx = np.floor((w[:, 0] - x0) / RES).astype(int) + idx.pad
        cy = np.floor((w[:, 1] - y0) / RES).astype(int) + idx.pad
        for dx in range(-10, 11):
            for dy in range(-10, 11):
                xx, yy = cx + dx, cy + dy
                ok = (xx >= 0) & (xx < lv.shape[1]) & (yy >= 0) & (yy < lv.shape[0])
                vol[a + n_ang, dy + 10, dx + 10] = lv[yy[ok], xx[ok]].astype(float).sum() / (
                    255.0 * len(pts)
                )
    a0, iy, ix = np.unravel_index(int(np.argmax(vol)), vol.shape)
    assert score == pytest.approx(vol.max(), abs=1e-12)
    A, Y, X = np.meshgrid(np.arange(vol.shape[0]) - a0, np.arange(21) - iy, np.arange(21) - ix,
                          indexing="ij")  # fmt: skip
    far = (np.hypot(X, Y) > radius / RES) | (np.abs(A) > np.floor(ang / step))
    assert second == pytest.approx(vol[far].max(), abs=1e-12)
    assert second < score
    assert np.hypot(*(pose[:2] - true[:2])) < 1.5 * RES


def test_match_information_equals_numeric_and_is_small_along_a_corridor(
    room_grid: ProbabilityGrid,
) -> None:
    """The match's information J^T J equals the one of a finite-difference Jacobian of the same
    residuals (scipy's bilinear interpolator), and in a corridor the information along its axis is a
    small fraction of the information across it (every shift along it fits as well)."""
    from scipy.interpolate import RegularGridInterpolator

    from imuslam.slam2d.matching import match_information

    rng = np.random.default_rng(16)
    true = np.array([-0.4, 0.1, -0.3])
    pts = _scan_at(true, rng)
    g = room_grid
    info = match_information(g.prob, g.x0, g.y0, RES, pts, true, 1.0, 0.1)
    H, W = g.prob.shape
    f = RegularGridInterpolator(((np.arange(H) + 0.5) * RES + g.y0, (np.arange(W) + 0.5) * RES + g.x0),
                                g.prob.astype(float), bounds_error=False, fill_value=0.1)  # fmt: skip

    def resid(x: np.ndarray) -> np.ndarray:
        p = pose2.act(x, pts)
        return (1.0 - f(p[:, ::-1])) / np.sqrt(len(pts))

    J = np.column_stack([(resid(true + e) - resid(true - e)) / 2e-5 for e in np.eye(3) * 1e-5])
    assert np.allclose(info, J.T @ J, rtol=0.05, atol=1e-3 * np.abs(info).max())

    gc, scan = _corridor(rng)
    ci = match_information(gc.prob, gc.x0, gc.y0, RES, scan, np.zeros(3), 1.0, 0.1)
    # not zero: the cells along a wall differ (2-3 hits each), which J^T J sees as texture
    assert ci[0, 0] < 0.25 * ci[1, 1]


def test_loop_match_in_a_corridor_is_ambiguous_and_in_a_room_distinct(
    room_grid: ProbabilityGrid,
) -> None:
    """A scan of a straight corridor fits a corridor submap equally well anywhere along it: no distinct
    peak. A scan of the room has one: its best pose beats every pose 0.5 m / 10 deg away by far."""
    from imuslam.slam2d.matching import bnb_match_distinct

    rng = np.random.default_rng(15)
    g, scan = _corridor(rng)
    prob, x0, y0 = g.cropped()
    idx = make_index(prob, x0, y0, RES, 5)
    guess = np.array([0.4, 0.05, 0.02])  # the scan was taken at the origin
    _, score, second = bnb_match_distinct(
        idx, scan, guess, 3.0, np.deg2rad(20.0), 0.5, 15.0, 0.5, np.deg2rad(10.0), 0.05
    )
    assert score > 0.5
    assert second >= score - 0.05  # ambiguous along the corridor

    prob, x0, y0 = room_grid.cropped()
    ridx = make_index(prob, x0, y0, RES, 5)
    true = np.array([0.3, 0.2, 0.25])
    pts = _scan_at(true, rng)
    _, score, second = bnb_match_distinct(
        ridx, pts, true + np.array([0.4, -0.3, 0.1]), 1.0, np.deg2rad(20.0), 0.5, 15.0, 0.5,
        np.deg2rad(10.0), 0.05,
    )  # fmt: skip
    assert score > 0.6
    assert second == -1.0  # nothing within 0.05 of the peak away from it


def test_peaks_search_equals_greedy_exhaustive_search(room_grid: ProbabilityGrid) -> None:
    """``bnb_match_peaks`` returns, best first, the peaks an exhaustive search of the same lattice finds by
    taking the best pose, masking every pose within the peak radius and angle of it, and again (peaks on
    the window's edge masked but not returned)."""
    from imuslam.slam2d.matching import bnb_match_peaks

    rng = np.random.default_rng(15)
    true = np.array([0.5, -0.6, 1.0])
    pts = _scan_at(true, rng)[::3]
    prob, x0, y0 = room_grid.cropped()
    idx = make_index(prob, x0, y0, RES, 4)
    start = true + np.array([0.2, -0.15, np.deg2rad(4.0)])
    radius, ang = 0.2, np.deg2rad(3.0)
    peaks = bnb_match_peaks(idx, pts, start, 0.5, np.deg2rad(10.0), 0.2, np.inf, radius, ang, 3)
    step = angular_step(RES, float(np.max(np.hypot(pts[:, 0], pts[:, 1]))))
    n_ang = int(np.ceil(np.deg2rad(10.0) / step))
    lv = idx.levels[0]
    vol = np.zeros((2 * n_ang + 1, 21, 21))
    for a in range(-n_ang, n_ang + 1):
        w = pose2.act(np.array([start[0], start[1], start[2] + a * step]), pts)
        cx = np.floor((w[:, 0] - x0) / RES).astype(int) + idx.pad
        cy = np.floor((w[:, 1] - y0) / RES).astype(int) + idx.pad
        for dx in range(-10, 11):
            for dy in range(-10, 11):
                xx, yy = cx + dx, cy + dy
                ok = (xx >= 0) & (xx < lv.shape[1]) & (yy >= 0) & (yy < lv.shape[0])
                vol[a + n_ang, dy + 10, dx + 10] = lv[yy[ok], xx[ok]].astype(float).sum() / (
                    255.0 * len(pts)
                )
    A, Y, X = np.meshgrid(np.arange(vol.shape[0]), np.arange(21), np.arange(21), indexing="ij")
    v = vol.copy()
    expected = []
    while len(expected) < 3 and v.max() >= 0.2:
        a0, iy, ix = np.unravel_index(int(np.argmax(v)), v.shape)
        score = v[a0, iy, ix]
        v[
            (np.hypot(X - ix, Y - iy) <= radius / RES) & (np.abs(A - a0) <= np.floor(ang / step))
        ] = -1
        if max(abs(ix - 10), abs(iy - 10)) >= 10 or a0 in (0, vol.shape[0] - 1):
            continue
        expected.append((score, ix - 10, iy - 10, a0 - n_ang))
    assert len(peaks) == len(expected) == 3
    for (pose, score), (s_ex, dx, dy, a) in zip(peaks, expected, strict=True):
        assert score == pytest.approx(s_ex, abs=1e-12)
        np.testing.assert_allclose(
            pose, [start[0] + dx * RES, start[1] + dy * RES, start[2] + a * step], atol=1e-9
        )
    assert np.hypot(*(peaks[0][0][:2] - true[:2])) < 1.5 * RES
