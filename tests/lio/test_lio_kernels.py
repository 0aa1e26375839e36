"""LiDAR odometry kernels against slow references and known geometry."""

from __future__ import annotations

import numpy as np
import pytest

from imuslam.geometry import exp
from imuslam.io.pointcloud import pcd_points, read_ply, write_pcd, write_ply
from imuslam.lio.config import FrontEndConfig
from imuslam.lio.deskew import deskew, deskew_constant_velocity, deskew_reference
from imuslam.lio.features import (
    FeatureParams,
    loam_features,
    ring_order,
    smoothness_reference,
    voxel_downsample,
    voxel_downsample_fast,
)
from imuslam.lio.features import _smoothness as smoothness_kernel
from imuslam.lio.frontend import select_points, select_points_reference
from imuslam.lio.ivox import IncrementalVoxelMap
from imuslam.lio.residuals import (
    fit_lines,
    fit_planes,
    fit_planes_reference,
    point_to_plane_reference,
    point_to_plane_system,
)
from imuslam.lio.voxelmap import KnnIndex, VoxelMap


def _ring_scan(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two rings around a box corner room: walls at x = 5 and y = 4 (a corner = an edge)."""
    pts, rings, ts = [], [], []
    for r, el in enumerate((-0.05, 0.05)):
        az = np.linspace(0.05, np.pi / 2 - 0.05, 400)
        d = np.stack([np.cos(az), np.sin(az), np.full_like(az, np.tan(el))], axis=1)
        t_x = 5.0 / d[:, 0]
        t_y = 4.0 / d[:, 1]
        rng_ = np.minimum(t_x, t_y) + rng.normal(size=az.size) * 1e-3
        pts.append(d * rng_[:, None])
        rings.append(np.full(az.size, r))
        ts.append(az / (2 * np.pi) * 0.1)
    return np.concatenate(pts), np.concatenate(rings), np.concatenate(ts)


def test_smoothness_kernel_matches_reference_and_finds_the_corner() -> None:
    rng = np.random.default_rng(0)
    pts, ring, t = _ring_scan(rng)
    order, starts = ring_order(ring, t)
    curv, _ = smoothness_kernel(np.ascontiguousarray(pts[order]), starts, 0.05, 0.1)
    for r in range(len(starts) - 1):
        seg = slice(starts[r], starts[r + 1])
        np.testing.assert_allclose(curv[seg], smoothness_reference(pts[order][seg]), rtol=1e-9)
    edges, planes, _ = loam_features(pts, ring, t, FeatureParams(max_edges=1, sectors=1))
    corner_az = np.arctan2(4.0, 5.0)
    az_e = np.arctan2(pts[edges, 1], pts[edges, 0])
    # one edge per ring, at the corner within the 5-point smoothing window (5 x 0.22 deg)
    assert len(edges) == 2
    assert np.all(np.abs(az_e - corner_az) < np.deg2rad(1.2))
    az_p = np.arctan2(pts[planes, 1], pts[planes, 0])
    assert len(planes) > 500 and np.all(np.abs(az_p - corner_az) > np.deg2rad(0.5))


def test_compiled_front_end_equals_the_numpy_reference() -> None:
    """The one-pass front end (range gate, ring order, LOAM features, voxel downsampling) returns the
    same points in the same order as the numpy path, on a simulated VLP-16 scan of the street, also
    when the points arrive shuffled (rings interleaved, times out of order within a ring)."""
    from imuslam.sim.drive import simulate_lidar_drive

    scan = simulate_lidar_drive("street", 0.15, seed=5).scans[0]
    pts, t = scan.points_l.astype(np.float64), scan.t_offset_s.astype(np.float64)
    ring = np.asarray(scan.ring)
    perm = np.random.default_rng(4).permutation(len(pts))
    for p, tt, rg in ((pts, t, ring), (pts[perm], t[perm], ring[perm])):
        for mode in ("features", "direct"):
            cfg = FrontEndConfig(mode=mode)
            fast, ref = select_points(p, tt, rg, cfg), select_points_reference(p, tt, rg, cfg)
            for a, b in zip(fast, ref, strict=True):
                np.testing.assert_array_equal(a, b)
            assert len(fast[0]) > 1000 and (mode == "direct" or len(fast[1]) > 100)
    idx = voxel_downsample_fast(pts, 0.7)
    np.testing.assert_array_equal(idx, voxel_downsample(pts, 0.7))


def test_deskew_recovers_the_scan_end_frame() -> None:
    """A sensor turning at 1 rad/s and moving at 5 m/s with acceleration: points fired over 0.1 s are
    moved into the scan-end frame; the truth is the world point seen from the end pose."""
    rng = np.random.default_rng(1)
    w = np.array([0.1, -0.2, 1.0])
    v0, acc = np.array([5.0, 0.5, 0.0]), np.array([0.3, -0.2, 0.1])

    def pose(t: float) -> tuple[np.ndarray, np.ndarray]:
        return exp(w * t), v0 * t + 0.5 * acc * t * t

    T_i_l = np.eye(4)
    T_i_l[:3, :3] = exp(np.array([0.0, 0.0, 0.3]))
    T_i_l[:3, 3] = [0.1, 0.0, 0.2]
    n = 2000
    t_pt = np.sort(rng.uniform(0.0, 0.1, n))
    q_w = rng.uniform(-20, 20, size=(n, 3))
    pts_l = np.empty((n, 3))
    for j in range(n):  # the point as the sensor saw it at its firing time
        R, p = pose(t_pt[j])
        x_i = R.T @ (q_w[j] - p)
        pts_l[j] = T_i_l[:3, :3].T @ (x_i - T_i_l[:3, 3])
    R_e, p_e = pose(0.1)
    truth = ((q_w - p_e) @ R_e - T_i_l[:3, 3]) @ T_i_l[:3, :3]
    t_k = np.arange(0.0, 0.1001, 0.005)
    R_k = np.array([pose(t)[0] for t in t_k])
    p_k = np.array([pose(t)[1] for t in t_k])
    v_k = v0[None] + acc[None] * t_k[:, None]
    a_k = np.broadcast_to(acc, (len(t_k), 3))
    w_k = np.broadcast_to(w, (len(t_k), 3))
    out = deskew(pts_l, t_pt, t_k, R_k, p_k, v_k, a_k, w_k, T_i_l, 0.1)
    assert np.max(np.linalg.norm(out - truth, axis=1)) < 1e-9
    ref = deskew_reference(pts_l[:50], t_pt[:50], pose, T_i_l, 0.1)
    np.testing.assert_allclose(out[:50], ref, atol=1e-9)
    # without deskew the error is the motion over the sweep: half a metre at the start
    assert np.max(np.linalg.norm(pts_l - truth, axis=1)) > 0.3


def test_constant_velocity_deskew_is_exact_for_constant_twist() -> None:
    rng = np.random.default_rng(2)
    w, v = np.array([0.0, 0.0, 0.8]), np.array([3.0, 0.0, 0.0])
    T_e = np.eye(4)
    T_e[:3, :3], T_e[:3, 3] = exp(w * 0.1), v * 0.1  # R(t) = exp(w t), p(t) = v t
    t_pt = rng.uniform(0, 0.1, 500)
    q_w = rng.uniform(-10, 10, size=(500, 3))
    pts = np.array([exp(w * t).T @ (q - v * t) for q, t in zip(q_w, t_pt, strict=True)])
    out = deskew_constant_velocity(pts, t_pt, 0.1, T_e, w, v)
    truth = (q_w - T_e[:3, 3]) @ T_e[:3, :3]
    assert np.max(np.linalg.norm(out - truth, axis=1)) < 1e-9


def test_plane_and_line_fits_against_eigh_and_truth() -> None:
    rng = np.random.default_rng(3)
    M, k = 300, 5
    normals = rng.normal(size=(M, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    centres = rng.uniform(-30, 30, size=(M, 3))
    pts = []
    for n, c in zip(normals, centres, strict=True):
        u = np.cross(n, [1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.cross(n, [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        vv = np.cross(n, u)
        ab = rng.uniform(-0.5, 0.5, size=(k, 2))
        pts.append(c + ab[:, :1] * u + ab[:, 1:] * vv + rng.normal(size=(k, 1)) * 0.005 * n)
    map_pts = np.concatenate(pts)
    nbr = np.arange(M * k).reshape(M, k)
    d2 = np.zeros((M, k))
    q = centres + 0.3 * normals
    n_fit, c_fit, ok = fit_planes(q, nbr, d2, map_pts, 1.0, 0.1)
    n_ref, c_ref = fit_planes_reference(nbr, map_pts)
    assert ok.all()
    np.testing.assert_allclose(np.abs(np.einsum("mk,mk->m", n_fit, n_ref)), 1.0, atol=1e-8)
    np.testing.assert_allclose(c_fit, c_ref, atol=1e-12)
    # noise 5 mm over a 1 m patch of 5 points: the normal within a few degrees of the truth
    ang = np.degrees(np.arccos(np.clip(np.abs(np.einsum("mk,mk->m", n_fit, normals)), 0, 1)))
    assert np.percentile(ang, 95) < 5.0
    # lines: 5 points along a direction; the query 0.4 m off the line
    dirs = normals
    line_pts = (centres[:, None] + np.linspace(-1, 1, k)[None, :, None] * dirs[:, None]).reshape(
        -1, 3
    )
    off = np.cross(dirs, rng.normal(size=(M, 3)))
    off = 0.4 * off / np.linalg.norm(off, axis=1, keepdims=True)
    n_l, c_l, ok_l = fit_lines(centres + off, nbr, d2, line_pts, 1.0, 3.0)
    assert ok_l.all()
    r = np.einsum("mk,mk->m", n_l, centres + off - c_l)
    np.testing.assert_allclose(r, 0.4, atol=1e-9)


def test_point_to_plane_jacobian_against_reference_and_finite_differences() -> None:
    rng = np.random.default_rng(4)
    M = 50
    p_i = rng.uniform(-10, 10, size=(M, 3))
    n = rng.normal(size=(M, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    c = rng.uniform(-10, 10, size=(M, 3))
    R, p = exp(np.array([0.3, -0.2, 1.1])), np.array([1.0, 2.0, -0.5])
    r, J = point_to_plane_system(p_i, n, c, R, p, np.ones(M))
    r_ref, J_ref = point_to_plane_reference(p_i, n, c, R, p)
    np.testing.assert_allclose(r, r_ref, atol=1e-12)
    np.testing.assert_allclose(J, J_ref, atol=1e-12)
    eps = 1e-6
    for a in range(6):
        dx = np.zeros(6)
        dx[a] = eps
        r1, _ = point_to_plane_system(p_i, n, c, R @ exp(dx[3:]), p + dx[:3], np.ones(M))
        np.testing.assert_allclose((r1 - r) / eps, J[:, a], atol=1e-5)


@pytest.mark.parametrize("backend", ["pykdtree", "small_gicp", "scipy"])
def test_knn_backends_match_brute_force(backend: str) -> None:
    rng = np.random.default_rng(5)
    pts = rng.uniform(-5, 5, size=(2000, 3))
    q = rng.uniform(-5, 5, size=(100, 3))
    idx, d2 = KnnIndex(pts, backend).query(q, 5)  # type: ignore[arg-type]
    full = np.sum((q[:, None] - pts[None]) ** 2, axis=2)
    ref = np.sort(full, axis=1)[:, :5]
    np.testing.assert_allclose(np.sort(d2, axis=1), ref, rtol=1e-9)
    np.testing.assert_allclose(np.sort(full[np.arange(100)[:, None], idx], axis=1), ref, rtol=1e-9)


def test_voxel_map_caps_voxels_and_prunes_by_distance() -> None:
    rng = np.random.default_rng(6)
    vm = VoxelMap(voxel_size=1.0, max_per_voxel=2, max_range=10.0)
    pts = rng.uniform(0, 3, size=(1000, 3))  # 27 voxels
    assert vm.add(pts) == 54
    assert vm.add(pts) == 0
    far = np.array([[50.0, 0.0, 0.0]])
    assert vm.add(far) == 1
    assert vm.prune(np.zeros(3)) == 1
    assert len(vm) == 54 and vm.add(far) == 1  # the pruned voxel is free again
    idx = voxel_downsample(pts, 1.0)
    assert len(idx) == 27


def test_ivox_matches_the_voxel_map_and_brute_force() -> None:
    """The incremental voxel-hash map admits the same points as the k-d tree map (one per voxel), grows
    its table without losing any, and its 27-cell search equals brute force wherever the k nearest lie
    within one cell (the guarantee); beyond it every returned neighbour is a true stored point and its
    distance is exact (only farther ones may be missed)."""
    rng = np.random.default_rng(8)
    pts = rng.uniform(-15, 15, size=(30000, 3))
    iv = IncrementalVoxelMap(0.5, 1, 100.0, nsub=2, capacity=64)  # forces several re-hashes
    vm = VoxelMap(0.5, 1, 100.0)
    for chunk in np.array_split(pts, 9):
        assert iv.add(chunk) == vm.add(chunk)
    assert len(iv) == len(vm)
    np.testing.assert_array_equal(np.unique(iv.points, axis=0), np.unique(vm.points, axis=0))
    q = rng.uniform(-15, 15, size=(400, 3))
    idx, d2 = iv.knn(q, 5)
    full = np.sum((q[:, None] - vm.points[None]) ** 2, axis=2)
    ref = np.sort(full, axis=1)[:, :5]
    inside = ref[:, 4] <= (2 * 0.5) ** 2
    assert inside.sum() > 20
    np.testing.assert_allclose(d2[inside], ref[inside], rtol=1e-12)
    found = idx >= 0
    got = np.sum((iv.storage[idx[found]] - np.repeat(q, 5, axis=0)[found.ravel()]) ** 2, axis=1)
    np.testing.assert_allclose(got, d2[found], rtol=1e-12)
    assert np.all(d2[found] >= np.sort(full, axis=1)[:, :5][found] - 1e-12)
    # pruning keeps exactly the points within range; a change of frame moves them and re-applies the
    # one-point-per-voxel rule in the new voxels
    n_far = int(np.sum(np.linalg.norm(iv.points - [10.0, 0, 0], axis=1) > 12.0))
    iv.max_range = 12.0
    assert iv.prune(np.array([10.0, 0, 0])) == n_far
    before = iv.points
    R = exp(np.array([0.1, -0.2, 0.3]))
    iv.transform(R, np.array([1.0, 2.0, 3.0]))
    moved = before @ R.T + [1.0, 2.0, 3.0]
    assert len(iv) == len(voxel_downsample(moved, 0.5))
    d_near = np.min(np.sum((iv.points[:, None] - moved[None]) ** 2, axis=2), axis=1)
    assert np.all(d_near < 1e-20)


def test_ivox_fused_search_fit_gate_equals_the_two_step_path() -> None:
    """The association's compiled pass (search, plane / line fit and residual gate per query,
    ``IncrementalVoxelMap.knn_fit``) keeps exactly the rows, normals, anchors and tags of the search
    followed by ``fit_planes`` / ``fit_lines`` and the gate on n . (q - c); after a prune (cells
    compacted, the occupancy bitmap rebuilt) the search still equals brute force where the k
    nearest lie within one cell."""
    rng = np.random.default_rng(21)
    # noisy patches of planes (2 cm) and lines, so that the plane test and the gate reject some rows
    base = rng.uniform(-20, 20, size=(400, 3))
    nrm = rng.normal(size=(400, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    u = np.cross(nrm, [0.3, 0.5, 0.8])
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    vv = np.cross(nrm, u)
    ab = rng.uniform(-1.5, 1.5, size=(400, 40, 2))
    pts = (base[:, None] + ab[..., :1] * u[:, None] + ab[..., 1:] * vv[:, None]
           + rng.normal(size=(400, 40, 1)) * 0.02 * nrm[:, None]).reshape(-1, 3)  # fmt: skip
    t = rng.uniform(-3, 3, size=(400, 60, 1))
    line_pts = (base[:, None] + t * nrm[:, None] + rng.normal(size=(400, 60, 3)) * 0.01).reshape(
        -1, 3
    )
    for lines, voxel, nsub, slots, thr in ((False, 0.5, 2, None, 0.1), (True, 0.25, 4, 16, 3.0)):
        iv = IncrementalVoxelMap(voxel, 1, 100.0, nsub=nsub, capacity=64, slots=slots)
        data = line_pts if lines else pts
        for i, chunk in enumerate(np.array_split(data, 5)):
            iv.add(chunk, tag=i)
        q = data[rng.integers(0, len(data), 3000)] + rng.normal(size=(3000, 3)) * 0.05
        p_i = rng.normal(size=(3000, 3))  # the same rows in another frame, carried along
        got = iv.knn_fit(q, p_i, 5, lines, 4.0, thr, 0.05)
        nbr, d2 = iv.knn(q, 5)
        fit = fit_lines if lines else fit_planes
        n, c, ok = fit(q, nbr, d2, iv.storage, 4.0, thr)
        ok &= np.abs(np.einsum("mk,mk->m", n, q - c)) < 0.05
        assert 100 < ok.sum() < len(q)  # both outcomes occur
        for a, b in zip(got, (p_i[ok], n[ok], c[ok], iv.ids[nbr[ok, 0]]), strict=True):
            np.testing.assert_array_equal(a, b)
    iv = IncrementalVoxelMap(0.5, 1, 100.0, nsub=2, capacity=64)
    iv.add(pts)
    iv.max_range = 15.0
    assert iv.prune(np.zeros(3)) > 0
    kept = iv.points
    assert np.all(np.linalg.norm(kept, axis=1) <= 15.0)
    q = rng.uniform(-12, 12, size=(500, 3))
    _, d2 = iv.knn(q, 5)
    ref = np.sort(np.sum((q[:, None] - kept[None]) ** 2, axis=2), axis=1)[:, :5]
    inside = ref[:, 4] <= 1.0
    assert inside.sum() > 20
    np.testing.assert_allclose(d2[inside], ref[inside], rtol=1e-12)


def test_pcd_and_ply_round_trip(tmp_path: object) -> None:
    from pathlib import Path

    d = Path(str(tmp_path))
    rng = np.random.default_rng(7)
    pts = rng.normal(size=(100, 3)).astype(np.float32).astype(float)
    write_pcd(d / "a.pcd", pts, np.arange(100.0))
    write_ply(d / "a.ply", pts)
    np.testing.assert_array_equal(pcd_points(d / "a.pcd"), pts)
    np.testing.assert_array_equal(read_ply(d / "a.ply"), pts)
    (d / "b.pcd").write_text(
        "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\nHEIGHT 1\n"
        "POINTS 2\nDATA ascii\n1 2 3\n4 5 6\n"
    )
    np.testing.assert_array_equal(pcd_points(d / "b.pcd"), [[1, 2, 3], [4, 5, 6]])


def test_map_covariance_transfers_a_map_pieces_error_to_the_pose() -> None:
    """``MapCovariance.transfer``'s J_kj against the geometry it stands for: a map piece placed with
    pose j's error is the truth moved by M = T_hat_j T_j^-1; a pose k registered exactly on it is
    T_hat_k = M T_k, whose error [log(R_hat_k^T R_k), p_k - p_hat_k] must be J_kj times pose j's
    (to first order: the rest is O(|e|^2 |p_k - p_j|), below 1e-6 m here against 1e-4 rad and m
    errors moved up to 3e-3 m by a 30 m lever).
    ``covariance`` is the rows' mean of J P J^T (three rows of one scan, one of another)."""
    from imuslam.geometry import log
    from imuslam.lio.estimator import MapCovariance

    rng = np.random.default_rng(5)
    R_j, p_j = exp(rng.normal(size=3)), rng.normal(size=3) * 20
    R_k, p_k = exp(rng.normal(size=3)), p_j + rng.normal(size=3) * 15
    e_j = np.r_[rng.normal(size=3) * 1e-4, rng.normal(size=3) * 1e-4]
    R_hat_j, p_hat_j = R_j @ exp(-e_j[:3]), p_j - e_j[3:]  # so that log(R_hat^T R) = e_j[:3]
    M_R = R_hat_j @ R_j.T
    M_p = p_hat_j - M_R @ p_j
    R_hat_k, p_hat_k = M_R @ R_k, M_R @ p_k + M_p
    e_k = np.r_[log(R_hat_k.T @ R_k), p_k - p_hat_k]
    C0 = np.eye(6)
    mc = MapCovariance(np.eye(3), np.zeros(3), C0)
    tag_j = mc.record(R_hat_j, p_hat_j, np.diag(np.arange(1.0, 7.0)))
    tag_i = mc.record(np.eye(3), np.zeros(3), 2 * np.eye(6))
    u, w, J = mc.transfer(np.array([tag_j], np.int32), R_hat_k, p_hat_k)
    assert len(u) == 1 and w[0] == 1.0
    np.testing.assert_allclose(J[0] @ e_j, e_k, rtol=0, atol=1e-6)
    assert np.linalg.norm(e_k[3:] - e_j[3:]) > 1e-4  # the lever term is tested, not negligible
    tags = np.array([tag_j, tag_i, tag_j, tag_j, -1], np.int32)
    C = mc.covariance(tags, R_hat_k, p_hat_k)
    _, _, Ji = mc.transfer(np.array([tag_i], np.int32), R_hat_k, p_hat_k)
    _, _, J0 = mc.transfer(np.array([-1], np.int32), R_hat_k, p_hat_k)
    ref = (3 * J[0] @ np.diag(np.arange(1.0, 7.0)) @ J[0].T + Ji[0] @ (2 * np.eye(6)) @ Ji[0].T
           + J0[0] @ C0 @ J0[0].T) / 5  # fmt: skip
    np.testing.assert_allclose(C, ref, rtol=1e-12)


def test_map_covariance_independent_own_parts_enter_as_a_weighted_mean() -> None:
    """``filter.map_correlation: independent``: a record's map-relative part ``C_rel`` enters as the
    covariance of a weighted mean of independent errors, sum_u w_u^2 J_u C_rel_u J_u^T, and the rest
    of its covariance (inherited from its map) as in the fully correlated model, sum_u w_u J_u (C_u -
    C_rel_u) J_u^T; a record without a map-relative part is the same in both models."""
    from imuslam.lio.estimator import MapCovariance

    rng = np.random.default_rng(3)
    A = rng.normal(size=(6, 6))
    C_map, C_rel = A @ A.T * 1e-6, np.diag(np.arange(1.0, 7.0)) * 1e-6
    full = MapCovariance(np.eye(3), np.zeros(3), np.zeros((6, 6)))
    ind = MapCovariance(np.eye(3), np.zeros(3), np.zeros((6, 6)), correlation="independent")
    poses = [(exp(rng.normal(size=3) * 0.1), rng.normal(size=3) * 10) for _ in range(2)]
    for mc in (full, ind):
        for R, p in poses:
            mc.record(R, p, C_map + C_rel, C_rel)
    R_k, p_k = exp(rng.normal(size=3) * 0.1), rng.normal(size=3) * 10
    tags = np.array([0, 0, 0, 1], np.int32)  # shares 3/4 and 1/4
    u, w, J = ind.transfer(tags, R_k, p_k)
    ref = sum(w[i] * J[i] @ C_map @ J[i].T + w[i] ** 2 * J[i] @ C_rel @ J[i].T for i in range(2))
    np.testing.assert_allclose(ind.covariance(tags, R_k, p_k), ref, rtol=1e-12)
    full_ref = sum(w[i] * J[i] @ (C_map + C_rel) @ J[i].T for i in range(2))
    np.testing.assert_allclose(full.covariance(tags, R_k, p_k), full_ref, rtol=1e-12)
    one = np.array([1, 1], np.int32)  # one record: w = 1, both models agree
    np.testing.assert_allclose(ind.covariance(one, R_k, p_k), full.covariance(one, R_k, p_k),
                               rtol=1e-12)  # fmt: skip


def test_map_drift_defaults_follow_the_front_end() -> None:
    """An empty ``filter.map_drift_*`` resolves to the front end in use, also when the mode is
    changed after construction (as ``imuslam lio --mode`` does); a value given is kept."""
    from imuslam.lio.config import MAP_DRIFT, FilterConfig, LioConfig

    cfg = LioConfig()
    cfg.frontend.mode = "direct"
    f = cfg.resolved().filter
    assert (f.map_drift_deg_per_sqrt_m, f.map_drift_m_per_sqrt_m) == MAP_DRIFT["direct"]
    f = LioConfig(filter=FilterConfig(map_drift_deg_per_sqrt_m=0.3)).resolved().filter
    assert (f.map_drift_deg_per_sqrt_m, f.map_drift_m_per_sqrt_m) == (0.3, MAP_DRIFT["features"][1])


def test_start_velocity_is_exact_for_constant_acceleration_and_averages_pose_noise() -> None:
    """The start's velocity (``LioEstimator.start_velocity``): exact on a constant-acceleration
    motion, and with 1 cm of pose noise within 5 sigma of the truth, sigma being the least-squares
    fit's own (the quadratic's derivative propagated from the poses' noise), which is below the
    0.07 m/s central differences of poses 0.2 s apart have."""
    from imuslam.lio.estimator import LioEstimator

    ts = 3.0 + 0.1 * np.arange(11)
    v0, a = np.array([8.0, -0.5, 0.1]), np.array([0.6, 1.2, -0.05])
    tt = ts - ts[0]
    p = tt[:, None] * v0 + 0.5 * tt[:, None] ** 2 * a
    v_true = v0 + tt[:, None] * a
    assert np.allclose(LioEstimator.start_velocity(ts, p), v_true, atol=1e-9)
    sigma = 0.01
    c = ts - ts.mean()
    V = np.vander(c, 3)
    dV = np.column_stack([2 * c, np.ones_like(c), np.zeros_like(c)])
    sd_fit = sigma * np.sqrt(np.einsum("ij,jk,ik->i", dV, np.linalg.inv(V.T @ V), dV))  # (11,)
    assert sd_fit.max() < sigma * np.sqrt(2) / 0.2
    rng = np.random.default_rng(3)
    v = LioEstimator.start_velocity(ts, p + rng.normal(0.0, sigma, p.shape))
    assert np.all(np.abs(v - v_true) < 5 * sd_fit[:, None])
