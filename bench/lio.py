"""LiDAR-inertial odometry on the simulator against KISS-ICP, measured in the same run.

    PYTHONPATH=src python bench/lio.py main      # street loop (4 laps, 137 s): imuslam modes/states vs KISS-ICP
    PYTHONPATH=src python bench/lio.py imu       # raw vs calibrated IMU x {reduced, full} x {none, kf, stkf, rwnn}, fading factor
    PYTHONPATH=src python bench/lio.py rotating  # IMU and LiDAR on a 10 Hz rotating platform vs fixed mount
    PYTHONPATH=src python bench/lio.py corridor  # LiDAR-only vs LIO in the corridor (degenerate for LiDAR)
    PYTHONPATH=src python bench/lio.py memory    # map size and peak RSS over a 30-minute drive (streamed)
    PYTHONPATH=src python bench/lio.py frontend  # the compiled front end against its numpy reference
    PYTHONPATH=src python bench/lio.py consistency  # mean NEES of the reported covariance, 6 seeds x 2 modes
    PYTHONPATH=src python bench/lio.py rowmodel  # one scan's covariance against a map from the true poses
    PYTHONPATH=src python bench/lio.py robust    # a wrong clock offset / extrinsic, without and with calibrate-lidar;
                                                 # dropped scans / IMU samples, an IMU gap, a clipped gyro, an open
                                                 # field, traffic: guards on / off, KISS-ICP (--part faults);
                                                 # the extrinsic / offset as filter states off / on (--part online)
    PYTHONPATH=src python bench/lio.py dense     # VLP-16, Ouster OS1-128 / OS1-64, Livox-like rosette: imuslam,
                                                 # rko-lio and KISS-ICP on the same scans, drift and scans/s
    PYTHONPATH=src python bench/lio.py calib     # the LiDAR-IMU calibration's errors and 1-sigma per seed, and on the street

Options: --duration S (drive length), --cache DIR (simulated drives are cached there, keyed by their
parameters). The street drive is seed 001's car loop around an urban block: VLP-16 at 10 Hz (about 28k
points a scan), IMU at 200 Hz with seed 000's table-2 errors (BWT901CL) plus noise and bias random walk.
"Calibrated" applies the table-2 correction model with its true parameters (a perfect calibration; the
bias random walk and noise stay). Drift is the KITTI translation error averaged over 100-800 m segments
(``imuslam.eval``), ATE after an SE(3) alignment; scans/s counts the estimator step only, for both.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # pykdtree's OpenMP pool stalls on a shared machine

import argparse  # noqa: E402
import pickle  # noqa: E402
import resource  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from imuslam.eval.metrics import KITTI_LENGTHS, evaluate  # noqa: E402
from imuslam.imu.model import ImuCalibration, TriadModel  # noqa: E402
from imuslam.interfaces import Trajectory  # noqa: E402
from imuslam.io.lidarsets import MemoryDataset  # noqa: E402
from imuslam.lio.config import ExtrinsicConfig, FilterConfig, FrontEndConfig, LioConfig, MapConfig  # noqa: E402
from imuslam.lio.pipeline import LioPipeline, LioResult  # noqa: E402
from imuslam.sim.drive import LidarDrive, simulate_lidar_drive  # noqa: E402
from imuslam.sim.imu import ImuErrorSpec  # noqa: E402
from imuslam.sim.imu_errors import SEED000_ACCEL, SEED000_GYRO  # noqa: E402

LAP_S = 34.32  # one lap of the street loop (sim.drive.car_loop_period_s)
FloatArr = NDArray[np.float64]


def true_calibration() -> ImuCalibration:
    """Seed 000's table-2 correction with the simulator's true parameters."""
    a, g = SEED000_ACCEL, SEED000_GYRO
    return ImuCalibration(
        TriadModel(a.T, a.K, a.b, a.bias_sign), TriadModel(g.T, g.K, g.b, g.bias_sign)
    )


def lidar_pattern(name: str) -> Any:
    """The simulator's LiDAR by name: vlp16 (the default), os1-64, os1-128 (Ouster OS1, 1024
    columns), livox (a 70 deg rosette, 240k points/s)."""
    from imuslam.sim.lidar import Lidar3dConfig

    return {"vlp16": Lidar3dConfig(), "os1-64": Lidar3dConfig.os1(64), "os1-128": Lidar3dConfig.os1(128),
            "livox": Lidar3dConfig.livox()}[name]  # fmt: skip


def drive(
    scene: str, duration: float, cache: Path, rotating_hz: float = 0.0, seed: int = 1,
    lidar: str = "vlp16",
) -> LidarDrive:  # fmt: skip
    cache.mkdir(parents=True, exist_ok=True)
    tag = "" if lidar == "vlp16" else f"_{lidar}"
    f = cache / f"{scene}_{duration:.2f}s_rot{rotating_hz:g}_seed{seed}{tag}.pkl"
    if f.exists():
        with open(f, "rb") as fh:
            d: LidarDrive = pickle.load(fh)
            return d
    t0 = time.perf_counter()
    d = simulate_lidar_drive(scene, duration, seed, rotating_platform_hz=rotating_hz, progress=True,
                             lidar=lidar_pattern(lidar))  # fmt: skip
    print(f"simulated {scene} {duration:g} s in {time.perf_counter() - t0:.0f} s")
    with open(f, "wb") as fh:
        pickle.dump(d, fh)
    return d


def truth(d: LidarDrive) -> Trajectory:
    return Trajectory(d.gt_t_ns, d.gt_p_w, d.gt_R_w_b, "simulator truth")


def metrics(gt: Trajectory, est: Trajectory) -> dict[str, float]:
    res = evaluate(gt, est, "se3", 1.0, "frames", 0.02, KITTI_LENGTHS)
    kd = [v[0] for v in res.kitti.values()]
    return {"drift_pct": float(np.mean(kd)) if kd else float("nan"), "ate_m": res.ape_trans.rmse,
            "rot_deg": res.ape_rot_deg.rmse}  # fmt: skip


def run_imuslam(d: LidarDrive, mode: str = "direct", state: str = "full", align: str = "none",
                imu: str = "cal", use_imu: bool = True, indoor: bool = False,
                map_covariance: bool = True, scan_voxel: float = 1.0) -> tuple[LioResult, Trajectory]:  # fmt: skip
    # indoors (the 2 m corridor) the walls are closer than the outdoor 1 m minimum range and 1 m voxels
    fe = (
        FrontEndConfig(mode=mode, scan_voxel=0.25, min_range=0.2)
        if indoor
        else FrontEndConfig(mode=mode, scan_voxel=scan_voxel)
    )  # type: ignore[arg-type]
    cfg = LioConfig(
        frontend=fe,
        map=MapConfig(voxel=0.2 if indoor else 0.5),
        extrinsic=ExtrinsicConfig(p_i_l=tuple(d.T_i_l[:3, 3])),  # type: ignore[arg-type]
        filter=FilterConfig(state=state, map_covariance=map_covariance),  # type: ignore[arg-type]
        align=align,  # type: ignore[arg-type]
        use_imu=use_imu,
    )
    log = true_calibration().correct(d.imu) if imu == "cal" else d.imu
    res = LioPipeline(
        MemoryDataset(d.scans, log if use_imu else None, "sim"), cfg, progress=False
    ).run()
    est = res.trajectory
    if (
        d.platform_rate and use_imu
    ):  # the vehicle from the platform (encoder) angle: R_w_b = R_w_i R_b_i^T
        R_b_i = d.R_b_i(est.t_ns)
        est = Trajectory(est.t_ns, est.p_w, est.R_w_b @ np.swapaxes(R_b_i, 1, 2), est.source)
    return res, est


def run_kiss(d: LidarDrive) -> tuple[Trajectory, float, float]:
    from kiss_icp.config import KISSConfig
    from kiss_icp.kiss_icp import KissICP

    cfg = KISSConfig()
    cfg.data.max_range, cfg.data.min_range, cfg.data.deskew = 100.0, 1.0, True
    cfg.mapping.voxel_size = 1.0  # max_range / 100, KISS-ICP's own rule
    k = KissICP(cfg)
    poses, t_ns, el, cpu = [], [], 0.0, 0.0
    for s in d.scans:
        pts = s.points_l.astype(np.float64)
        ts = s.t_offset_s.astype(np.float64)
        ts = (ts - ts.min()) / max(
            float(ts.max() - ts.min()), 1e-9
        )  # normalised per scan, as its readers do
        t0, c0 = time.perf_counter(), time.process_time()
        k.register_frame(pts, ts)
        el += time.perf_counter() - t0
        cpu += time.process_time() - c0  # all of its threads
        poses.append(k.last_pose.copy())
        t_ns.append(s.t_ns + int(round(float(s.t_offset_s.max()) * 1e9)))
    P = np.array(poses)
    T_l_i = np.linalg.inv(d.T_i_l)
    P = P @ T_l_i  # LiDAR poses -> the body (IMU) frame, as the truth
    traj = Trajectory(np.array(t_ns), P[:, :3, 3], P[:, :3, :3], "kiss-icp")
    return traj, len(d.scans) / el, len(d.scans) / cpu


def run_rko(d: LidarDrive, imu: Any) -> tuple[Trajectory, float]:
    """rko-lio (PyPI ``rko-lio``, C++) on the same scans and the same (calibrated) IMU: the IMU samples
    up to each scan's end, then the scan with absolute per-point times; its base frame is the IMU's.
    Returns the IMU poses at the scan ends and scans/s (wall) of its scan step (IMU feeding included)."""
    from rko_lio.config import LIOConfig
    from rko_lio.lio import LIO

    lio = LIO(LIOConfig(max_range=100.0, min_range=1.0))
    eye = np.eye(4)
    t_imu, j, el = imu.t_ns, 0, 0.0
    poses, t_ns = [], []
    for s in d.scans:
        t_pts = s.t_ns + np.round(s.t_offset_s.astype(np.float64) * 1e9).astype(np.int64)
        end = int(t_pts.max())
        t0 = time.perf_counter()
        while j < len(t_imu) and t_imu[j] <= end:
            lio.add_imu_measurement(imu.accel[j], imu.gyro[j], int(t_imu[j]), eye)
            j += 1
        lio.register_scan(s.points_l.astype(np.float64), t_pts, d.T_i_l)
        el += time.perf_counter() - t0
        poses.append(lio.pose().copy())
        t_ns.append(end)
    P = np.array(poses)
    return Trajectory(np.array(t_ns), P[:, :3, 3], P[:, :3, :3], "rko-lio"), len(d.scans) / el


def dense_bench(args: Any) -> None:
    """The street drive with each simulated LiDAR (``--patterns``: VLP-16 27k points a scan, Ouster
    OS1-64 61k and OS1-128 122k at 1024 columns, a Livox-like 70 deg rosette 19k) at 10 Hz: imuslam
    ``lio`` with the default config (``--dense-voxel V``: ``frontend.scan_voxel`` V m instead of the
    default 1 m for scans of more than 40k points: the scan downsampled before matching, FAST-LIO2's
    point filter), rko-lio (PyPI, C++) and KISS-ICP (C++, all cores, LiDAR only) on the same scans in
    the same run: drift, rotation, ATE, scans/s (wall, the estimator step), scans per CPU second
    (imuslam: its estimator step, one thread; KISS-ICP: all its threads; rko-lio: not measured) and the
    wall ratio to KISS-ICP's. On a shared machine the wall figure is the share of the cores the run got;
    the CPU figure is the one that holds (the 1-minute load average is printed)."""
    from dataclasses import replace

    dur = args.duration or 20.0
    rows = []
    first = True
    with open("/proc/loadavg") as f:
        load0 = f.read().split()[0]
    for name in args.patterns:
        d = drive("street", dur, args.cache, lidar=name)
        gt = truth(d)
        npts = float(np.mean([len(s) for s in d.scans]))
        if first:  # load the compiled kernels before any timing
            run_imuslam(replace(d, scans=d.scans[:20]), "direct", "full")
            first = False
        kt, ksps, kcps = run_kiss(d)
        dense = args.dense_voxel is not None and len(d.scans[0]) > 40000
        res, est = run_imuslam(d, "direct", "full", scan_voxel=args.dense_voxel if dense else 1.0)
        imu = true_calibration().correct(d.imu)
        try:
            rt, rsps = run_rko(d, imu)
            rm: dict[str, float] | None = metrics(gt, rt)
        except Exception as exc:  # a failing anchor is a row of the table
            print(f"rko-lio failed on {name}: {exc}")
            rm, rsps = None, float("nan")
        rows.append((name, npts, metrics(gt, est), res.scans_per_s, res.scans_per_cpu_s, rm, rsps,
                     metrics(gt, kt), ksps, kcps))  # fmt: skip
    with open("/proc/loadavg") as f:
        load1 = f.read().split()[0]
    voxel = (
        "1 m (default)" if args.dense_voxel is None else f"{args.dense_voxel:g} m above 40k points"
    )
    print(f"scan_voxel {voxel}; 1-minute load average {load0} at the start, {load1} at the end, "
          f"{os.cpu_count()} cores")  # fmt: skip
    print("| LiDAR | points / scan | run | KITTI drift % | rotation RMSE deg | ATE m | scans/s (wall) "
          "| scans per CPU s | wall speed / KISS-ICP |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|")
    for name, npts, m, sps, cps, rm, rsps, km, ksps, kcps in rows:
        for run, mm, ss, cc in (
            ("imuslam lio", m, sps, f"{cps:.1f}"),
            ("rko-lio 0.4.0", rm, rsps, "-"),
            ("KISS-ICP 1.x", km, ksps, f"{kcps:.1f}"),
        ):
            cells = (
                " | ".join(f"{mm[k]:.3f}" for k in ("drift_pct", "rot_deg", "ate_m"))
                if mm
                else "failed | |"
            )
            print(
                f"| {name} | {npts / 1e3:.0f}k | {run} | {cells} | {ss:.1f} | {cc} | {ss / ksps:.2f} |"
            )


def row(name: str, m: dict[str, float], sps: float, extra: str = "") -> str:
    return f"| {name} | {m['drift_pct']:.3f} | {m['rot_deg']:.3f} | {m['ate_m']:.3f} | {sps:.1f} |{extra}"


HEAD = "| run | KITTI drift % | rotation RMSE deg | ATE m | scans/s |"
SEP = "|---|---|---|---|---|"


def main_bench(args: Any) -> None:
    d = drive("street", args.duration or 137.5, args.cache)  # four laps and a little
    gt = truth(d)
    print(f"street loop: {len(d.scans)} scans, {gt.path_length:.0f} m, closes every {LAP_S:.1f} s")
    from dataclasses import replace

    for mode in ("features", "direct"):  # load the compiled kernels before any timing
        run_imuslam(replace(d, scans=d.scans[:20]), mode, "full")
    kt, ksps, kcpu = run_kiss(d)
    km = metrics(gt, kt)
    print("| run | KITTI drift % | rotation RMSE deg | ATE m | scans per CPU s | scans/s (wall) "
          "| drift / KISS | CPU speed / KISS | wall speed / KISS |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|")

    def line(name: str, m: dict[str, float], cps: float, sps: float) -> None:
        print(f"| {name} | {m['drift_pct']:.3f} | {m['rot_deg']:.3f} | {m['ate_m']:.3f} | {cps:.1f} | "
              f"{sps:.1f} | {m['drift_pct'] / km['drift_pct']:.2f} | {cps / kcpu:.2f} | {sps / ksps:.2f} |", flush=True)  # fmt: skip

    line("KISS-ICP 1.x (C++, all cores)", km, kcpu, ksps)
    runs = [(f"imuslam lio {mode} {state}", mode, state, True)
            for mode in ("features", "direct") for state in ("reduced", "full")]  # fmt: skip
    runs.append(("imuslam LiDAR-only direct", "direct", "full", False))
    for name, mode, state, use_imu in runs:
        res, est = run_imuslam(d, mode, state, "none", "cal", use_imu=use_imu,
                               map_covariance=not args.no_map_covariance)  # fmt: skip
        line(name, metrics(gt, est), res.scans_per_cpu_s, res.scans_per_s)


def imu_bench(args: Any) -> None:
    d = drive("street", args.duration or LAP_S + 1.0, args.cache)
    gt = truth(d)
    print(f"street loop, {len(d.scans)} scans, {gt.path_length:.0f} m, direct mode")
    print(
        "| IMU | state | align | KITTI drift % | rotation RMSE deg | ATE m | largest fading factor |"
    )
    print("|---|---|---|---|---|---|---|")
    for imu in ("raw", "cal"):
        for state in ("reduced", "full"):
            for align in ("none", "kf", "stkf", "rwnn"):
                try:
                    res, est = run_imuslam(d, "direct", state, align, imu)
                    m = metrics(gt, est)
                    # the strong tracking filter's fading factor over the alignment (1: the Kalman filter)
                    fade = (
                        "-" if res.alignment is None else f"{float(res.alignment.fading.max()):.3f}"
                    )
                    print(
                        f"| {imu} | {state} | {align} | {m['drift_pct']:.3f} | {m['rot_deg']:.3f} | {m['ate_m']:.3f} | {fade} |"
                    )
                except Exception as exc:  # a diverging run is a result of the table
                    print(
                        f"| {imu} | {state} | {align} | failed: {str(exc).splitlines()[0][:80]} | | | |"
                    )


def rotating_bench(args: Any) -> None:
    dur = args.duration or LAP_S + 1.0
    print(HEAD)
    print(SEP)
    for hz in (0.0, 10.0):
        d = drive("street", dur, args.cache, rotating_hz=hz)
        gt = truth(d)
        for state in ("reduced", "full"):
            res, est = run_imuslam(d, "direct", state, "none", "cal")
            print(
                row(
                    f"{'rotating 10 Hz' if hz else 'fixed mount'} {state}",
                    metrics(gt, est),
                    res.scans_per_s,
                )
            )


def corridor_bench(args: Any) -> None:
    d = drive("corridor", args.duration or 30.0, args.cache)
    gt = truth(d)
    print(f"corridor: {len(d.scans)} scans, {gt.path_length:.1f} m")
    print("| run | ATE m | final error m | rotation RMSE deg |")
    print("|---|---|---|---|")
    for name, use_imu in (("LiDAR-only", False), ("LIO full", True)):
        try:
            _, est = run_imuslam(d, "direct", "full", "none", "cal", use_imu=use_imu, indoor=True)
            res = evaluate(gt, est, "se3", 1.0, "frames", 0.02)
            r, ea = res.reference, res.estimate_aligned
            fin = float(np.linalg.norm(ea.p_w[-1] - r.p_w[-1]))
            print(f"| {name} | {res.ape_trans.rmse:.3f} | {fin:.3f} | {res.ape_rot_deg.rmse:.3f} |")
        except Exception as exc:
            print(f"| {name} | failed: {str(exc).splitlines()[0][:80]} | | |")


def memory_bench(args: Any) -> None:
    """The street loop for ``--duration`` s (default 30 min), each scan simulated, registered and
    dropped (nothing of the drive is kept but the IMU log), with a coarser LiDAR than the other
    benches (``--columns``, default 450 per turn: about 7k points a scan) so the simulation is
    affordable; prints the local map size and the process's peak RSS every ``--every`` scans."""
    from imuslam.lio.estimator import LioEstimator
    from imuslam.sim.drive import T0_NS
    from imuslam.sim.imu import ImuErrorSpec, simulate_imu
    from imuslam.sim.lidar import Lidar3dConfig, simulate_lidar3d_scan
    from imuslam.sim.trajectory import CarLoop
    from imuslam.sim.world import urban_block

    dur = args.duration or 1800.0
    rng = np.random.default_rng(1)
    traj, world = CarLoop(), urban_block()
    imu, _ = simulate_imu(traj, dur, rng, ImuErrorSpec.bwt901cl(), 200.0, t0_ns=T0_NS)
    p_b_l = np.array([0.0, 0.0, 0.2])

    def pose_w_l(t: Any) -> tuple[Any, Any]:  # the fixed mount of sim.drive
        st = traj.state(t)
        return st.R_w_b, st.p_w + st.R_w_b @ p_b_l

    lcfg = Lidar3dConfig()
    lcfg.columns = args.columns
    cfg = LioConfig(frontend=FrontEndConfig(mode="direct", scan_voxel=1.0),
                    extrinsic=ExtrinsicConfig(p_i_l=tuple(p_b_l)))  # type: ignore[arg-type]  # fmt: skip
    est = LioEstimator(cfg, true_calibration().correct(imu))
    n = int(np.floor(dur * lcfg.rate_hz + 1e-9))
    print(
        f"street loop {dur:g} s, {n} scans, VLP-16 with {lcfg.columns} columns, direct mode, full state"
    )
    print(
        "| scans | drive min | local map points | map MB | peak RSS MB | position error m (from the filter start) | CPU s |"
    )
    print("|---|---|---|---|---|---|---|")
    c0 = time.process_time()
    anchor = None
    for k in range(n):
        sc = simulate_lidar3d_scan(world, pose_w_l, k / lcfg.rate_hz, lcfg, rng)
        t = k / lcfg.rate_hz + sc.t_offset_s.astype(np.float64)
        T = est.register_scan(sc.points_l.astype(np.float64), t, sc.ring)
        st = traj.state(np.array([float(t.max())]))
        T_true = np.eye(4)
        T_true[:3, :3], T_true[:3, 3] = st.R_w_b[0], st.p_w[0]
        if anchor is None and est.eskf is not None:  # the filter's world against the truth's, once
            anchor = T @ np.linalg.inv(T_true)
        if (k + 1) % args.every == 0 or k == n - 1:
            err = (
                float(np.linalg.norm((anchor @ T_true)[:3, 3] - T[:3, 3]))
                if anchor is not None
                else np.nan
            )
            rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
            print(f"| {k + 1} | {(k + 1) / lcfg.rate_hz / 60:.1f} | {len(est.map)} | {est.map.nbytes / 1e6:.1f} | "
                  f"{rss:.0f} | {err:.2f} | {time.process_time() - c0:.0f} |", flush=True)  # fmt: skip


def frontend_bench(args: Any) -> None:
    """CPU time per scan of the front end (deskewed scan -> registered points), the compiled one-pass
    kernel against the numpy path it replaced, on the street drive's scans (the same points out)."""
    from imuslam.lio.frontend import select_points, select_points_reference

    d = drive("street", args.duration or 12.0, args.cache)
    scans = d.scans
    print(f"street loop, {len(scans)} scans, CPU ms per scan (best of 3 passes)")
    print("| mode | compiled ms | numpy reference ms | speed-up | plane points | edge points |")
    print("|---|---|---|---|---|---|")
    for mode in ("features", "direct"):
        cfg = FrontEndConfig(mode=mode)  # type: ignore[arg-type]
        data = [(s.points_l.astype(np.float64), s.t_offset_s.astype(np.float64), np.asarray(s.ring))
                for s in scans]  # fmt: skip
        select_points(*data[0], cfg)  # compile
        best = {}
        for name, fn in (("fast", select_points), ("ref", select_points_reference)):
            times = []
            for _ in range(3):
                c0 = time.process_time()
                out = [fn(p, t, r, cfg) for p, t, r in data]
                times.append(time.process_time() - c0)
            best[name] = min(times) / len(data) * 1e3
        n_p = np.mean([len(o[0]) for o in out])
        n_e = np.mean([len(o[1]) for o in out])
        print(f"| {mode} | {best['fast']:.2f} | {best['ref']:.2f} | {best['ref'] / best['fast']:.1f}x | "
              f"{n_p:.0f} | {n_e:.0f} |")  # fmt: skip


def _consistency_run(d: LidarDrive, mode: str, state: str, true_gravity: bool = False,
                     use_imu: bool = True, g_w: list[FloatArr] | None = None,
                     drift: list[float] | None = None, map_covariance: bool = True,
                     map_voxel: float = 0.5, sensor_noise: bool = False,
                     map_correlation: str = "full", lidar: tuple[float, float] = (0.05, 30.0),
                     lidar_model: str = "dof", range_std: float = 0.02,
                     split: list[tuple[float, float]] | None = None,
                     cpu: list[float] | None = None,
                     start_covariance: bool = False) -> tuple[FloatArr, FloatArr, FloatArr]:  # fmt: skip
    """Register ``d``'s scans one by one (calibrated IMU); returns, for the scans after the filter
    start (all scans without the IMU), the NEES of [attitude, position] against the reported 6 x 6
    covariance (NaN without the IMU), the body-frame attitude error (K, 3) rad and the position error
    (K, 3) m, in the world of the first IMU pose (the first scan end; the filter's levelling R_w_i0
    applied once), the truth at the first sample at or after each scan end. ``sensor_noise``: the
    filter's IMU noise densities and bias random walks set to the simulated IMU's
    (``ImuErrorSpec.bwt901cl``: the MPU-9250 datasheet's densities) instead of the config defaults.
    ``cpu``: filled with the CPU time of each filter scan (after the start), s."""
    from imuslam.geometry import log as so3_log
    from imuslam.lio.estimator import LioEstimator
    from imuslam.lio.lidar_only import LidarOdometry

    imu_noise: dict[str, float] = {}
    if sensor_noise:
        spec = ImuErrorSpec.bwt901cl()
        imu_noise = {"accel_noise": spec.accel_density, "gyro_noise": float(spec.gyro_density),
                     "accel_bias_rw": spec.accel_bias_rw, "gyro_bias_rw": spec.gyro_bias_rw}  # fmt: skip
    cfg = LioConfig(frontend=FrontEndConfig(mode=mode),  # type: ignore[arg-type]
                    map=MapConfig(voxel=map_voxel),
                    extrinsic=ExtrinsicConfig(p_i_l=tuple(d.T_i_l[:3, 3])),  # type: ignore[arg-type]
                    filter=FilterConfig(state=state, map_covariance=map_covariance,  # type: ignore[arg-type]
                                        map_correlation=map_correlation,
                                        lidar_std=lidar[0], lidar_dof=lidar[1],
                                        lidar_model=lidar_model, lidar_range_std=range_std,  # type: ignore[arg-type]
                                        start_covariance=start_covariance,
                                        **imu_noise),  # type: ignore[arg-type]
                    use_imu=use_imu)  # fmt: skip
    if drift is not None:  # --map-drift: the rates of both front ends replaced
        cfg.filter.map_drift_deg_per_sqrt_m, cfg.filter.map_drift_m_per_sqrt_m = drift[0], drift[1]
    imu = true_calibration().correct(d.imu)
    est = LioEstimator(cfg, imu) if use_imu else None
    lo = None if use_imu else LidarOdometry(cfg)
    t_ref = d.imu.t_ns[0]
    rows: list[tuple[int, FloatArr, FloatArr | None]] = []
    for s in d.scans:
        t = (s.t_ns - t_ref) * 1e-9 + s.t_offset_s.astype(np.float64)
        pts = s.points_l.astype(np.float64)
        t_end = t_ref + int(round(t.max() * 1e9))
        if est is None:
            assert lo is not None
            rows.append((t_end, lo.register_scan(pts, t, s.ring), None))
            continue
        started = est.eskf is not None
        c0 = time.process_time()
        T = est.register_scan(pts, t, s.ring)
        if started and cpu is not None:
            cpu.append(time.process_time() - c0)
        if est.eskf is not None and not started and true_gravity:  # the filter's g set to the truth
            g0 = int(np.searchsorted(d.gt_t_ns, rows[0][0] if rows else t_end))
            R_a = est.T_w_i0[:3, :3] @ d.gt_R_w_b[min(g0, len(d.gt_t_ns) - 1)].T
            est.eskf.x.g_n[:] = R_a @ np.array([0.0, 0.0, -cfg.filter.g])
        if est.covariance is not None:
            if g_w is not None and est.eskf is not None:
                g_w.append(est.eskf.x.g_n.copy())  # the filter's gravity after each scan
            idx = np.r_[est.layout.TH, est.layout.P]
            rows.append((t_end, T, est.covariance[np.ix_(idx, idx)]))
        elif not rows:
            rows.append((t_end, T, None))  # the first scan end defines the world
    t0 = rows[0][0]
    n = len(d.gt_t_ns) - 1
    g0 = min(int(np.searchsorted(d.gt_t_ns, t0)), n)
    R_w_i0 = est.T_w_i0[:3, :3] if est is not None else np.eye(3)
    R_a = R_w_i0 @ d.gt_R_w_b[g0].T
    if g_w is not None:  # the true gravity in this world, last
        g_w.append(R_a @ np.array([0.0, 0.0, -cfg.filter.g]))
    nees, e_th, e_p = [], [], []
    split = [] if split is None else split
    for t_end, T, C in rows[1:] if est is not None else rows:
        g = min(int(np.searchsorted(d.gt_t_ns, t_end)), n)
        th = so3_log(T[:3, :3].T @ (R_a @ d.gt_R_w_b[g]))
        dp = R_a @ (d.gt_p_w[g] - d.gt_p_w[g0]) - T[:3, 3]
        e = np.r_[th, dp]
        nees.append(float(e @ np.linalg.solve(C, e)) if C is not None else np.nan)
        if C is not None:  # the attitude's and the position's own 3-dof NEES (marginal blocks)
            split.append((float(th @ np.linalg.solve(C[:3, :3], th)),
                          float(dp @ np.linalg.solve(C[3:, 3:], dp))))  # fmt: skip
        e_th.append(th)
        e_p.append(dp)
    return np.array(nees), np.array(e_th), np.array(e_p)


def consistency_bench(args: Any) -> None:
    """Mean NEES of the reported covariance per seed and front end (``LioEstimator.covariance``: the
    filter's map-relative covariance plus ``MapCovariance``'s consider term with the map's drift),
    against the chi-square band of the mean; with ``--diagnose`` the first seed's attitude errors
    with LiDAR alone and with the filter started at the true gravity (README, LIO covariance)."""
    from scipy.stats import chi2

    dur = args.duration or 6.0
    modes = ["direct", "features"]
    print(f"street excerpt {dur:g} s, {args.state} state, calibrated IMU; mean NEES of [attitude, "
          f"position] (6 dof) in the world of the first IMU pose")  # fmt: skip
    print("| seed | " + " | ".join(modes) + " | n | chi2 band 0.1-99.9 % | CPU s |")
    print("|---" * (len(modes) + 4) + "|")
    for seed in args.seeds:
        d = drive("street", dur, args.cache, seed=seed)
        c0 = time.process_time()
        means, n = [], 0
        for mode in modes:
            split: list[tuple[float, float]] = []
            cpu: list[float] = []
            nees, e_th, e_p = _consistency_run(d, mode, args.state, drift=args.map_drift,
                                          map_covariance=not args.no_map_covariance,
                                          map_voxel=args.map_voxel, sensor_noise=args.sensor_noise,
                                          map_correlation=args.map_correlation, split=split,
                                          lidar=(args.lidar_std, args.lidar_dof),
                                          lidar_model=args.lidar_model,
                                          range_std=args.range_std, cpu=cpu,
                                          start_covariance=args.start_covariance)  # fmt: skip
            cell = f"{np.mean(nees):.2f}"
            if args.split:
                sp = np.array(split)
                cell += (f" (att {sp[:, 0].mean():.2f}, pos {sp[:, 1].mean():.2f}; RMS "
                         f"{np.rad2deg(np.sqrt(np.mean(e_th**2))):.3f} deg, "
                         f"{1e3 * np.sqrt(np.mean(e_p**2)):.1f} mm; filter CPU "
                         f"{1e3 * np.median(cpu):.0f} ms/scan median)")  # fmt: skip
            means.append(cell)
            n = len(nees)
        lo, hi = chi2.ppf(0.001, 6 * n) / n, chi2.ppf(0.999, 6 * n) / n
        print(f"| {seed} | " + " | ".join(means) + f" | {n} | [{lo:.2f}, {hi:.2f}] | "
              f"{time.process_time() - c0:.1f} |")  # fmt: skip
    if args.diagnose:
        d = drive("street", dur, args.cache, seed=args.seeds[0])
        g_w: list[FloatArr] = []
        _, th, _ = _consistency_run(d, "direct", args.state, g_w=g_w)
        g_true = g_w.pop()
        ang = [np.rad2deg(np.arccos(np.clip(g @ g_true / np.linalg.norm(g) / np.linalg.norm(g_true), -1, 1)))
               for g in g_w]  # fmt: skip
        _, th_g, _ = _consistency_run(d, "direct", args.state, true_gravity=True)
        _, th_lo, _ = _consistency_run(d, "direct", args.state, use_imu=False)
        deg = np.rad2deg
        print(f"seed {args.seeds[0]}, direct: body attitude error (roll, pitch) ranges, deg")
        for name, e in (("LIO", th), ("LiDAR only", th_lo)):
            print(f"  {name}: roll {deg(e[:, 0].min()):.2f} to {deg(e[:, 0].max()):.2f}, pitch "
                  f"{deg(e[:, 1].min()):.2f} to {deg(e[:, 1].max()):.2f}")  # fmt: skip
        print(f"  the filter's gravity against the true one: {ang[0]:.2f} deg at the filter start, "
              f"{ang[-1]:.2f} deg at the last scan")  # fmt: skip
        print(f"  LIO started at the true gravity: largest change of a scan's attitude error "
              f"{deg(np.max(np.linalg.norm(th_g - th, axis=1))):.3f} deg")  # fmt: skip


def _rowmodel_run(d: LidarDrive, mode: str, map_voxel: float = 0.5,
                  range_std: float = 0.02, map_scans: int = 10) -> dict[str, FloatArr]:  # fmt: skip
    """Each scan registered on its own against a map built from the TRUE poses of the scans before it
    (the points keep their range noise; the scan deskewed with the true motion), from the true pose:
    per scan [NEES 6, attitude NEES 3, position NEES 3, |attitude error| deg, |position error| mm] of
    the registration's covariance, for the rows' noise model (``filter.lidar_model: plane``,
    ``lio.rowcov``) and the default (diagonal ``lidar_std``^2 scaled by M / ``lidar_dof``, the metric
    Huber). Isolates one scan's covariance from the filter's prior, its start and the map's pose errors."""
    from imuslam.geometry import log as so3_log
    from imuslam.lio.frontend import select_points
    from imuslam.lio.lidar_only import gauss_newton
    from imuslam.lio.matcher import LocalMap, MatchParams, huber_weights
    from imuslam.lio.rowcov import SensorOrigins, gauss_newton_rows

    R_i_l, p_i_l = d.T_i_l[:3, :3], d.T_i_l[:3, 3]
    fe, fc = FrontEndConfig(mode=mode), FilterConfig()  # type: ignore[arg-type]
    lmap = LocalMap(map_voxel, 100.0, 1, "ivox", MatchParams())
    origins = SensorOrigins()
    out: dict[str, list[list[float]]] = {"plane": [], "dof": []}

    def row(e: FloatArr, C: FloatArr) -> list[float]:  # e, C on [dp, dtheta]
        return [float(e @ np.linalg.solve(C, e)), float(e[3:] @ np.linalg.solve(C[3:, 3:], e[3:])),
                float(e[:3] @ np.linalg.solve(C[:3, :3], e[:3])),
                float(np.rad2deg(np.linalg.norm(e[3:]))), float(1e3 * np.linalg.norm(e[:3]))]  # fmt: skip

    for j, s in enumerate(d.scans):
        x_l, t, pe, Re = d.true_deskewed(j)  # the LiDAR frame at the scan end, true deskew
        surf_l, edge_l = select_points(x_l, t - t.min(), s.ring, fe)
        surf, edge = surf_l @ R_i_l.T + p_i_l, edge_l @ R_i_l.T + p_i_l
        if j >= map_scans:  # a map of ``map_scans`` scans first (ten by default)
            Rk, pk, _, _, C = gauss_newton_rows(lmap, surf, edge, Re, pe, range_std, origins,
                                                coarse=False, p_s=p_i_l)  # fmt: skip
            out["plane"].append(row(np.r_[pe - pk, so3_log(Rk.T @ Re)], C))
            reg = gauss_newton(lmap, surf, edge, Re, pe, huber=0.2)
            corr = lmap.associate(surf, edge, reg.R_w_s, reg.p_w)
            r, J = corr.system(reg.R_w_s, reg.p_w)
            Rd = max(1.0, len(r) / fc.lidar_dof) * fc.lidar_std**2 / huber_weights(r, 0.2)
            C = np.linalg.inv(J.T @ (J / Rd[:, None]))
            out["dof"].append(row(np.r_[pe - reg.p_w, so3_log(reg.R_w_s.T @ Re)], C))
        lmap.insert(surf, edge, Re, pe, j)
        origins.record(j, Re @ p_i_l + pe)
    return {k: np.array(v) for k, v in out.items()}


def rowmodel_bench(args: Any) -> None:
    """Per-scan consistency of the LiDAR rows' noise model (``_rowmodel_run``), per seed and front end."""
    from scipy.stats import chi2

    dur = args.duration or 6.0
    print(f"street excerpt {dur:g} s: each scan against a map from the true poses, from the true pose; "
          f"mean NEES 6 dof (attitude 3, position 3) and mean |error| (deg, mm); map voxel "
          f"{args.map_voxel:g} m, range noise {args.range_std:g} m")  # fmt: skip
    print(
        "| seed | mode | plane (lio.rowcov) | default (5 cm, 30 dof) | n | chi2 band 6 dof | CPU s |"
    )
    print("|---|---|---|---|---|---|---|")
    for seed in args.seeds:
        d = drive("street", dur, args.cache, seed=seed)
        for mode in ("direct", "features"):
            c0 = time.process_time()
            res = _rowmodel_run(d, mode, args.map_voxel, args.range_std, args.map_scans)
            cells = [f"{a[:, 0].mean():.2f} ({a[:, 1].mean():.2f}, {a[:, 2].mean():.2f}); "
                     f"{a[:, 3].mean():.4f} deg, {a[:, 4].mean():.2f} mm" for a in (res["plane"], res["dof"])]  # fmt: skip
            n = len(res["plane"])
            lo, hi = chi2.ppf(0.001, 6 * n) / n, chi2.ppf(0.999, 6 * n) / n
            print(f"| {seed} | {mode} | {cells[0]} | {cells[1]} | {n} | [{lo:.2f}, {hi:.2f}] | "
                  f"{time.process_time() - c0:.1f} |")  # fmt: skip


RIG_T_I_L_RPY_DEG = (5.0, -3.0, 90.0)  # roll, pitch, yaw of the LiDAR on the IMU (the tests' rig)
RIG_P_I_L = (0.1, -0.05, 0.15)


def rig_T_i_l() -> FloatArr:
    """The rig's true LiDAR pose on the IMU (4 x 4)."""
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    r, p, y = RIG_T_I_L_RPY_DEG
    T[:3, :3] = Rotation.from_euler("ZYX", [y, p, r], degrees=True).as_matrix()
    T[:3, 3] = RIG_P_I_L
    return T


def extrinsic(R: FloatArr, p: FloatArr, offset_s: float) -> ExtrinsicConfig:
    """The config's extrinsic from a rotation, a lever arm and a clock offset."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return ExtrinsicConfig(p_i_l=tuple(p), quat_wxyz_i_l=(w, x, y, z), time_offset_s=offset_s)  # type: ignore[arg-type]


def off_by_2deg_10cm(R: FloatArr, p: FloatArr) -> tuple[FloatArr, FloatArr]:
    """The start the tests use: the rotation turned 2 deg about (1, 1, 1), the lever arm moved 10 cm
    along (1, -1, 1)."""
    from scipy.spatial.transform import Rotation

    dR = Rotation.from_rotvec(np.deg2rad(2.0) * np.ones(3) / np.sqrt(3)).as_matrix()
    return dR @ R, p + 0.1 * np.array([1.0, -1.0, 1.0]) / np.sqrt(3)


def rig(duration: float, offset_s: float, cache: Path, seed: int = 1) -> Any:
    """The excited LiDAR-IMU rig of tests/lio/test_lio_extrinsic.py (900 columns), cached."""

    from imuslam.sim.drive import simulate_lidar_imu_rig
    from imuslam.sim.lidar import Lidar3dConfig

    cache.mkdir(parents=True, exist_ok=True)
    f = cache / f"rig_{duration:.2f}s_off{offset_s * 1e3:g}ms_seed{seed}.pkl"
    if f.exists():
        with open(f, "rb") as fh:
            return pickle.load(fh)
    d = simulate_lidar_imu_rig(
        "excited", duration, seed, rig_T_i_l(), offset_s, lidar=Lidar3dConfig(columns=900)
    )
    with open(f, "wb") as fh:
        pickle.dump(d, fh)
    return d


def fault_drive(scene: str, duration: float, cache: Path, seed: int = 1) -> LidarDrive:
    """A drive of ``sim.faults.simulate_fault_drive`` (spin, traffic, field), cached."""
    from imuslam.sim.faults import simulate_fault_drive

    cache.mkdir(parents=True, exist_ok=True)
    f = cache / f"fault_{scene}_{duration:.2f}s_seed{seed}.pkl"
    if f.exists():
        with open(f, "rb") as fh:
            d: LidarDrive = pickle.load(fh)
            return d
    t0 = time.perf_counter()
    d = simulate_fault_drive(scene, duration, seed, progress=True)
    print(f"simulated {scene} {duration:g} s in {time.perf_counter() - t0:.0f} s")
    with open(f, "wb") as fh:
        pickle.dump(d, fh)
    return d


def faults_bench(args: Any) -> None:
    """The street drive (24 s, 192 m) with what real sensors do, each run with the guards on
    (``filter.imu_guard``, ``filter.degeneracy_guard``: ``lio.guards``) and off, and KISS-ICP on the
    same scans (LiDAR only): 5 % of the scans and 2 % of the IMU samples dropped; a 0.5 s IMU gap
    at 12 s; a +-250 deg/s gyro on a whole turn of the head in 2 s (337 deg/s peak; the raw gyro
    clipped, then calibrated); a straight road across an open field (the ground alone within the
    LiDAR's 60 m from 15 s to 21 s: degenerate in x, y and yaw); cars and pedestrians moving through
    the scans. A divergence the filter detects is printed as its message (exit 3 in ``imuslam lio``)."""
    from dataclasses import replace

    from imuslam.errors import EstimatorError
    from imuslam.sim import faults as F

    dur = args.duration or 24.0
    rng = np.random.default_rng(5)
    street = drive("street", dur, args.cache)
    cases: list[tuple[str, LidarDrive, dict[str, Any]]] = [
        ("none (the street drive)", street, {}),
        ("5 % scans, 2 % IMU samples dropped",
         replace(street, scans=F.drop_scans(street.scans, 0.05, rng),
                 imu=F.drop_imu_samples(street.imu, 0.02, rng)), {}),
        ("0.5 s IMU gap at 12 s", replace(street, imu=F.imu_gap(street.imu, 12.0, 0.5)), {}),
    ]  # fmt: skip
    spin = fault_drive("spin", dur, args.cache)
    cases.append(("gyro +-250 deg/s, 337 deg/s turn", replace(spin, imu=F.saturate_gyro(spin.imu, 250.0)),
                  {"gyro_range_dps": 250.0}))  # fmt: skip
    cases.append(("open field 15-21 s (degenerate)", fault_drive("field", dur, args.cache), {}))
    traffic = fault_drive("traffic", dur, args.cache)
    cases.append((f"moving cars, pedestrians ({100 * F.dynamic_fraction(traffic.scans):.1f} % of points)",
                  traffic, {}))  # fmt: skip
    for mode in ("direct",):  # load the compiled kernels before any timing
        run_imuslam(replace(street, scans=street.scans[:20]), mode, "full")
    print("| fault | run | KITTI drift % | rotation RMSE deg | ATE m | scans/s | reported |")
    print("|---|---|---|---|---|---|---|")
    for name, d, extra in cases:
        gt = truth(d)
        for guard in (True, False):
            fc = FilterConfig(imu_guard=guard, degeneracy_guard=guard, **extra)
            cfg = LioConfig(frontend=FrontEndConfig(mode="direct", scan_voxel=1.0),
                            extrinsic=ExtrinsicConfig(p_i_l=tuple(d.T_i_l[:3, 3])), filter=fc)  # type: ignore[arg-type]  # fmt: skip
            run = f"imuslam lio, guards {'on' if guard else 'off'}"
            try:
                res = LioPipeline(MemoryDataset(d.scans, true_calibration().correct(d.imu), "sim"),
                                  cfg, progress=False).run()  # fmt: skip
            except EstimatorError as exc:
                print(f"| {name} | {run} | diverged | | | | exit 3: {exc} |", flush=True)
                continue
            m = metrics(gt, res.trajectory)
            print(f"| {name} | {run} | {m['drift_pct']:.3f} | {m['rot_deg']:.3f} | {m['ate_m']:.3f} | "
                  f"{res.scans_per_s:.1f} | {'; '.join(res.warnings) or '-'} |", flush=True)  # fmt: skip
        kt, ksps, _ = run_kiss(d)
        m = metrics(gt, kt)
        print(f"| {name} | KISS-ICP (LiDAR only) | {m['drift_pct']:.3f} | {m['rot_deg']:.3f} | "
              f"{m['ate_m']:.3f} | {ksps:.1f} | - |", flush=True)  # fmt: skip


def robust_bench(args: Any) -> None:
    """``--part faults``: the faults of real sensors on the street drive (``faults_bench``);
    ``--part calib``: a wrong clock offset / extrinsic on the rig (``offsets_bench``); both by default."""
    if args.part in ("all", "faults"):
        faults_bench(args)
    if args.part in ("all", "calib"):
        offsets_bench(args)
    if args.part in ("all", "online"):
        online_bench(args)


def online_bench(args: Any) -> None:
    """The extrinsic and clock offset refined inside the filter (``filter.estimate_extrinsic`` /
    ``estimate_time_offset``, ``lio.online_calib``), off / on, started 2 deg / 10 cm / 20 ms away, on
    the waved rig (20 s, the room's front end of ``offsets_bench``) and the street car (20 s, yaw only,
    seed 4: the tests' drives), with the true values as the first row of each: ATE after an SE(3)
    alignment, the final errors with their reported 1-sigma, the directions reported unobserved and
    whether the guard held them."""
    from scipy.spatial.transform import Rotation

    from imuslam.sim.drive import simulate_lidar_imu_rig
    from imuslam.sim.lidar import Lidar3dConfig

    dur = args.duration or 20.0
    T = rig_T_i_l()
    print("| drive | extrinsic / offset given | in-filter refinement | ATE m | rotation RMSE deg | rotation err deg "
          "(1-sigma) | lever-arm err cm (1-sigma) | offset err ms (1-sigma) | unobserved (the guard) | s |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|")
    room = {"frontend": FrontEndConfig(mode="features", scan_voxel=0.25, min_range=0.2),
            "map": MapConfig(voxel=0.2)}  # fmt: skip
    for motion, seed in (("excited", 1), ("street", 4)):
        d = simulate_lidar_imu_rig(motion, dur, seed, T, 0.02, lidar=Lidar3dConfig(columns=900))
        R0, p0 = d.T_i_l[:3, :3], d.T_i_l[:3, 3]
        imu = true_calibration().correct(d.imu)
        for given, online in (("truth", False), ("2 deg / 10 cm / 20 ms off", False),
                              ("2 deg / 10 cm / 20 ms off", True)):  # fmt: skip
            start = (
                extrinsic(R0, p0, 0.02)
                if given == "truth"
                else extrinsic(*off_by_2deg_10cm(R0, p0), 0.0)
            )
            cfg = LioConfig(extrinsic=start, **(room if motion == "excited" else {}))  # type: ignore[arg-type]
            if online:
                f = cfg.filter.model_copy(
                    update={"estimate_extrinsic": True, "estimate_time_offset": True}
                )
                cfg = cfg.model_copy(update={"filter": f})
            t0 = time.perf_counter()
            res = LioPipeline(MemoryDataset(d.scans, imu, "rig"), cfg, progress=False).run()
            ev = evaluate(truth(d), res.trajectory, "se3", 1.0, "frames", 0.02)
            oc = res.online_calibration
            errs = ["", "", "", ""]
            if oc is not None:
                q = oc["quat_wxyz_i_l"]
                Rq = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()
                er = np.rad2deg(Rotation.from_matrix(Rq @ R0.T).as_rotvec())
                ep = 100 * (np.array(oc["p_i_l_m"]) - p0)
                f3 = lambda v: " ".join(f"{x:+.2f}" for x in v)  # noqa: E731
                errs = [f"{f3(er)} ({f3(oc['sigma_rot_deg'])})",
                        f"{f3(ep)} ({f3(100 * np.array(oc['sigma_p_i_l_m']))})",
                        f"{1e3 * (oc['time_offset_s'] - 0.02):+.2f} ({1e3 * oc['sigma_time_offset_s']:.2f})",
                        "; ".join(f"{u.split(':')[0]} ({u.rsplit(', ', 1)[-1]})" for u in oc["unobserved"])
                        or "none"]  # fmt: skip
            print(f"| {motion} | {given} | {'on' if online else 'off'} | {ev.ape_trans.rmse:.4f} | "
                  f"{ev.ape_rot_deg.rmse:.3f} | {' | '.join(errs)} | {time.perf_counter() - t0:.0f} |",
                  flush=True)  # fmt: skip


def offsets_bench(args: Any) -> None:
    """LIO on the excited rig (30 s in the calibration room) when the config's clock offset is zero
    while the LiDAR's clock is 5, 20 or 50 ms behind, and when the extrinsic is 2 deg / 10 cm off:
    without and with the target-free calibration (``lio.extrinsic``) started from the wrong values.
    The first row of each drive runs with the true values. ATE after an SE(3) alignment, also per
    metre of path; the calibration's own errors (rotation deg, lever arm cm, offset ms)."""
    from scipy.spatial.transform import Rotation

    from imuslam.lio.extrinsic import calibrate_lidar_imu

    dur = args.duration or 30.0
    fe = FrontEndConfig(mode="features", scan_voxel=0.25, min_range=0.2)
    mp = MapConfig(voxel=0.2)

    print("| drive | extrinsic / offset given | calibrated | ATE m | ATE % of path | rotation RMSE deg "
          "| calib. rotation err deg | calib. lever-arm err cm | calib. offset err ms | s |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|")
    cases: list[tuple[float, str, str]] = [(0.005, "truth", "no"), (0.005, "offset 0", "no"), (0.005, "offset 0", "yes"),
                                           (0.02, "truth", "no"), (0.02, "offset 0", "no"), (0.02, "offset 0", "yes"),
                                           (0.05, "truth", "no"), (0.05, "offset 0", "no"), (0.05, "offset 0", "yes"),
                                           (0.02, "2 deg / 10 cm off", "no"), (0.02, "2 deg / 10 cm off", "yes"),
                                           (0.02, "both", "no"), (0.02, "both", "yes")]  # fmt: skip
    for off, given, cal in cases:
        d = rig(dur, off, args.cache)
        R, p = d.T_i_l[:3, :3], d.T_i_l[:3, 3]
        Rw, pw = off_by_2deg_10cm(R, p)
        start = {"truth": extrinsic(R, p, off), "offset 0": extrinsic(R, p, 0.0),
                 "2 deg / 10 cm off": extrinsic(Rw, pw, off), "both": extrinsic(Rw, pw, 0.0)}[given]  # fmt: skip
        imu = true_calibration().correct(d.imu)
        t0 = time.perf_counter()
        errs = ["", "", ""]
        if cal == "yes":
            c = calibrate_lidar_imu(d.scans, imu, LioConfig(extrinsic=start, frontend=fe, map=mp))
            start = c.extrinsic()
            e_rot = np.rad2deg(np.linalg.norm(Rotation.from_matrix(c.R_i_l @ R.T).as_rotvec()))
            errs = [f"{e_rot:.3f}", f"{100 * np.linalg.norm(c.p_i_l - p):.2f}",
                    f"{1e3 * (c.time_offset_s - off):+.2f}"]  # fmt: skip
        cfg = LioConfig(extrinsic=start, frontend=fe, map=mp)
        res = LioPipeline(MemoryDataset(d.scans, imu, "rig"), cfg, progress=False).run()
        gt = truth(d)
        ev = evaluate(gt, res.trajectory, "se3", 1.0, "frames", 0.02)
        ate = ev.ape_trans.rmse
        print(f"| {off * 1e3:g} ms behind | {given} | {cal} | {ate:.4f} | {100 * ate / gt.path_length:.3f} | "
              f"{ev.ape_rot_deg.rmse:.3f} | {' | '.join(errs)} | {time.perf_counter() - t0:.0f} |", flush=True)  # fmt: skip


STREET_CALIB_S = 30.0  # the street drive of calib_bench and tests/lio/test_lio_extrinsic.py


def _lidar_frame(tr: Trajectory, ext: ExtrinsicConfig) -> Trajectory:
    """The LiDAR's trajectory from the IMU's through the extrinsic ``ext``."""
    return tr.of_mounted_frame(ext.T_i_l())


def calib_bench(args: Any) -> None:
    """The target-free LiDAR-IMU calibration (``lio.extrinsic``) on the excited rig (the tests' drive,
    20 s by default) and on the street drive (the car loop, yaw only, 30 s) for each of
    ``--calib-seeds``, started 2 deg / 10 cm / 20 ms from the truth: errors and reported 1-sigma per IMU
    axis, the verdict (unobservable; weak: 1-sigma above the target), the time. Then ``lio`` on each
    street drive with the true, the calibrated and the starting extrinsic and offset: the KITTI drift
    and ATE of the IMU's trajectory (the frame ``lio`` reports) and of the LiDAR's (the IMU's through
    the extrinsic the run used, against the true LiDAR's)."""
    from scipy.spatial.transform import Rotation

    from imuslam.lio.extrinsic import calibrate_lidar_imu
    from imuslam.sim.drive import simulate_lidar_imu_rig
    from imuslam.sim.lidar import Lidar3dConfig

    dur = args.duration or 20.0
    T = rig_T_i_l()
    start = extrinsic(*off_by_2deg_10cm(T[:3, :3], T[:3, 3]), 0.0)

    def f3(v: FloatArr, k: float = 1.0, fmt: str = "+.3f") -> str:
        return ", ".join(f"{k * a:{fmt}}" for a in v)

    print("| drive | seed | rotation err deg (x, y, z) | 1-sigma deg | lever-arm err mm | 1-sigma mm "
          "| offset err ms | 1-sigma ms | unobservable | weak | s |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    runs = [("excited", s, dur) for s in args.calib_seeds] + [
        ("street", s, STREET_CALIB_S) for s in args.calib_seeds
    ]
    lio_rows: list[str] = []
    for motion, seed, length in runs:
        d = simulate_lidar_imu_rig(motion, length, seed, T, 0.02, lidar=Lidar3dConfig(columns=900))
        t0 = time.perf_counter()
        c = calibrate_lidar_imu(
            d.scans, true_calibration().correct(d.imu), LioConfig(extrinsic=start)
        )
        dt = time.perf_counter() - t0
        rot = np.rad2deg(Rotation.from_matrix(c.R_i_l @ T[:3, :3].T).as_rotvec())
        un = ", ".join([f"p_{a}" for a, o in zip("xyz", c.observable_p, strict=True) if not o]
                       + [f"rot_{a}" for a, o in zip("xyz", c.observable_rot, strict=True) if not o])  # fmt: skip
        weak = ", ".join([f"p_{a}" for a, w in zip("xyz", c.weak_p, strict=True) if w]
                         + [f"rot_{a}" for a, w in zip("xyz", c.weak_rot, strict=True) if w]
                         + (["offset"] if c.weak_time else []))  # fmt: skip
        print(f"| {motion} {length:g} s | {seed} | {f3(rot)} | {f3(c.sigma_rot_deg, fmt='.3f')} | "
              f"{f3(c.p_i_l - T[:3, 3], 1e3, '+.1f')} | {f3(c.sigma_p_m, 1e3, '.1f')} | "
              f"{1e3 * (c.time_offset_s - 0.02):+.2f} | {1e3 * c.sigma_time_offset_s:.2f} | {un or '-'} | "
              f"{weak or '-'} | {dt:.0f} |", flush=True)  # fmt: skip
        if motion == "street":
            lio_rows += _street_lio_rows(d, c, seed, start)
    print("\n| street 30 s | seed | extrinsic / offset | IMU drift % | IMU ATE m | IMU rotation RMSE deg "
          "| LiDAR drift % | LiDAR ATE m | s |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|")
    print("\n".join(lio_rows))


def _street_lio_rows(d: Any, c: Any, seed: int, start: ExtrinsicConfig) -> list[str]:
    """``lio`` on a street drive with the true, the calibrated (``c``) and the starting extrinsic: the
    IMU's and the LiDAR's drift and ATE, one table row each."""
    imu = true_calibration().correct(d.imu)
    gt = truth(d)
    true_ext = extrinsic(d.T_i_l[:3, :3], d.T_i_l[:3, 3], d.time_offset_s)
    gt_l = _lidar_frame(gt, true_ext)
    rows = []
    for name, ext in (("truth", true_ext), ("calibrated", c.extrinsic()), ("start", start)):
        t0 = time.perf_counter()
        res = LioPipeline(
            MemoryDataset(d.scans, imu, "rig"), LioConfig(extrinsic=ext), progress=False
        ).run()
        mi, ml = metrics(gt, res.trajectory), metrics(gt_l, _lidar_frame(res.trajectory, ext))
        rows.append(f"| street | {seed} | {name} | {mi['drift_pct']:.3f} | {mi['ate_m']:.4f} | {mi['rot_deg']:.3f} | "
                    f"{ml['drift_pct']:.3f} | {ml['ate_m']:.4f} | {time.perf_counter() - t0:.0f} |")  # fmt: skip
    return rows


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument(
        "what",
        choices=[
            "main",
            "imu",
            "rotating",
            "corridor",
            "memory",
            "frontend",
            "consistency",
            "rowmodel",
            "robust",
            "calib",
            "dense",
        ],
    )
    ap.add_argument("--duration", type=float, default=None)
    ap.add_argument(
        "--patterns",
        nargs="+",
        default=["vlp16", "os1-128", "os1-64", "livox"],
        choices=["vlp16", "os1-64", "os1-128", "livox"],
        help="dense: the simulated LiDARs",
    )
    ap.add_argument("--dense-voxel", type=float, default=None,
                    help="dense: frontend.scan_voxel for scans of more than 40k points, m (default: "
                         "the default config's 1 m for every scan)")  # fmt: skip
    ap.add_argument("--part", choices=["all", "faults", "calib", "online"], default="all",
                    help="robust: the sensor faults, the wrong offset / extrinsic (calibrate-lidar; "
                         "online: the filter's own refinement), or all")  # fmt: skip
    ap.add_argument("--cache", type=Path, default=Path("/tmp/imuslam-bench-lio"))
    ap.add_argument("--columns", type=int, default=450, help="memory: LiDAR columns per turn")
    ap.add_argument("--every", type=int, default=1000, help="memory: scans between table rows")
    ap.add_argument("--no-map-covariance", action="store_true",
                    help="main, consistency: the filters with filter.map_covariance off (the "
                         "map-relative covariance only: the same estimate, without the consider term)")  # fmt: skip
    ap.add_argument(
        "--seeds",
        type=int,
        nargs="+",
        default=[5, 7, 11, 13, 17, 19],
        help="consistency: the street drive's seeds",
    )
    ap.add_argument(
        "--calib-seeds",
        type=int,
        nargs="+",
        default=[1, 2, 3],
        help="calib: the seeds of the rig and the street drive",
    )
    ap.add_argument("--state", default="full", help="consistency: reduced or full")
    ap.add_argument("--map-voxel", type=float, default=0.5, help="consistency: map.voxel, m")
    ap.add_argument(
        "--lidar-std", type=float, default=0.05, help="consistency: filter.lidar_std, m"
    )
    ap.add_argument("--lidar-dof", type=float, default=30.0, help="consistency: filter.lidar_dof")
    ap.add_argument("--lidar-model", choices=["dof", "plane", "plane_diag"], default="dof",
                    help="consistency: filter.lidar_model")  # fmt: skip
    ap.add_argument(
        "--map-scans",
        type=int,
        default=10,
        help="rowmodel: scans in the map before the first registered one",
    )
    ap.add_argument(
        "--start-covariance",
        action="store_true",
        help="consistency: filter.start_covariance (with a rows' model)",
    )
    ap.add_argument("--range-std", type=float, default=0.02,
                    help="consistency: filter.lidar_range_std, m (the simulated LiDAR's 2 cm)")  # fmt: skip
    ap.add_argument(
        "--map-correlation",
        choices=["full", "independent"],
        default="full",
        help="consistency: filter.map_correlation",
    )
    ap.add_argument(
        "--sensor-noise",
        action="store_true",
        help="consistency: the filter's IMU noise set to the simulated IMU's densities",
    )
    ap.add_argument(
        "--split",
        action="store_true",
        help="consistency: also the attitude's and the position's 3-dof NEES (expect 3)",
    )
    ap.add_argument("--map-drift", type=float, nargs=2, default=None, metavar=("DEG", "M"),
                    help="consistency: filter.map_drift_deg_per_sqrt_m and map_drift_m_per_sqrt_m "
                         "for both front ends (default: each front end's own)")  # fmt: skip
    ap.add_argument("--diagnose", action="store_true",
                    help="consistency: the first seed's attitude errors with LiDAR alone and with the "
                         "true gravity")  # fmt: skip
    args = ap.parse_args()
    t0 = time.perf_counter()
    {"main": main_bench, "imu": imu_bench, "rotating": rotating_bench, "corridor": corridor_bench,
     "memory": memory_bench, "frontend": frontend_bench,
     "consistency": consistency_bench, "rowmodel": rowmodel_bench, "robust": robust_bench, "calib": calib_bench,
     "dense": dense_bench}[args.what](args)  # fmt: skip
    print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
