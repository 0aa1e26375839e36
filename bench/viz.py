"""The cost of recording a run for the viewer: ``lio`` with ``--rrd`` against the same run without, in
the same process, on the same scans.

    PYTHONPATH=src python bench/viz.py [--duration 20] [--rounds 3] [--mode features]

The street drive of bench/lio.py (seed 1, VLP-16 at 10 Hz, IMU at 200 Hz with seed 000's errors,
corrected with its true calibration). Each round runs the pipeline without an observer, then with the
recording's logger writing a .rrd file (the IMU columns, per scan the pose, the registered points, the
covariance, the scan's figures, the local map every 50 scans; the final trajectory and map; the file
flushed and closed), in turn, the order swapped every round (ABBA), so a change of the machine's load
hits both sides alike. The table holds the median wall time and CPU time (the process's, every thread:
rerun's own encoder and writer threads included) of each side, their ratios (goal: wall <= 1.15) and
the per-round wall ratios. On a shared machine the CPU ratio is the steadier figure.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from imuslam.io.lidarsets import MemoryDataset  # noqa: E402
from imuslam.lio.config import ExtrinsicConfig, FrontEndConfig, LioConfig, MapConfig  # noqa: E402
from imuslam.lio.pipeline import LioPipeline  # noqa: E402
from imuslam.threads import configure_process  # noqa: E402
from lio import drive, true_calibration  # noqa: E402


def one_run(d, cfg, imu, rrd: Path | None) -> tuple[float, float, int]:  # type: ignore[no-untyped-def]
    """Wall and CPU time, s, of a whole run (recording opened, logged, closed included) and its scans."""
    from imuslam.viz.recording import open_recording

    t0, c0 = time.perf_counter(), time.process_time()
    with open_recording("bench", rrd, viewer=False) as rec:
        obs = None
        if rec is not None:
            from imuslam.viz.lio import LioLogger, log_imu

            log_imu(rec, imu, "imu/corrected")
            obs = LioLogger(rec)
        res = LioPipeline(MemoryDataset(d.scans, imu, "sim"), cfg, progress=False).run(obs)
        if obs is not None:
            obs.finish(res)
    return time.perf_counter() - t0, time.process_time() - c0, len(res.stats)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--mode", choices=["features", "direct"], default="features")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/imuslam-bench-lio"))
    args = ap.parse_args()
    configure_process()
    d = drive("street", args.duration, args.cache)
    cfg = LioConfig(frontend=FrontEndConfig(mode=args.mode, scan_voxel=1.0), map=MapConfig(voxel=0.5),  # type: ignore[arg-type]
                    extrinsic=ExtrinsicConfig(p_i_l=tuple(d.T_i_l[:3, 3])))  # type: ignore[arg-type]  # fmt: skip
    imu = true_calibration().correct(d.imu)
    from dataclasses import replace

    with tempfile.TemporaryDirectory() as tmp:
        one_run(d, cfg, imu, None)  # compile every kernel, load rerun, warm the caches
        one_run(replace(d, scans=d.scans[:20]), cfg, imu, Path(tmp) / "warm.rrd")
        times: dict[bool, list[tuple[float, float]]] = {False: [], True: []}
        size = 0
        for k in range(args.rounds):
            for recorded in (False, True) if k % 2 == 0 else (True, False):
                f = Path(tmp) / f"run{k}.rrd" if recorded else None
                w, c, n = one_run(d, cfg, imu, f)
                times[recorded].append((w, c))
                size = f.stat().st_size if f is not None else size
    plain, rec = np.array(times[False]), np.array(times[True])
    wall = float(np.median(rec[:, 0]) / np.median(plain[:, 0]))
    cpu = float(np.median(rec[:, 1]) / np.median(plain[:, 1]))
    per_round = rec[:, 0] / plain[:, 0]
    print(f"lio {args.mode} on a {args.duration:g} s street drive: {n} scans, {args.rounds} rounds, "
          f"recording {size / 1e6:.1f} MB")  # fmt: skip
    print("| run | wall s (median) | CPU s (median) | scans/s | wall ratio | CPU ratio | goal (wall) "
          "| per-round wall ratios |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    wp, cp = np.median(plain, axis=0)
    wr, cr = np.median(rec, axis=0)
    print(f"| lio {args.mode} | {wp:.2f} | {cp:.2f} | {n / wp:.1f} | 1 | 1 | | |")
    print(f"| lio {args.mode} --rrd | {wr:.2f} | {cr:.2f} | {n / wr:.1f} | {wall:.3f} | {cpu:.3f} | "
          f"<= 1.15 {'met' if wall <= 1.15 else 'MISSED'} | {', '.join(f'{r:.3f}' for r in per_round)} |")  # fmt: skip


if __name__ == "__main__":
    main()
