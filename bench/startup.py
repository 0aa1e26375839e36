"""Whole processes as a user times them: start-up, calibrate, eval, against evo_ape in the same run.

Each round runs every case once, in a rotated order (paired runs: a load change hits all cases alike);
after one untimed round (bytecode and numba caches written, as on a user's second run), the table
gives the median wall time and the median CPU time (user + system of the process and its
children) over the rounds, and the 1-minute load average around the run: on a busy machine the wall
times are meaningless and the CPU times are the figure to compare. ``--before SRC`` adds the imuslam
cases run from another source tree (e.g. ``git archive main src | tar -x -C /tmp/before``) for a
before/after in one run; ``--imutk EXE`` adds imu_tk's calibration program (``EXE acc.mat gyro.mat``:
reads both files, calibrates once, prints), or ``--imutk-src DIR`` builds it first from an imu_tk
checkout (https://github.com/Kyle-ak/imu_tk) with Debian's libceres-dev and cmake, as
bench/calibrate_vs_imutk.py does, with its driver's five timed repetitions cut to one;
``--all-commands`` adds ``imuslam <command> --help`` for every command, from both trees with ``--before``
(the time a command needs before its body starts working).

The calibrate cases: the default (joint fit and a 5-fold cross-validation, 6 fits in all), and the run
that does what imu_tk's program does (``--method tedaldi --cv-folds 0 --no-plots``: imu_tk's method,
one fit, the calibration files).

Run: python bench/startup.py [--rounds N] [--before SRC] [--imutk EXE | --imutk-src DIR] [--all-commands]
[--help-only]
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
XSENS = DATA / "imu_tk_xsens"
KITTI = DATA / "evo_testdata"
CALIBRATE = [str(XSENS / "xsens_acc.mat"), str(XSENS / "xsens_gyro.mat"), "--g", "9.81744",
             "--t-init", "50", "--bias-sign", "minus"]  # fmt: skip
EVAL = [str(KITTI / "KITTI_00_gt.txt"), str(KITTI / "KITTI_00_ORB.txt"), "--format", "kitti",
        "--align", "sim3"]  # fmt: skip
IMUSLAM = [
    sys.executable,
    "-c",
    "from imuslam.cli import main; main()",
]  # the console script's body


def _cases(
    before: Path | None, imutk: str | None, all_commands: bool
) -> list[tuple[str, list[str], Path | None]]:
    """(label, argv with {out} for a fresh output folder, src tree on PYTHONPATH)."""
    trees: list[tuple[str, Path | None]] = [("", ROOT / "src")]
    if before is not None:
        trees.insert(0, ("before: ", before))
    out: list[tuple[str, list[str], Path | None]] = []
    for tag, src in trees:
        out += [
            (f"{tag}imuslam --help", IMUSLAM + ["--help"], src),
            (f"{tag}imuslam calibrate --help", IMUSLAM + ["calibrate", "--help"], src),
            (f"{tag}imuslam eval --help", IMUSLAM + ["eval", "--help"], src),
            (
                f"{tag}imuslam calibrate xsens --method tedaldi --cv-folds 0 --no-plots",
                IMUSLAM
                + [
                    "calibrate",
                    *CALIBRATE,
                    "--method",
                    "tedaldi",
                    "--cv-folds",
                    "0",
                    "--no-plots",
                    "--out",
                    "{out}",
                ],
                src,
            ),  # fmt: skip
            (
                f"{tag}imuslam calibrate xsens --no-plots",
                IMUSLAM + ["calibrate", *CALIBRATE, "--no-plots", "--out", "{out}"],
                src,
            ),  # fmt: skip
            (
                f"{tag}imuslam calibrate xsens (plots, report)",
                IMUSLAM + ["calibrate", *CALIBRATE, "--out", "{out}"],
                src,
            ),  # fmt: skip
            (
                f"{tag}imuslam eval KITTI 00 sim3 --no-plots",
                IMUSLAM + ["eval", *EVAL, "--no-plots", "--out", "{out}"],
                src,
            ),  # fmt: skip
            (f"{tag}imuslam eval KITTI 00 sim3", IMUSLAM + ["eval", *EVAL, "--out", "{out}"], src),
        ]
    if all_commands:  # every command's help, from each tree (a command new in this tree: only here)
        from imuslam.cli import COMMANDS

        for tag, src in trees:
            old = {p.stem for p in (src / "imuslam" / "cli").glob("*.py")}
            out += [(f"{tag}imuslam {c} --help", IMUSLAM + [c, "--help"], src)
                    for c, (mod, _) in COMMANDS.items() if mod in old]  # fmt: skip
    evo = shutil.which("evo_ape") or str(Path(sys.executable).parent / "evo_ape")
    if Path(evo).exists():
        kitti = [str(KITTI / "KITTI_00_gt.txt"), str(KITTI / "KITTI_00_ORB.txt")]
        out.append(("evo_ape kitti -as (Sim(3))", [evo, "kitti", *kitti, "-as"], None))
        out.append(("evo_ape kitti -as --save_plot", [evo, "kitti", *kitti, "-as", "--plot_mode", "xz",
                                                       "--save_plot", "{out}/ape.png"], None))  # fmt: skip
    if imutk:
        out.append(("imu_tk calibration program", [imutk, *CALIBRATE[:2]], None))
    return list({c[0]: c for c in out}.values())  # a help listed twice is one case


def _run(argv: list[str], src: Path | None, tmp: Path) -> tuple[float, float]:
    """(wall, CPU) seconds of one process."""
    d = Path(tempfile.mkdtemp(dir=tmp))
    args = [a.replace("{out}", str(d / "out")) for a in argv]
    (d / "out").mkdir()  # evo saves into an existing folder; imuslam accepts an empty one
    env = dict(os.environ, MPLBACKEND="Agg")
    env.pop("PYTHONPATH", None)
    # as a user's Python does: modules' bytecode cached in __pycache__ (some shells and containers set
    # PYTHONDONTWRITEBYTECODE, which would recompile every source file in every process)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    if src is not None:
        env["PYTHONPATH"] = str(src)
    c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    r = subprocess.run(args, env=env, capture_output=True, text=True, cwd=d)
    dt = time.perf_counter() - t
    c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime)
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(args)} failed ({r.returncode}):\n{r.stderr[-2000:]}")
    shutil.rmtree(d)
    return dt, cpu


def build_imutk(src: Path, work: Path) -> Path:
    """imu_tk's calibration program, built as bench/calibrate_vs_imutk.py builds it, calibrating once."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import calibrate_vs_imutk as cvi

    cvi.DRIVER = cvi.DRIVER.replace(
        "rep < 5", "rep < 1"
    )  # the program a user runs: one calibration
    return Path(cvi.build(src, work))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--before", type=Path, default=None, help="a src/ tree to time as 'before'")
    ap.add_argument("--imutk", default=None, help="imu_tk's calibration program")
    ap.add_argument(
        "--imutk-src", type=Path, default=None, help="an imu_tk checkout to build first"
    )
    ap.add_argument("--all-commands", action="store_true")
    ap.add_argument(
        "--help-only", action="store_true", help="every command's --help and nothing else"
    )
    a = ap.parse_args()
    from rich.console import Console
    from rich.table import Table

    with tempfile.TemporaryDirectory() as tmp:
        imutk = a.imutk
        if a.imutk_src is not None:
            (Path(tmp) / "imutk").mkdir()
            imutk = str(build_imutk(a.imutk_src, Path(tmp) / "imutk"))
        cases = _cases(a.before, imutk, a.all_commands or a.help_only)
        if a.help_only:
            cases = [c for c in cases if c[0].endswith("--help")]
        times: dict[str, list[tuple[float, float]]] = {c[0]: [] for c in cases}
        with open("/proc/loadavg") as f:
            load_start = f.read().split()[0]
        for _label, argv, src in cases:  # one untimed round: bytecode and numba caches written
            _run(argv, src, Path(tmp))
        for r in range(a.rounds):
            k = r % len(cases)
            for label, argv, src in cases[k:] + cases[:k]:
                times[label].append(_run(argv, src, Path(tmp)))
    with open("/proc/loadavg") as f:
        load_end = f.read().split()[0]
    table = Table(
        title=f"Whole processes, {a.rounds} paired rounds; 1-min load average {load_start} "
        f"at the start, {load_end} at the end on {os.cpu_count()} cores"
    )
    for col in ("process", "wall median [s]", "wall min [s]", "CPU median [s]", "CPU min [s]"):
        table.add_column(col, justify="left" if col == "process" else "right")
    for label, ts in times.items():
        w = [x[0] for x in ts]
        c = [x[1] for x in ts]
        table.add_row(label, f"{statistics.median(w):.2f}", f"{min(w):.2f}",
                      f"{statistics.median(c):.2f}", f"{min(c):.2f}")  # fmt: skip
    Console(width=110).print(table)


if __name__ == "__main__":
    main()
