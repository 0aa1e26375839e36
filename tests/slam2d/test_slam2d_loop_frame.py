"""The 2D SLAM's loop constraint in its frame: a node matched against a finished submap whose anchor node
is NOT at the origin gives the edge anchor -> node of the true relative pose, and the pose graph puts the
node where that edge says."""

from __future__ import annotations

import numpy as np

from imuslam.sim.lidar import Lidar2dConfig, simulate_lidar2d_scan
from imuslam.sim.world import room_8x8
from imuslam.slam2d import pose2
from imuslam.slam2d.slam import Slam2d, Slam2dConfig


def _scan_at(pose_xy_yaw: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Points (P, 2) in the body frame of a simulated RPLIDAR scan (1 cm range noise) of the 8 m room
    from a static pose [x, y, yaw] (the room's frame)."""
    c, s = np.cos(pose_xy_yaw[2]), np.sin(pose_xy_yaw[2])
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    p = np.array([pose_xy_yaw[0], pose_xy_yaw[1], 0.45])

    def pose_fn(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.broadcast_to(R, (len(t), 3, 3)).copy(), np.broadcast_to(p, (len(t), 3)).copy()

    scan = simulate_lidar2d_scan(room_8x8(), pose_fn, 0.0, Lidar2dConfig(range_noise_std=0.01), rng)
    ang = scan.angle_min + np.arange(len(scan.ranges)) * scan.angle_increment
    ok = np.isfinite(scan.ranges)
    r = scan.ranges[ok].astype(float)
    return np.column_stack([r * np.cos(ang[ok]), r * np.sin(ang[ok])])


def test_loop_constraint_is_the_true_anchor_to_node_pose() -> None:
    """Local SLAM's frame is the room's frame here, shifted: the first node (the first submap's anchor)
    sits at (1.0, -0.5, 0.6 rad), the next ones around it. Eight nodes make a finished submap; a last
    node, truly at (-1.1, 0.9, -0.9 rad), comes back with a drift of (0.35 m, -0.25 m, 4 deg) in its
    local pose. Its branch-and-bound match against the finished submap is searched around the drifted
    guess; the loop constraint it gives must be the TRUE relative pose from the anchor node to it (the
    match refines to a fraction of the 5 cm cell: within 2.5 cm and 0.5 deg; a constraint written in the
    submap's or the node's frame instead of the anchor's is off by the anchor's offset, over a metre).
    The pose graph then moves the drifted node to the anchor's pose times that edge."""
    rng = np.random.default_rng(7)
    cfg = Slam2dConfig()
    cfg.scans_per_submap = 8
    cfg.loop.background = False
    cfg.loop.skip_recent_submaps = 0
    cfg.loop.every_n_nodes = 1
    cfg.loop.consistent_min = (
        1  # one match is a constraint (the consistency check has its own tests)
    )
    cfg.loop.peaks_per_match = 0
    slam = Slam2d(cfg)
    anchor = np.array([1.0, -0.5, 0.6])
    steps = [np.array([0.15 * k, 0.05 * k, 0.05 * k]) for k in range(8)]
    first = [pose2.compose(anchor, s) for s in steps]
    for k, P in enumerate(first):
        slam.add_node(k, P, _scan_at(P, rng), 0.1 * k)
    assert slam.submaps[0].finished and slam.submaps[0].anchor_node == 0
    truth = np.array([-1.1, 0.9, -0.9])
    drift = np.array([0.35, -0.25, np.deg2rad(4.0)])
    local = pose2.compose(drift, truth)
    j = len(first)
    slam.add_node(j, local, _scan_at(truth, rng), 10.0)
    assert any(c.node == j and c.submap == 0 for c in slam.loops)
    true_pose = [*first, truth]
    for c in slam.loops:  # the last node's, and the one of the node that finished the submap
        assert c.anchor == slam.submaps[c.submap].anchor_node
        d = pose2.between(pose2.between(true_pose[c.anchor], true_pose[c.node]), c.T_anchor_node)
        assert np.hypot(d[0], d[1]) < 0.025, f"node {c.node}: off by {np.hypot(d[0], d[1]):.3f} m"
        assert abs(pose2.wrap(d[2])) < np.deg2rad(0.5), f"node {c.node}: off by {d[2]:.4f} rad"
    expect = pose2.between(anchor, truth)
    # the graph: the anchor held at its pose, the drifted node joined to the first nodes by the loop
    # edge only (its local edge from node 7 carries the drift, 0.4 m, against 1 mm / 0.1 deg sigmas:
    # cut it to let the loop edge alone place the node)
    slam.cfg.loop.local_sigma_m = 1e3
    slam.cfg.loop.local_sigma_rad = 1e3
    slam.optimise()
    g = slam.node_global[j]
    want = pose2.compose(slam.node_global[0], expect)
    assert np.hypot(*(g[:2] - want[:2])) < 0.03, (
        f"node off by {np.hypot(*(g[:2] - want[:2])):.3f} m"
    )
    assert abs(pose2.wrap(g[2] - want[2])) < np.deg2rad(0.6)
