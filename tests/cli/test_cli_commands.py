"""The command line end to end: outputs written, numbers consistent, errors clean and atomic."""

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from imuslam.cli import app
from imuslam.imu.model import ImuCalibration
from imuslam.io.load import load_imu, write_imu
from imuslam.sim.multipose import simulate_multipose, sphere_plan_deg

runner = CliRunner()


def test_calibrate_xsens_writes_everything(shared_data: Path, tmp_path: Path) -> None:
    d = shared_data / "imu_tk_xsens"
    out = tmp_path / "out"
    r = runner.invoke(
        app,
        ["calibrate", str(d / "xsens_acc.mat"), str(d / "xsens_gyro.mat"), "--g", "9.81744",
         "--t-init", "50", "--bias-sign", "minus", "--method", "tedaldi", "--out", str(out)],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    assert "held out" in (out / "report.html").read_text()  # the cross-validation section
    for f in (
        "calibration.yaml",
        "acc.calib",
        "gyro.calib",
        "report.html",
        "static_detection.png",
        "config.yaml",
    ):
        assert (out / f).stat().st_size > 0
    cal = ImuCalibration.load_yaml(out / "calibration.yaml")
    np.testing.assert_allclose(cal.accel.K, [0.00241278, 0.00242712, 0.00241168], rtol=5e-6)
    assert yaml.safe_load((out / "config.yaml").read_text())["g"] == 9.81744


def test_correct_bag_round_trip(tmp_path: Path) -> None:
    """Calibrate a simulated log, write its raw IMU as MCAP, correct it: the result is the truth + noise."""
    rng = np.random.default_rng(5)
    sim = simulate_multipose(sphere_plan_deg(40, rng), rng)
    write_imu(sim.log, tmp_path / "raw.mcap", "bag", topic="/imu")
    write_imu(sim.log, tmp_path / "raw.txt", "imutk")
    r = runner.invoke(
        app,
        ["calibrate", str(tmp_path / "raw.txt"), "--g", "9.80665", "--out", str(tmp_path / "c")],
    )
    assert r.exit_code == 0, r.output
    r = runner.invoke(
        app, ["correct", str(tmp_path / "raw.mcap"), "--calib", str(tmp_path / "c" / "calibration.yaml"),
              "--out", str(tmp_path / "fixed.mcap")],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    fixed = load_imu(tmp_path / "fixed.mcap")
    # Corrected static samples equal the true specific force up to the white noise (0.029 m/s^2).
    st = sim.truth.static
    err = fixed.accel[st] - sim.truth.accel_i[st]
    assert abs(np.mean(err)) < 0.005 and np.std(err) < 0.035


def test_allan_command(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    n = 20_000
    log_path = tmp_path / "static.txt"
    t = np.arange(n) * 0.01
    acc = rng.normal(size=(n, 3)) * 0.02 + [0, 0, 9.81]
    gyr = rng.normal(size=(n, 3)) * 0.001
    np.savetxt(log_path, np.column_stack([t, acc, gyr]))
    r = runner.invoke(
        app,
        [
            "allan",
            str(log_path),
            "--accel-unit",
            "m/s^2",
            "--gyro-unit",
            "rad/s",
            "--out",
            str(tmp_path / "a"),
        ],
    )
    assert r.exit_code == 0, r.output
    k = yaml.safe_load((tmp_path / "a" / "imu.yaml").read_text())
    # white std 0.02 at 100 Hz -> density 0.02 / sqrt(100) = 2e-3; 1e-4 for the gyro
    assert abs(k["accelerometer_noise_density"] / 2e-3 - 1) < 0.05
    assert abs(k["gyroscope_noise_density"] / 1e-4 - 1) < 0.05
    assert (tmp_path / "a" / "allan.png").exists()
    # the noise terms once, in metrics.json (no byte copy under another name)
    assert sorted(p.name for p in (tmp_path / "a").glob("[!.]*.json")) == ["metrics.json"]
    terms = json.loads((tmp_path / "a" / "metrics.json").read_text())["terms"]
    white = {t["sensor"]: t["white"] for t in terms}
    assert abs(white["accel"] / 2e-3 - 1) < 0.05 and abs(white["gyro"] / 1e-4 - 1) < 0.05


def test_errors_are_one_line_and_leave_no_output(tmp_path: Path) -> None:
    bad = tmp_path / "bad.txt"
    bad.write_text("0 1 2 3 4 5 6\n0.01 1 2 nan 4 5 6\n")
    out = tmp_path / "out"
    r = runner.invoke(app, ["calibrate", str(bad), "--out", str(out)])
    assert r.exit_code == 2
    assert "line 2" in r.output and "Traceback" not in r.output
    assert not out.exists()
    r = runner.invoke(app, ["calibrate", str(bad), "--format", "xml", "--out", str(out)])
    assert r.exit_code == 2 and "--format" in r.output


def test_demo(tmp_path: Path) -> None:
    r = runner.invoke(app, ["demo", "--out", str(tmp_path / "d")])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "d" / "report.html").exists() and (
        tmp_path / "d" / "corrected_imu.mcap"
    ).exists()
    import json

    runs = {r["variant"]: r for r in json.loads((tmp_path / "d" / "ins_benefit.json").read_text())}
    assert (tmp_path / "d" / "ins_benefit.png").exists() and len(runs) == 5
    # metrics.json: the INS rows as ins_benefit.json, and the calibration's errors against the truth
    metrics = json.loads((tmp_path / "d" / "metrics.json").read_text())
    assert metrics["ins_benefit"] == list(runs.values())
    assert (tmp_path / "d" / "config.yaml").exists()
    # every parameter against the simulator's truth within 5 of the fit's own 1-sigma (the demo's
    # calibration is consistent: its error/sigma column)
    for kind in ("accel", "gyro"):
        par = metrics[kind]
        assert len(par) == 9 and all(abs(p["error"]) < 5 * p["sigma"] for p in par.values()), par
    # progress is shown before the long steps, and the report shows the INS result it computed
    assert r.output.index("compiles the numerical kernels") < r.output.index("Accelerometer")
    report = (tmp_path / "d" / "report.html").read_text()
    assert "What the calibration buys an INS" in report and 'src="ins_benefit.png"' in report
    for v in runs.values():
        assert f"<td>{v['position_err_m']:.2f}</td>" in report
    # the raw BWT901CL's gyro biases (1.6, 2.9, 0.6 deg/s) and misalignments (up to 5 deg) wreck a free INS
    # within 30 s; calibrated, its residual errors are ~100x smaller; after the same KF alignment the
    # calibrated IMU still keeps its attitude several times better (the filter models biases only)
    raw, cal = (
        runs["raw IMU, free from the true state"],
        runs["calibrated IMU, free from the true state"],
    )
    assert raw["position_err_m"] > 20 * cal["position_err_m"] and raw["attitude_err_deg"] > 10
    assert cal["attitude_err_deg"] < 1.0
    kf_raw, kf_cal = runs["raw IMU, KF-aligned"], runs["calibrated IMU, KF-aligned"]
    assert kf_cal["attitude_err_deg"] < kf_raw["attitude_err_deg"] / 2


def test_eval_command(shared_data: Path, tmp_path: Path) -> None:
    d = shared_data / "evo_testdata"
    r = runner.invoke(
        app, ["eval", str(d / "fr2_desk_groundtruth.txt"), str(d / "fr2_desk_ORB.txt"), "--align", "sim3",
              "--out", str(tmp_path / "e")],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    import json

    m = json.loads((tmp_path / "e" / "metrics.json").read_text())
    assert m["n_pairs"] == 2174 and m["align"] == "sim3"
    assert (tmp_path / "e" / "trajectories.png").exists()
    r = runner.invoke(
        app,
        [
            "eval",
            str(d / "fr2_desk_groundtruth.txt"),
            str(d / "fr2_desk_ORB.txt"),
            "--align",
            "xyz",
        ],
    )
    assert r.exit_code == 2 and "--align" in r.output


def test_online_sim_command(tmp_path: Path) -> None:
    r = runner.invoke(
        app,
        ["online", "--sim", "--duration-h", "0.5", "--drift-accel", "0.2", "--out", str(tmp_path)],
    )
    assert r.exit_code == 0, r.output
    # 0.2 m/s^2 per hour crosses the 0.03 m/s^2 threshold after ~10 min: at least one recalibration
    assert "drift" in r.output and len(list((tmp_path / "history").glob("v*.yaml"))) >= 2
    r = runner.invoke(app, ["online"])
    assert r.exit_code == 2 and "--imu-port" in r.output


@pytest.mark.slow
def test_online_shorter_plan_prints_its_predicted_uncertainty(tmp_path: Path) -> None:
    """Fewer poses than seed 000's 40 is an option: the command prints the plan's predicted 1-sigma next to
    the default 40-pose plan's. The accelerometer's information grows with every pose (a sum of positive
    semi-definite terms over a denser set), so each of its ratios exceeds 1; the gyro's depends on the order
    of the moves, so only their mean is asked to."""
    import re

    r = runner.invoke(
        app,
        [
            "online",
            "--sim",
            "--poses",
            "24",
            "--t-init",
            "20",
            "--duration-h",
            "0.05",
            "--out",
            str(tmp_path),
        ],
    )
    assert r.exit_code == 0, r.output
    assert "Predicted 1-sigma with 24 poses" in r.output
    cells = [[c.strip() for c in ln.split("│")[1:-1]] for ln in r.output.splitlines() if "│" in ln]
    rows = [c for c in cells if len(c) == 4 and re.fullmatch(r"[abgs]_[a-z]+", c[0])]
    assert len(rows) == 18, rows
    ratios = np.array([float(c[3]) for c in rows])
    assert np.all(ratios[:9] > 1.0) and np.mean(ratios[9:]) > 1.0, ratios


def test_align_command(tmp_path: Path) -> None:
    """A still simulated IMU with known biases, zero-velocity aiding: the vertical accelerometer bias and
    the level gyro biases come out within 4 sigma (the others are not observable on a still base)."""
    from imuslam.sim.imu import ImuErrorSpec, simulate_imu
    from imuslam.sim.imu_errors import TriadErrors
    from imuslam.sim.trajectory import Static

    ba, bg = np.array([0.02, -0.01, 0.05]), np.array([0.002, -0.001, 0.003])
    spec = ImuErrorSpec(TriadErrors(np.eye(3), np.ones(3), ba, "minus"), TriadErrors(np.eye(3), np.ones(3), bg, "minus"),
                        3e-3, 2e-4)  # fmt: skip
    log, _ = simulate_imu(
        Static(rpy=(0.02, -0.01, 0.3)), 60, np.random.default_rng(0), spec, 100.0, t0_ns=10**18
    )
    write_imu(log, tmp_path / "still.csv", "euroc")
    r = runner.invoke(
        app, ["align", str(tmp_path / "still.csv"), "--method", "kf", "--out", str(tmp_path / "a")]
    )
    assert r.exit_code == 0, r.output
    import json

    res = json.loads((tmp_path / "a" / "metrics.json").read_text())
    assert abs(res["accel_bias"][2] - ba[2]) < 4 * res["accel_bias_std"][2]
    for j in (0, 1):
        assert abs(res["gyro_bias"][j] - bg[j]) < 4 * res["gyro_bias_std"][j]
    assert (tmp_path / "a" / "corrected_imu.csv").exists()
    r = runner.invoke(
        app,
        [
            "align",
            str(tmp_path / "still.csv"),
            "--method",
            "coarse",
            "--lat-deg",
            "47",
            "--out",
            str(tmp_path / "c"),
        ],
    )
    assert r.exit_code == 0 and "unobservable" in r.output
    r = runner.invoke(app, ["align", str(tmp_path / "still.csv"), "--method", "coarse", "--heading-deg", "30",
                            "--out", str(tmp_path / "h")])  # fmt: skip
    assert r.exit_code == 0, r.output
    coarse = json.loads((tmp_path / "h" / "metrics.json").read_text())
    assert coarse["heading_observable"] and abs(np.rad2deg(coarse["yaw"]) - 30.0) < 1e-9


def test_calibrate_no_plots_writes_the_calibration_only(shared_data: Path, tmp_path: Path) -> None:
    """``--no-plots``: calibration.yaml, the imu_tk files and config.yaml, no PNG or report."""
    d = shared_data / "imu_tk_xsens"
    r = runner.invoke(app, ["calibrate", str(d / "xsens_acc.mat"), str(d / "xsens_gyro.mat"), "--g", "9.81744",
                            "--t-init", "50", "--bias-sign", "minus", "--no-plots", "--cv-folds", "0",
                            "--out", str(tmp_path)])  # fmt: skip
    assert r.exit_code == 0, r.output
    names = {p.name for p in tmp_path.iterdir()}
    assert {"calibration.yaml", "acc.calib", "gyro.calib", "config.yaml", "metrics.json"} <= names
    assert not any(n.endswith(".png") or n.endswith(".html") for n in names)
