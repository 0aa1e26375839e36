"""2D SLAM on real logs: speed against real time and accuracy against corrected poses.

Freiburg benchmark logs (Kümmerle et al. 2009; raw laser + raw odometry, CARMEN): the relation error of
consecutive corrected scans (scans associated by their readings, ``imuslam.eval.relations``) for the
SLAM and for the raw odometry; wall and CPU time of the whole run (loop closure included) against the log's
duration. BreezySLAM's mine logs (wheel ticks + Hokuyo): the loop closure: where the robot passes its start again,
its scan matched against the map of the first third of the log; a closed loop needs no correction.

    python bench/slam2d.py                 # all logs (several minutes on 2 cores)
    python bench/slam2d.py --logs intel    # the speed criterion: the full Intel log
    python bench/slam2d.py --maps DIR      # also write DIR/<log>.png (map + trajectory)
    python bench/slam2d.py --logs exp1 exp2
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from imuslam.eval.slam2d_gt import relations_against_corrected
from imuslam.io.carmen import read_breezyslam, read_carmen
from imuslam.io.laserlog import LaserLog
from imuslam.slam2d import pose2
from imuslam.slam2d.grid import GridParams, ProbabilityGrid
from imuslam.slam2d.matching import bnb_match, make_index, refine_pose
from imuslam.slam2d.slam import Slam2dConfig, Slam2dResult, render_map, run_slam2d, scan_points

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
RADISH = {"intel": "intel", "fr079": "freiburg-079", "aces": "aces", "mit-csail": "csail"}


def run(log_: LaserLog, cfg: Slam2dConfig) -> tuple[Slam2dResult, float, float]:
    t0, c0 = time.perf_counter(), time.process_time()
    res = run_slam2d(log_, cfg)
    return res, time.perf_counter() - t0, time.process_time() - c0


def save_map(log_: LaserLog, res: Slam2dResult, cfg: Slam2dConfig, path: Path, title: str) -> None:
    from imuslam.io.figures import save_figure
    from imuslam.slam2d.output import map_figure

    save_figure(map_figure(render_map(log_, res.pose_xy_yaw, cfg), res, title), path)


def loop_check(
    log_: LaserLog, res: Slam2dResult, cfg: Slam2dConfig
) -> tuple[int, float, float, float, float]:
    """Where the robot comes back to its start: the scan of the last two thirds whose SLAM pose is nearest
    the start is matched against the map of the first third of the scans (branch and bound over +-1 m, +-30 deg around
    the SLAM pose, then refined). Returns that scan, its distance from the start (m), the correction the
    match makes to the SLAM pose (m, deg) and the match score: a closed loop needs no correction."""
    pts = scan_points(log_, cfg)
    P = res.pose_xy_yaw
    first = len(P) // 3
    g = ProbabilityGrid(GridParams(resolution=cfg.resolution), P[0, :2], 6.0)
    for k in range(first):
        g.insert(pose2.act(P[k], log_.T_b_l[None, :2])[0], pose2.act(P[k], pts[k]))
    prob, x0, y0 = g.cropped()
    idx = make_index(prob, x0, y0, cfg.resolution, 5)
    k = first + int(np.argmin(np.hypot(P[first:, 0] - P[0, 0], P[first:, 1] - P[0, 1])))
    dist = float(np.hypot(P[k, 0] - P[0, 0], P[k, 1] - P[0, 1]))
    best, score = bnb_match(idx, pts[k], P[k], 1.0, np.deg2rad(30.0), 0.3, 15.0)
    if score < 0:
        return k, dist, float("nan"), float("nan"), score
    ref, sc = refine_pose(prob, x0, y0, cfg.resolution, pts[k], best, best, 1.0, 0.0, 0.0, 0.1, 30)
    d = pose2.between(ref, P[k])
    return k, dist, float(np.hypot(d[0], d[1])), float(np.rad2deg(abs(d[2]))), float(sc)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--logs", nargs="*", default=[*RADISH, "exp1", "exp2"])
    ap.add_argument("--maps", default="")
    args = ap.parse_args()
    maps = Path(args.maps) if args.maps else None
    if maps:
        maps.mkdir(parents=True, exist_ok=True)
    cfg = Slam2dConfig()
    rows = []
    print("| log | scans | log duration [s] | wall [s] | CPU [s] | x real time (wall / CPU) | loops | SLAM relation error: trans [m], rot [deg] | odometry relation error | relations |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name in args.logs:
        if name in RADISH:
            c = read_carmen(DATA / "radish_freiburg_benchmark" / f"{name}.clf.bz2")
            log_ = c.laser
            res, wall, cpu = run(log_, cfg)
            assert log_.odom_xy_yaw is not None
            m = relations_against_corrected(
                DATA / "carmen_radish_corrected_ple" / f"{RADISH[name]}-corrected.log.gz", log_,
                {"slam": res.pose_xy_yaw, "odometry": log_.odom_xy_yaw},
            )  # fmt: skip
            s, o = m["slam"], m["odometry"]
            print(f"| {name} | {len(log_)} | {log_.duration_s:.0f} | {wall:.1f} | {cpu:.1f} | "
                  f"{log_.duration_s / wall:.0f} / {log_.duration_s / cpu:.0f} | {len(res.loops)} | "
                  f"{s['trans_mean']:.3f} ± {s['trans_std']:.3f}, {s['rot_mean_deg']:.2f} ± {s['rot_std_deg']:.2f} | "
                  f"{o['trans_mean']:.3f} ± {o['trans_std']:.3f}, {o['rot_mean_deg']:.2f} ± {o['rot_std_deg']:.2f} | "
                  f"{s['n']} |", flush=True)  # fmt: skip
        else:
            log_ = read_breezyslam(DATA / "breezyslam_mines" / f"{name}.dat")
            # the 4 m Hokuyo in the mine scores 0.57 on average even against its own submap: accept loop
            # matches from 0.5 (Cartographer's default global minimum score is 0.6, local 0.55)
            cfg_b = cfg.model_copy(deep=True)
            cfg_b.loop.min_score = 0.5
            res, wall, cpu = run(log_, cfg_b)
            k, dist, dm, dd, sc = loop_check(log_, res, cfg_b)
            rows.append(
                (name, len(log_), log_.duration_s, wall, cpu, len(res.loops), k, dist, dm, dd, sc)
            )
        if maps:
            save_map(log_, res, cfg, maps / f"{name}.png", name)
    if rows:
        print("\n| log | scans | duration [s] | wall [s] | CPU [s] | loops | return scan | its distance from the start [m] | correction by matching the start map [m] | [deg] | match score |")  # fmt: skip
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        for r in rows:
            print(f"| {r[0]} | {r[1]} | {r[2]:.0f} | {r[3]:.1f} | {r[4]:.1f} | {r[5]} | {r[6]} | {r[7]:.2f} | {r[8]:.3f} | {r[9]:.2f} | {r[10]:.2f} |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
