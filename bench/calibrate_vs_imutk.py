"""imuslam's multi-position calibration against imu_tk's C++ (Ceres), both timed in this run.

imu_tk is built from its source (a checkout of https://github.com/Kyle-ak/imu_tk, given as the first
argument or IMUTK_SRC) with Debian's libceres-dev, leaving out its Qt / OpenGL plotting files: only
``src/calibration.cpp``, ``src/io_utils.cpp`` and ``src/filters.cpp`` are compiled, with a driver written
here that sets what imu_tk's own ``apps/test_imu_calib.cpp`` sets (verbose output off, so its one gnuplot
call and key wait in ``calibration.cpp`` are removed with their include) (g = 9.81744, T_init 50 s, initial
bias 32768 counts and gyro scale 1 / 6258) and times ``calibrateAccGyro`` alone (best of 5; reading the
files is not timed, on either side). Three setters of ``calibration.h`` are declared non-void and return
nothing (undefined behaviour that g++ -O2 may turn into a trap): the build copy declares them void.

Run: .venv/bin/python bench/calibrate_vs_imutk.py /path/to/imu_tk
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

from imuslam.imu.calibrate import CalibrationConfig, calibrate
from imuslam.io.load import load_imu
from imuslam.threads import configure_process

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "imu_tk_xsens"

DRIVER = r"""
#include <chrono>
#include <iostream>
#include "imu_tk/io_utils.h"
#include "imu_tk/calibration.h"
using namespace imu_tk;
int main(int argc, char** argv) {
  std::vector<TriadData> acc, gyro;
  importAsciiData(argv[1], acc, imu_tk::TIMESTAMP_UNIT_SEC);
  importAsciiData(argv[2], gyro, imu_tk::TIMESTAMP_UNIT_SEC);
  double best = 1e9;
  for (int rep = 0; rep < 5; ++rep) {
    CalibratedTriad init_acc, init_gyro;
    init_acc.setBias(Eigen::Vector3d(32768, 32768, 32768));
    init_gyro.setScale(Eigen::Vector3d(1.0 / 6258.0, 1.0 / 6258.0, 1.0 / 6258.0));
    MultiPosCalibration mp;
    mp.setInitStaticIntervalDuration(50.0);
    mp.setInitAccCalibration(init_acc);
    mp.setInitGyroCalibration(init_gyro);
    mp.setGravityMagnitude(9.81744);
    mp.enableVerboseOutput(false);
    mp.enableAccUseMeans(false);
    auto t0 = std::chrono::steady_clock::now();
    mp.calibrateAccGyro(acc, gyro);
    double dt = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (dt < best) best = dt;
    if (rep == 0) std::cout << "acc_K " << mp.getAccCalib().getScaleMatrix().diagonal().transpose() << std::endl;
  }
  std::cout << "calibrateAccGyro_s " << best << std::endl;
  return 0;
}
"""

CMAKE = """
cmake_minimum_required(VERSION 3.10)
project(imutk_bench CXX)
set(CMAKE_CXX_STANDARD 17)
set(CMAKE_BUILD_TYPE Release)
find_package(Ceres REQUIRED)
find_package(Eigen3 REQUIRED)
add_executable(imutk_bench driver.cpp src/calibration.cpp src/io_utils.cpp src/filters.cpp)
target_include_directories(imutk_bench PRIVATE include ${EIGEN3_INCLUDE_DIR})
target_link_libraries(imutk_bench Ceres::ceres)
"""


def build(src: Path, work: Path) -> Path:
    """Copy imu_tk's core sources, declare the three value-less setters void, build with CMake."""
    for d in ("include", "src"):
        shutil.copytree(src / d, work / d)
    h = work / "include" / "imu_tk" / "calibration.h"
    text = h.read_text()
    text, n = re.subn(
        r"\b(_T|int|bool) (setInitStaticIntervalDuration|setIntarvalsNumSamples|enableGyroBiasOptimization)\(",
        r"void \2(",
        text,
    )
    if n != 3:
        raise SystemExit(f"{h}: expected 3 value-less setters to patch, found {n}")
    h.write_text(text)
    # the plotting (gnuplot through visualization.h, boost) runs only with verbose output: left out
    c = work / "src" / "calibration.cpp"
    code = c.read_text().replace('#include "imu_tk/visualization.h"', "")
    code, n = re.subn(r"Plot plot;\s*plot\.plotIntervals\([^;]*\);", "", code)
    code, m = re.subn(r"waitForKey\(\);", "", code)
    if (n, m) != (1, 1):
        raise SystemExit(
            f"{c}: expected one plotting call and one key wait to leave out, found {n}, {m}"
        )
    c.write_text(code)
    (work / "driver.cpp").write_text(DRIVER)
    (work / "CMakeLists.txt").write_text(CMAKE)
    b = work / "build"
    for cmd in (["cmake", "-S", str(work), "-B", str(b), "-DCMAKE_BUILD_TYPE=Release"],
                ["cmake", "--build", str(b), "-j", "2"]):  # fmt: skip
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode != 0:
            raise SystemExit(f"{' '.join(cmd)} failed:\n{(r.stdout + r.stderr)[-3000:]}")
    return b / "imutk_bench"


def main() -> None:
    src = Path(sys.argv[1] if len(sys.argv) > 1 else os.environ.get("IMUTK_SRC", ""))
    if not (src / "src" / "calibration.cpp").is_file():
        raise SystemExit("give the path of an imu_tk checkout (argument or IMUTK_SRC)")
    acc, gyr = DATA / "xsens_acc.mat", DATA / "xsens_gyro.mat"
    with tempfile.TemporaryDirectory() as tmp:
        exe = build(src, Path(tmp))
        out = subprocess.run(
            [str(exe), str(acc), str(gyr)], check=True, capture_output=True, text=True
        ).stdout
    t_imutk = float(re.search(r"calibrateAccGyro_s (\S+)", out).group(1))  # type: ignore[union-attr]
    log = load_imu(acc, gyr)
    cfg = CalibrationConfig(g=9.81744, bias_sign="minus")
    calibrate(log, cfg)  # JIT warm-up
    times = []
    for _ in range(5):
        t0 = time.perf_counter()
        calibrate(log, cfg)
        times.append(time.perf_counter() - t0)
    table = Table(
        title="imu_tk xsens log (51,175 samples): calibration call only, best of 5, same run"
    )
    for c in ("implementation", "calibrate [s]", "ratio"):
        table.add_column(c, justify="right")
    table.add_row(
        "imu_tk C++ (Ceres), built here", f"{t_imutk:.3f}", f"{t_imutk / min(times):.1f}x"
    )
    table.add_row("imuslam (numba + scipy)", f"{min(times):.3f}", "1.0x")
    Console().print(table)


if __name__ == "__main__":
    configure_process()  # the command line's thread defaults, before numba's first parallel kernel
    main()
