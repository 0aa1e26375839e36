"""One table of every headline speed ratio, each against its anchor measured in the same run.

Each row is a pair of timings repeated in rounds (ours, then the anchor, alternately), so a change of the
machine's load hits both sides of a round alike; the row holds the median of each side, the ratio of the
medians (ours / anchor: below 1 is faster than the anchor), the goal, the run-to-run spread of the
per-round ratios and the command a user runs to see the figure on its own. The table goes to
``bench/results.json`` (one file, in the spirit of asv's results: machine, environment with the versions
of numpy, numba, llvmlite and numba's threading layer, commit, date, and per row the raw times of every
round), and ``bench/compare.py`` compares it with the committed ``bench/reference.json``.

Rows (``--only`` picks groups):

- ``allan``: overlapped Allan deviation of 1e7 samples at 100 taus against allantools' ``oadev`` (wall
  time; goal ours <= 0.1 x allantools), then the same with one busy-loop process per extra core started
  by this bench (goal <= 0.2 x). Run in a fresh process as a user's would, imuslam imported first.
- ``inproc``: in-process calls: APE + RPE of a 5000-pose pair against evo's classes (SE(3), Sim(3)), and
  the xsens calibration (``calibrate``, default joint fit) against imu_tk's ``calibrateAccGyro``.
- ``lio``: LiDAR-inertial odometry (features and direct mode, full state) on a 20 s simulated street
  drive (bench/lio.py's, about 200 VLP-16 scans) against KISS-ICP on the same scans: wall time per scan
  (goal <= 0.4 x, i.e. 2.5x KISS-ICP's scans/s); and the direct mode with the default config on the same
  drive seen by a simulated 128-beam Ouster OS1-128 at 10 Hz (about 123k points a scan; cached by
  bench/lio.py in /tmp/imuslam-bench-lio) against rko-lio on the same scans: wall time per scan (goal
  <= 0.05 s, 20 scans/s), with its CPU time per scan and its drift beside the VLP-16 drive's (goal:
  within 10 % of it).
- ``process``: whole processes timed from outside (CPU time of the process and its children, the figure
  that holds on a busy machine): ``imuslam eval`` KITTI 00 Sim(3) against ``evo_ape`` (goal <= 0.7 x),
  every ``--help`` (goal under 0.3 s, no anchor); and ``imuslam calibrate`` doing imu_tk's job against
  imu_tk's program by wall time, the time a user waits (goal: no slower, <= 1.0 x), with its CPU-time
  ratio beside it (imu_tk's program runs on one thread, so its wall and CPU times agree; ours reads the
  two files on a second thread while it imports). The libraries the command is built on (numpy,
  pydantic, typer, rich, yaml) take about a third of imu_tk's time to import, so the 0.6 x once set
  here is out of reach for a Python process (docs/bench.md, "Calibrate as a process").

imu_tk's program is built from its source when one is given (``--imutk-src DIR`` or ``IMUTK_SRC``, a
checkout of https://github.com/Kyle-ak/imu_tk; Debian's libceres-dev, libeigen3-dev and cmake; the build
is cached under ``bench/.cache/``, never committed). Without it the imu_tk rows use the CPU time recorded
in ../shared/data/README.md (0.9-1.1 s, taken as 1.0 s) and are marked as a recorded, not same-run,
anchor; the in-process imu_tk row is then left out.

Run: python bench/table.py [--rounds N] [--only allan,inproc,lio,process] [--imutk-src DIR] [--out FILE]
"""

from __future__ import annotations

import argparse
import datetime
import hashlib
import json
import os
import platform
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from imuslam.threads import configure_process

configure_process()  # the command line's thread defaults, before numpy and numba load

BENCH = Path(__file__).resolve().parent
ROOT = BENCH.parent
sys.path.insert(0, str(BENCH))

# imu_tk's calibration program, recorded (../shared/data/README.md: "0.9-1.1 s of CPU on this kind of
# machine"), used only when it cannot be built here
IMUTK_RECORDED_CPU_S = 1.0
ALLAN_N = 10_000_000
ALLAN_TAUS = 100


def mad_spread(ratios: list[float]) -> float:
    """Run-to-run spread of a row: the robust relative standard deviation of its per-round ratios,
    1.4826 * median(|r - median r|) / median r (equal to std / mean for normally scattered ratios)."""
    med = statistics.median(ratios)
    return 1.4826 * statistics.median(abs(r - med) for r in ratios) / med


def _ratio_and_spread(ours: list[float], anchor: list[float] | None) -> tuple[float | None, float]:
    """(median ours / median anchor, spread of the per-round ratios); without an anchor (None, spread of
    ours' own times); with a single recorded anchor value, the spread of ours' times."""
    om = statistics.median(ours)
    if not anchor:
        return None, mad_spread(ours)
    am = statistics.median(anchor)
    if len(anchor) == 1:
        return om / am, mad_spread(ours)
    return om / am, mad_spread([o / a for o, a in zip(ours, anchor, strict=True)])


def make_row(
    name: str,
    ours: list[float],
    anchor: list[float] | None,
    goal: float | None,
    goal_kind: str,
    command: str,
    clock: str,
    anchor_name: str,
    anchor_kind: str = "same run",
    ours_cpu: list[float] | None = None,
    anchor_cpu: list[float] | None = None,
    **extra: Any,
) -> dict[str, Any]:
    """One row. goal_kind: "ratio" (ours / anchor at most ``goal``), "seconds" (ours at most ``goal``),
    or "" (tracked, no goal). ``clock`` names what ``ours`` and ``anchor`` hold (wall or CPU seconds);
    ``ours_cpu`` / ``anchor_cpu``, when given for a wall-clock row, add its CPU-time ratio and spread
    (less sensitive to the load than wall time, so a slip shows there first)."""
    ratio, spread = _ratio_and_spread(ours, anchor)
    row = {
        "name": name, "ours_s": statistics.median(ours),
        "anchor_s": statistics.median(anchor) if anchor else None, "ratio": ratio, "goal": goal,
        "goal_kind": goal_kind, "spread": spread, "rounds": len(ours), "command": command,
        "clock": clock, "anchor": anchor_name, "anchor_kind": anchor_kind, "ours_times": ours,
        "anchor_times": anchor,
    }  # fmt: skip
    if ours_cpu is not None and anchor_cpu is not None:
        row["cpu_ratio"], row["cpu_spread"] = _ratio_and_spread(ours_cpu, anchor_cpu)
        row["ours_cpu_times"], row["anchor_cpu_times"] = ours_cpu, anchor_cpu
    return {**row, **extra}


def goal_met(row: dict[str, Any]) -> bool | None:
    if row["goal_kind"] == "ratio" and row["ratio"] is not None:
        return bool(row["ratio"] <= row["goal"])
    if row["goal_kind"] == "seconds":
        return bool(row["ours_s"] <= row["goal"])
    return None


# ---------------------------------------------------------------------------------------------------
# workers: each group of in-process timings runs in a fresh interpreter (imuslam imported first, as a
# user's program would, so its thread defaults apply), printing one JSON line


def _worker_allan(rounds: int) -> dict[str, Any]:
    import allantools
    import numba
    import numpy as np

    from imuslam.imu.allan import cluster_sizes, overlapped_adev

    rng = np.random.default_rng(0)
    y = rng.normal(size=ALLAN_N) + np.cumsum(rng.normal(size=ALLAN_N)) * 1e-3
    ms = cluster_sizes(ALLAN_N, ALLAN_TAUS)
    overlapped_adev(y[:1000], 100.0, cluster_sizes(1000, 10))  # compile (or load the cache)
    taus, _, _ = overlapped_adev(y, 100.0, ms)  # first touch of the big arrays
    ours, anchor, ours_cpu, anchor_cpu, diff = [], [], [], [], 0.0
    for _ in range(rounds):
        t, c = time.perf_counter(), time.process_time()  # process_time: every thread of the process
        taus, ad, _ = overlapped_adev(y, 100.0, ms)
        ours.append(time.perf_counter() - t)
        ours_cpu.append(time.process_time() - c)
        t, c = time.perf_counter(), time.process_time()
        _, ad2, _, _ = allantools.oadev(y, rate=100.0, data_type="freq", taus=taus)
        anchor.append(time.perf_counter() - t)
        anchor_cpu.append(time.process_time() - c)
        diff = max(diff, float(np.max(np.abs(ad / ad2 - 1))))
    return {
        "ours": ours, "anchor": anchor, "ours_cpu": ours_cpu, "anchor_cpu": anchor_cpu,
        "max_rel_diff": diff, "n_taus": len(ms),
        "threading_layer": numba.threading_layer(), "num_threads": numba.get_num_threads(),
    }  # fmt: skip


def _worker_inproc(rounds: int, imutk: str | None) -> dict[str, Any]:
    import eval as bench_eval  # bench/eval.py
    from imuslam.imu.calibrate import CalibrationConfig, calibrate
    from imuslam.io.load import load_imu

    out: dict[str, Any] = {}
    ref, est = bench_eval.make_pair()
    bench_eval.ours(ref, est, "se3")  # JIT warm-up
    for align, scale in (("se3", False), ("sim3", True)):
        o, a = [], []
        for _ in range(rounds):
            o.append(bench_eval.ours(ref, est, align))
            a.append(bench_eval.evo_time(ref, est, scale))
        out[f"eval_{align}"] = {"ours": o, "anchor": a}
    xs = ROOT.parent / "shared" / "data" / "imu_tk_xsens"
    log = load_imu(xs / "xsens_acc.mat", xs / "xsens_gyro.mat")
    cfg = CalibrationConfig(g=9.81744, bias_sign="minus")
    calibrate(log, cfg)  # JIT warm-up
    o, a = [], []
    for _ in range(rounds):
        t = time.perf_counter()
        calibrate(log, cfg)
        o.append(time.perf_counter() - t)
        if imutk:
            r = subprocess.run(
                [imutk, str(xs / "xsens_acc.mat"), str(xs / "xsens_gyro.mat")],
                check=True, capture_output=True, text=True,
            )  # fmt: skip
            m = re.search(r"calibrateAccGyro_s (\S+)", r.stdout)
            if m is None:
                raise SystemExit(f"{imutk}: no calibrateAccGyro_s in its output:\n{r.stdout}")
            a.append(float(m.group(1)))
    out["calibrate"] = {"ours": o, "anchor": a}
    return out


LIO_DRIVE_S = 20.0  # the street drive of bench/lio.py, shortened: about 200 VLP-16 scans
LIO_MODES = ("features", "direct")


def _worker_lio(rounds: int) -> dict[str, Any]:
    from dataclasses import replace

    import lio as bench_lio  # bench/lio.py (its OMP_NUM_THREADS=1 for pykdtree applies here)

    d = bench_lio.simulate_lidar_drive("street", LIO_DRIVE_S, 1)
    for mode in LIO_MODES:  # load the compiled kernels before any timing
        bench_lio.run_imuslam(replace(d, scans=d.scans[:20]), mode, "full")
    out: dict[str, Any] = {"n_scans": len(d.scans), "kiss": []}
    out.update({m: [] for m in LIO_MODES})
    for _ in range(rounds):
        _, kiss_sps, _ = bench_lio.run_kiss(d)
        out["kiss"].append(1.0 / kiss_sps)
        for mode in LIO_MODES:
            res, _ = bench_lio.run_imuslam(d, mode, "full")
            out[mode].append(1.0 / res.scans_per_s)
    return out


LIO_DENSE = (
    "os1-128"  # bench/lio.py's simulated Ouster OS1-128, 1024 columns at 10 Hz (about 123k points)
)
LIO_DENSE_CACHE = Path("/tmp/imuslam-bench-lio")  # bench/lio.py's cache of simulated drives


def _worker_lio_dense(rounds: int) -> dict[str, Any]:
    """The 128-beam street drive with the default config (direct front end, full state) against
    rko-lio on the same scans, in rounds; the drift of that run and of the VLP-16 drive (the goal:
    within 10 % of it, or below)."""
    from dataclasses import replace

    import numpy as np

    import lio as bench_lio

    d16 = bench_lio.drive("street", LIO_DRIVE_S, LIO_DENSE_CACHE)
    _, est16 = bench_lio.run_imuslam(d16, "direct", "full")
    drift16 = bench_lio.metrics(bench_lio.truth(d16), est16)["drift_pct"]
    del d16, est16
    d = bench_lio.drive("street", LIO_DRIVE_S, LIO_DENSE_CACHE, lidar=LIO_DENSE)
    bench_lio.run_imuslam(
        replace(d, scans=d.scans[:20]), "direct", "full"
    )  # compiled kernels loaded
    imu = bench_lio.true_calibration().correct(d.imu)
    out: dict[str, Any] = {"n_scans": len(d.scans), "points": float(np.mean([len(s) for s in d.scans])),
                           "wall": [], "cpu": [], "rko": [], "drift_pct_16": drift16}  # fmt: skip
    for _ in range(rounds):
        _, rko_sps = bench_lio.run_rko(d, imu)
        out["rko"].append(1.0 / rko_sps)
        res, est = bench_lio.run_imuslam(d, "direct", "full")
        out["wall"].append(1.0 / res.scans_per_s)
        out["cpu"].append(1.0 / res.scans_per_cpu_s)
    out["drift_pct"] = bench_lio.metrics(bench_lio.truth(d), est)["drift_pct"]
    return out


def _run_worker(kind: str, rounds: int, imutk: str | None = None) -> dict[str, Any]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "src"), str(BENCH)])
    args = [
        sys.executable,
        str(Path(__file__).resolve()),
        "--worker",
        kind,
        "--rounds",
        str(rounds),
    ]
    if imutk:
        args += ["--imutk", imutk]
    r = subprocess.run(args, env=env, capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"worker {kind} failed:\n{r.stderr[-3000:]}")
    # the last JSON line: an anchor may print more at exit (rko-lio's profiling summary)
    return dict(json.loads([x for x in r.stdout.splitlines() if x.startswith("{")][-1]))


# ---------------------------------------------------------------------------------------------------
# groups


def _busy(n: int) -> list[subprocess.Popen[bytes]]:
    """``n`` busy-loop processes (each holds one core), stopped by the caller."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


def rows_allan(rounds: int) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    rows = []
    cmd = "python bench/allan.py"
    idle = _run_worker("allan", rounds)
    rows.append(make_row(
        "allan 1e7 samples, 100 taus", idle["ours"], idle["anchor"], 0.1, "ratio", cmd, "wall",
        "allantools.oadev", ours_cpu=idle["ours_cpu"], anchor_cpu=idle["anchor_cpu"],
        max_rel_diff=idle["max_rel_diff"],
    ))  # fmt: skip
    procs = _busy(max((os.cpu_count() or 2) - 1, 1))
    try:
        busy = _run_worker("allan", rounds)
    finally:
        for p in procs:
            p.terminate()
            p.wait()
    rows.append(make_row(
        "allan 1e7 samples, 100 taus, other cores busy", busy["ours"], busy["anchor"], 0.2, "ratio",
        cmd + "  (beside `python -c 'while True: pass'` per extra core)", "wall", "allantools.oadev",
        ours_cpu=busy["ours_cpu"], anchor_cpu=busy["anchor_cpu"], max_rel_diff=busy["max_rel_diff"],
    ))  # fmt: skip
    return rows, {"threading_layer": idle["threading_layer"], "num_threads": idle["num_threads"]}


def rows_inproc(rounds: int, imutk: str | None) -> list[dict[str, Any]]:
    w = _run_worker("inproc", rounds, imutk)
    rows = [
        make_row(
            f"eval APE + RPE 5000 poses {al.upper()} (in-process)",
            w[f"eval_{al}"]["ours"],
            w[f"eval_{al}"]["anchor"],
            None,
            "",
            "python bench/eval.py",
            "wall",
            "evo metrics.APE / RPE",
        )  # fmt: skip
        for al in ("se3", "sim3")
    ]
    if imutk:
        rows.append(make_row(
            "calibrate xsens, joint fit (in-process call)", w["calibrate"]["ours"],
            w["calibrate"]["anchor"], None, "", "python bench/calibrate_vs_imutk.py /path/to/imu_tk",
            "wall", "imu_tk calibrateAccGyro (C++, Ceres)",
        ))  # fmt: skip
    return rows


def rows_lio(rounds: int) -> list[dict[str, Any]]:
    w = _run_worker("lio", rounds)
    return [
        make_row(
            f"lio {mode} full state, {LIO_DRIVE_S:g} s street drive (wall s per scan)",
            w[mode],
            w["kiss"],
            0.4,
            "ratio",
            f"python bench/lio.py main --duration {LIO_DRIVE_S:g}  (headline: 137.5 s drive)",
            "wall",
            "KISS-ICP 1.x register_frame (C++, all cores)",
            n_scans=w["n_scans"],
        )  # fmt: skip
        for mode in LIO_MODES
    ] + rows_lio_dense(rounds)


def rows_lio_dense(rounds: int) -> list[dict[str, Any]]:
    """LiDAR-inertial odometry on the 128-beam drive, default config: wall seconds per scan (goal
    0.05 s: 20 scans/s), rko-lio's on the same scans beside it (tracked); the CPU seconds per scan
    and both drifts in the row."""
    w = _run_worker("lio_dense", rounds)
    return [make_row(
        f"lio direct full state, {LIO_DENSE} ({w['points'] / 1e3:.0f}k points a scan), default config, "
        f"{LIO_DRIVE_S:g} s street drive (wall s per scan)", w["wall"], w["rko"], 0.05, "seconds",
        f"python bench/lio.py dense --patterns vlp16 {LIO_DENSE} --duration {LIO_DRIVE_S:g}", "wall",
        "rko-lio 0.4.0 register_scan (C++) on the same scans", n_scans=w["n_scans"],
        ours_cpu_per_scan=statistics.median(w["cpu"]), ours_cpu_times=w["cpu"],
        drift_pct=w["drift_pct"], drift_pct_16_beam=w["drift_pct_16"],
        drift_goal_met=bool(w["drift_pct"] <= 1.1 * w["drift_pct_16"]),
    )]  # fmt: skip


def rows_process(rounds: int, imutk: str | None) -> list[dict[str, Any]]:
    import startup
    from imuslam.cli import COMMANDS

    cases: list[tuple[str, list[str], Path | None]] = [
        ("calibrate", startup.IMUSLAM + ["calibrate", *startup.CALIBRATE, "--method", "tedaldi",
                                         "--cv-folds", "0", "--no-plots", "--out", "{out}"],
         ROOT / "src"),
        ("eval", startup.IMUSLAM + ["eval", *startup.EVAL, "--no-plots", "--out", "{out}"],
         ROOT / "src"),
        ("help", startup.IMUSLAM + ["--help"], ROOT / "src"),
    ]  # fmt: skip
    cases += [(f"help {c}", startup.IMUSLAM + [c, "--help"], ROOT / "src") for c in COMMANDS]
    evo = shutil.which("evo_ape") or str(Path(sys.executable).parent / "evo_ape")
    kitti = [str(startup.KITTI / "KITTI_00_gt.txt"), str(startup.KITTI / "KITTI_00_ORB.txt")]
    cases.append(("evo_ape", [evo, "kitti", *kitti, "-as"], None))
    if imutk:
        cases.append(("imu_tk", [imutk, *startup.CALIBRATE[:2]], None))
    cpu: dict[str, list[float]] = {c[0]: [] for c in cases}
    wall: dict[str, list[float]] = {c[0]: [] for c in cases}
    with tempfile.TemporaryDirectory() as tmp:
        for _label, argv, src in cases:  # one untimed round: bytecode and numba caches written
            startup._run(argv, src, Path(tmp))
        for r in range(rounds):  # paired rounds in a rotated order
            k = r % len(cases)
            for label, argv, src in cases[k:] + cases[:k]:
                w, c = startup._run(argv, src, Path(tmp))
                wall[label].append(w)
                cpu[label].append(c)
    calib_cmd = (
        "imuslam calibrate xsens_acc.mat xsens_gyro.mat --g 9.81744 --t-init 50 --bias-sign "
        "minus --method tedaldi --cv-folds 0 --no-plots --out DIR  (python bench/startup.py)"
    )
    eval_cmd = ("imuslam eval KITTI_00_gt.txt KITTI_00_ORB.txt --format kitti --align sim3 --no-plots "
                "--out DIR  against  evo_ape kitti KITTI_00_gt.txt KITTI_00_ORB.txt -as")  # fmt: skip
    rows = []
    if imutk:
        rows.append(make_row(
            "process: calibrate xsens as imu_tk (tedaldi, no CV, no plots)", wall["calibrate"],
            wall["imu_tk"], 1.0, "ratio", calib_cmd, "wall", "imu_tk's calibration program (C++)",
            ours_cpu=cpu["calibrate"], anchor_cpu=cpu["imu_tk"],
        ))  # fmt: skip
    else:  # one thread: its recorded CPU time is its wall time too
        rows.append(make_row(
            "process: calibrate xsens as imu_tk (tedaldi, no CV, no plots)", wall["calibrate"],
            [IMUTK_RECORDED_CPU_S], 1.0, "ratio", calib_cmd, "wall", "imu_tk's calibration program (C++)",
            anchor_kind="recorded (../shared/data/README.md: 0.9-1.1 s CPU), not same run",
            ours_cpu_s=statistics.median(cpu["calibrate"]),
        ))  # fmt: skip
    rows.append(make_row(
        "process: eval KITTI 00 Sim(3), no plots", cpu["eval"], cpu["evo_ape"], 0.7, "ratio", eval_cmd,
        "cpu", "evo_ape kitti -as", ours_wall=wall["eval"], anchor_wall=wall["evo_ape"],
    ))  # fmt: skip
    for label in [c[0] for c in cases if c[0].startswith("help")]:
        sub = label.removeprefix("help").strip()
        rows.append(make_row(
            f"process: imuslam {sub + ' ' if sub else ''}--help", cpu[label], None, 0.3, "seconds",
            f"imuslam {sub + ' ' if sub else ''}--help  (python bench/startup.py --all-commands)", "cpu",
            "", anchor_kind="none", ours_wall=wall[label],
        ))  # fmt: skip
    return rows


# ---------------------------------------------------------------------------------------------------


def imutk_program(src: Path) -> str:
    """imu_tk's calibration program (one calibration per run), built once per source tree and cached."""
    import startup

    key = hashlib.sha1(
        b"".join((src / "src" / f).read_bytes() for f in ("calibration.cpp", "io_utils.cpp"))
    ).hexdigest()[:12]
    cache = BENCH / ".cache" / f"imutk-{key}"
    exe = cache / "build" / "imutk_bench"
    if not exe.is_file():
        if cache.exists():
            shutil.rmtree(cache)
        cache.mkdir(parents=True)
        print(f"building imu_tk's program from {src} (cmake, libceres-dev) ...", flush=True)
        exe = startup.build_imutk(src, cache)
    return str(exe)


def environment(extra: dict[str, Any]) -> dict[str, Any]:
    import llvmlite
    import numba
    import numpy

    def version(mod: str) -> str | None:
        try:
            from importlib.metadata import version as v

            return v(mod)
        except Exception:
            return None

    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True,
                            text=True).stdout.strip()  # fmt: skip
    dirty = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "--", "src", "bench"],
                           capture_output=True, text=True).stdout.strip() != ""  # fmt: skip
    return {
        "machine": {
            "node": platform.node(), "cpu": platform.processor() or platform.machine(),
            "num_cpu": os.cpu_count(), "os": f"{platform.system()} {platform.release()}",
        },
        "env": {
            "python": platform.python_version(), "numpy": numpy.__version__,
            "numba": numba.__version__, "llvmlite": llvmlite.__version__,
            "allantools": version("allantools"), "evo": version("evo"), **extra,
            "NUMBA_THREADING_LAYER": os.environ.get("NUMBA_THREADING_LAYER"),
            "NUMBA_NUM_THREADS": os.environ.get("NUMBA_NUM_THREADS"),
            "OMP_WAIT_POLICY": os.environ.get("OMP_WAIT_POLICY"),
        },
        "commit_hash": commit, "src_or_bench_modified": dirty,
    }  # fmt: skip


def print_table(res: dict[str, Any]) -> None:
    from rich.console import Console
    from rich.table import Table

    e = res["env"]
    t = Table(
        title=f"imuslam headline ratios, {res['date']}, commit {res['commit_hash'][:9]}; numpy "
        f"{e['numpy']}, numba {e['numba']} ({e['threading_layer']}, {e['num_threads']} threads), "
        f"llvmlite {e['llvmlite']}; 1-min load {res['load_start']} at the start, {res['load_end']} "
        f"at the end, {res['machine']['num_cpu']} cores"
    )
    for c in (
        "row",
        "ours [s]",
        "anchor [s]",
        "ratio",
        "goal",
        "spread",
        "clock",
        "anchor",
        "command",
    ):
        t.add_column(c, justify="left" if c in ("row", "anchor", "command") else "right")
    for r in res["rows"]:
        met = goal_met(r)
        goal = (
            "-"
            if r["goal"] is None
            else (f"<= {r['goal']}" + (" s" if r["goal_kind"] == "seconds" else ""))
        )
        if met is not None:
            goal += " met" if met else " MISSED"
        anchor = r["anchor"] + (
            "" if r["anchor_kind"] in ("same run", "none") else f" [{r['anchor_kind']}]"
        )
        t.add_row(
            r["name"], f"{r['ours_s']:.3f}",
            "-" if r["anchor_s"] is None else f"{r['anchor_s']:.3f}",
            "-" if r["ratio"] is None else f"{r['ratio']:.3f}", goal, f"{100 * r['spread']:.0f} %",
            r["clock"] + ("" if r.get("cpu_ratio") is None else f" (cpu ratio {r['cpu_ratio']:.3f})"),
            anchor, r["command"],
        )  # fmt: skip
    Console(width=250).print(t)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--allan-rounds", type=int, default=5, help="allantools takes 5-15 s a call")
    ap.add_argument("--only", default="allan,inproc,lio,process")
    ap.add_argument("--lio-rounds", type=int, default=3)
    ap.add_argument("--imutk-src", type=Path, default=os.environ.get("IMUTK_SRC") or None)
    ap.add_argument("--out", type=Path, default=BENCH / "results.json")
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--imutk", default=None, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.worker == "allan":
        print(json.dumps(_worker_allan(a.rounds)))
        return
    if a.worker == "inproc":
        print(json.dumps(_worker_inproc(a.rounds, a.imutk)))
        return
    if a.worker == "lio":
        print(json.dumps(_worker_lio(a.rounds)))
        return
    if a.worker == "lio_dense":
        print(json.dumps(_worker_lio_dense(a.rounds)))
        return

    imutk = None
    if a.imutk_src is not None:
        if not (Path(a.imutk_src) / "src" / "calibration.cpp").is_file():
            raise SystemExit(f"{a.imutk_src}: not an imu_tk checkout (no src/calibration.cpp)")
        imutk = imutk_program(Path(a.imutk_src))
    groups = a.only.split(",")
    t0 = time.perf_counter()
    load_start = os.getloadavg()[0]
    rows: list[dict[str, Any]] = []
    numba_threads: dict[str, Any] = {"threading_layer": None, "num_threads": None}
    if "allan" in groups:
        r, numba_threads = rows_allan(a.allan_rounds)
        rows += r
    if "inproc" in groups:
        rows += rows_inproc(a.rounds, imutk)
    if "lio" in groups:
        rows += rows_lio(a.lio_rounds)
    if "process" in groups:
        rows += rows_process(a.rounds, imutk)
    res = {
        "version": 1,
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        **environment(numba_threads),
        "load_start": round(load_start, 2), "load_end": round(os.getloadavg()[0], 2),
        "duration_s": round(time.perf_counter() - t0, 1),
        "imutk": "built here from " + str(a.imutk_src) if imutk else "recorded",
        "rows": rows,
    }  # fmt: skip
    res["env"]["threading_layer"] = numba_threads["threading_layer"]
    res["env"]["num_threads"] = numba_threads["num_threads"]
    a.out.write_text(json.dumps(res, indent=1) + "\n")
    print_table(res)
    print(f"written {a.out} ({res['duration_s']} s)")


if __name__ == "__main__":
    main()
