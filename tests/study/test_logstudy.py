"""A study of a recorded log (``imuslam study`` with 'logs'): the map sharpness without ground truth
against point maps of known spread, the study on the real Cartographer backpack bag against the 2D
SLAM run directly, and bad input (one line, exit 2, nothing written)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
import yaml
from typer.testing import CliRunner

from imuslam.cli import app
from imuslam.eval.mapquality import point_map_quality
from imuslam.imu.model import ImuCalibration, TriadModel

runner = CliRunner()
BAG = "cartographer_backpack_2d/b0-2014-07-21-12-42-53-short.bag"


def walls_2d(rng: np.random.Generator, sigma: float, offset: float = 0.0) -> np.ndarray:
    """Two parallel 8 m walls 2 m apart (no corners), hits every 2 mm with a perpendicular spread
    ``sigma``; with ``offset`` each wall a second time ``offset`` further out (a doubled wall)."""
    x = rng.uniform(0.0, 8.0, 8000)
    parts = []
    for y0 in (0.0, 2.0):
        for dy in (0.0, offset) if offset else (0.0,):
            parts.append(np.column_stack([x, y0 + dy + sigma * rng.normal(size=len(x))]))
    return np.concatenate(parts)


def test_point_map_quality_2d_against_known_spread() -> None:
    rng = np.random.default_rng(1)
    sigma, r = 0.01, 0.2
    p = walls_2d(rng, sigma)
    inner = p[(p[:, 0] > r) & (p[:, 0] < 8 - r)][:3000]  # away from the walls' ends
    q = point_map_quality(p, r, queries=inner)
    # the RMS distance from the local line is sigma; the neighbourhoods (about 400 hits each) estimate
    # it to 1/sqrt(2 * 400) = 3.5 % each, their mean over 3000 queries to well under 3 %
    assert q.wall_spread_cm == pytest.approx(100 * sigma, rel=0.03)
    # entropy of a segment of length 2r (variance r^2 / 3 along it) with sigma across
    expect = 0.5 * np.log((2 * np.pi * np.e) ** 2 * (r**2 / 3) * sigma**2)
    assert q.map_entropy == pytest.approx(expect, abs=0.05)  # 0.05 nats: 5 % of a variance
    # a wall seen twice 4 cm apart (a map from two misaligned passes): spread sqrt(sigma^2 + d^2 / 4)
    d = 0.04
    q2 = point_map_quality(walls_2d(rng, sigma, d), r, queries=inner)
    assert q2.wall_spread_cm == pytest.approx(100 * np.hypot(sigma, d / 2), rel=0.03)
    assert q2.map_entropy > q.map_entropy + 0.5 * np.log(1 + (d / 2 / sigma) ** 2) - 0.05


def test_point_map_quality_3d_plane() -> None:
    rng = np.random.default_rng(2)
    sigma, r = 0.02, 0.3
    n = 60000
    p = np.column_stack([rng.uniform(0, 6, n), rng.uniform(0, 6, n), sigma * rng.normal(size=n)])
    q = point_map_quality(p, r, max_queries=2000)
    # queries away from the edges, where a neighbourhood is a whole disc
    inner = point_map_quality(p, r, queries=p[(np.abs(p[:, :2] - 3) < 2.5).all(axis=1)][:2000])
    assert inner.plane_variance_m2 == pytest.approx(sigma**2, rel=0.06)  # twice sigma's 3 %
    # a disc of radius r has variance r^2 / 4 along each axis of the plane
    expect = 0.5 * np.log((2 * np.pi * np.e) ** 3 * (r**2 / 4) ** 2 * sigma**2)
    assert inner.map_entropy == pytest.approx(expect, abs=0.05)
    assert q.queries == 2000 and q.points == n


def _calibration(path: Path, unit: str = "m/s^2", gyro_b: float = 0.0) -> Path:
    """A calibration file as ``imuslam calibrate`` writes it: identity (or a gyro bias), in ``unit``."""
    gunit = "rad/s" if unit == "m/s^2" else unit
    cal = ImuCalibration(TriadModel(np.eye(3), np.ones(3), np.zeros(3), "plus"),
                         TriadModel(np.eye(3), np.ones(3), np.full(3, gyro_b), "plus"),
                         accel_unit=unit, gyro_unit=gunit)  # fmt: skip
    cal.save_yaml(path)
    return path


def _study(tmp_path: Path, data: Path, runs: list[dict[str, Any]], **log: Any) -> Path:
    spec = {"name": "t", "logs": [{"name": "backpack", "path": str(data / BAG), "estimator": "map2d",
                                   "scan_topic": "horizontal_laser_2d", "runs": runs, **log}]}  # fmt: skip
    f = tmp_path / "study.yaml"
    f.write_text(yaml.safe_dump(spec))
    return f


@pytest.mark.slow  # three 2D SLAM runs over the 10 s bag: about 20 s
def test_log_study_on_the_backpack_bag(tmp_path: Path, shared_data: Path) -> None:
    """Two calibrations of the real bag's IMU through the CLI: an identity one changes nothing, and the
    raw run's map sharpness is that of the 2D SLAM run directly over the bag (the anchor)."""
    from imuslam.io.laserload import load_laser_log
    from imuslam.slam2d.pipeline import Slam2dPipeline
    from imuslam.study.logstudy import map2d_points

    ident = _calibration(tmp_path / "identity.yaml")
    f = _study(
        tmp_path,
        shared_data,
        [{"name": "raw"}, {"name": "identity", "calibration": "identity.yaml"}],
    )
    assert ident.parent == f.parent  # a relative calibration path is read from the study's folder
    out = tmp_path / "out"
    r = runner.invoke(app, ["study", str(f), "--out", str(out)])
    assert r.exit_code == 0, r.output
    for name in ("report.md", "report.html", "results.csv", "study.yaml", "backpack/raw.tum",
                 "backpack/identity.tum"):  # fmt: skip
        assert (out / name).is_file(), name
    df = pd.read_csv(out / "results.csv").set_index("run")
    raw, same = df.loc["raw"], df.loc["identity"]
    for k in ("wall_spread_cm", "map_entropy", "occupied_cells"):
        assert same[k] == raw[k], k  # x_O = I diag(1) (x_S + 0): the same IMU, the same map
    assert same["ref_ate_m"] < 1e-9 and raw["ref_ate_m"] < 1e-9
    # the anchor: the SLAM over the bag as `imuslam map2d` runs it, scored by the same function
    log_ = load_laser_log(shared_data / BAG, "bag", "horizontal_laser_2d")
    run = Slam2dPipeline(log_).run_and_render()
    q = point_map_quality(map2d_points(log_, run.result.pose_xy_yaw, run.result.config), 0.2)
    assert raw["wall_spread_cm"] == pytest.approx(q.wall_spread_cm, rel=1e-9)
    assert raw["map_entropy"] == pytest.approx(q.map_entropy, rel=1e-9)
    # the hits of a real indoor map lie within a few cm of their walls (the scanner's range noise is
    # about 1-3 cm); a map blurred by a wrong pose would show far more
    assert 0.5 < raw["wall_spread_cm"] < 5.0
    # the metric sees a blur on real data: the poses turned by a yaw ramp reaching 1 deg at the end
    # move a hit at range rho by up to 0.017 rho; the hits are mostly 2 m or more away (median 7 m),
    # where the ramp spreads a wall by at least 0.017 * 2 / sqrt(12) = 1 cm, so sqrt(s^2 + 1 cm^2)
    P = run.result.pose_xy_yaw.copy()
    P[:, 2] += np.deg2rad(1.0) * np.linspace(0.0, 1.0, len(P))
    blur = point_map_quality(map2d_points(log_, P, run.result.config), 0.2)
    assert blur.wall_spread_cm > np.hypot(q.wall_spread_cm, 1.0) - 0.05
    # and the entropy by at least 0.5 ln((s^2 + 1 cm^2) / s^2) with s about 3 cm: 0.05 nats
    assert blur.map_entropy > q.map_entropy + 0.05
    assert "backpack: map2d on" in (out / "report.md").read_text()


def _cli_error(tmp_path: Path, f: Path, *extra: str) -> str:
    out = tmp_path / "out"
    r = runner.invoke(app, ["study", str(f), "--out", str(out), *extra])
    assert r.exit_code == 2, r.output
    assert not out.exists()
    text = " ".join(r.output.split())
    assert text.startswith("error: ") and text.count("error:") == 1, r.output
    return text


def test_log_without_the_estimators_topics(tmp_path: Path, shared_data: Path) -> None:
    f = _study(tmp_path, shared_data, [{"name": "raw"}], scan_topic="no_such_scan")
    line = _cli_error(tmp_path, f)
    assert (
        "logs[0] (backpack) (map2d needs a 2D laser scan topic)" in line and "no_such_scan" in line
    )
    f = _study(tmp_path, shared_data, [{"name": "raw"}], estimator="vio", scan_topic=None)
    line = _cli_error(tmp_path, f)
    assert "logs[0] (backpack) (vio needs stereo images and an IMU)" in line


def test_calibration_for_another_sensors_units(tmp_path: Path, shared_data: Path) -> None:
    """A calibration of a sensor logged in raw counts (imu_tk's) applied to the bag's SI IMU."""
    _calibration(tmp_path / "counts.yaml", "counts")
    f = _study(
        tmp_path, shared_data, [{"name": "raw"}, {"name": "c", "calibration": "counts.yaml"}]
    )
    line = _cli_error(tmp_path, f)
    assert "logs[0] (backpack).runs[1] (c).calibration:" in line
    assert (
        "the calibration applies to accel in counts and gyro in counts; the log has m/s^2" in line
    )


@pytest.mark.parametrize(
    ("runs", "log", "expect"),
    [
        ([], {}, "logs[0] (backpack).runs is empty"),
        ([{"name": "a"}, {"name": "a"}], {}, "run names repeat: a"),
        ([{"name": "a"}], {"reference": "b"}, "reference 'b' is not a run (a)"),
        ([{"name": "a", "colour": 1}], {}, "logs[0] (backpack).runs[0] (a).colour: unknown key"),
        ([{"name": "a", "calibration": "nope.yaml"}], {}, "runs[0] (a).calibration: "),
        ([{"name": "a", "inject": "seed999"}], {}, "runs[0] (a).inject: Input should be 'seed000'"),
        (
            [{"name": "a", "use_imu": False, "inject": "seed000"}],
            {},
            "run 'a': use_imu false with an IMU to corrupt or correct",
        ),
        ([{"name": "a", "use_imu": False}], {"estimator": "vio"}, "run 'a' without the IMU; vio"),
        (
            [{"name": "a"}],
            {"estimator": "slam9000"},
            "logs[0] (backpack).estimator: Input should be",
        ),
    ],
)
def test_bad_log_study(
    tmp_path: Path, shared_data: Path, runs: list[dict[str, Any]], log: dict[str, Any], expect: str
) -> None:
    assert expect in _cli_error(tmp_path, _study(tmp_path, shared_data, runs, **log))


@pytest.mark.slow  # a 4 s simulated street drive, LIO twice: about 20 s
def test_log_study_lio_on_a_simulated_bag(tmp_path: Path) -> None:
    """lio over a bag of the simulator's street drive, whose IMU has seed 000's table-2 errors: as
    recorded against corrected by the true model; both maps scored in 3D, both runs against the truth."""
    from dataclasses import replace

    from imuslam.interfaces import Trajectory
    from imuslam.io.trajectory import write_tum
    from imuslam.sim import export
    from imuslam.sim.drive import simulate_lidar_drive
    from imuslam.sim.imu_errors import SEED000_ACCEL, SEED000_GYRO

    d = simulate_lidar_drive("street", 4.0, seed=5)
    pc = [(s.t_ns, "/points", export.pointcloud_message(replace(s))[1]) for s in d.scans]
    export.write_bag(tmp_path / "bag", [export.imu_messages(d.imu), iter(pc)])
    write_tum(Trajectory(d.gt_t_ns, d.gt_p_w, d.gt_R_w_b, "truth"), tmp_path / "gt.tum")
    a, g = SEED000_ACCEL, SEED000_GYRO
    ImuCalibration(TriadModel(a.T, a.K, a.b, a.bias_sign),
                   TriadModel(g.T, g.K, g.b, g.bias_sign)).save_yaml(tmp_path / "true.yaml")  # fmt: skip
    spec = {"logs": [{"name": "street", "path": "bag", "estimator": "lio", "gt": "gt.tum",
                      "config": {"extrinsic": {"p_i_l": [0.0, 0.0, 0.2]}},
                      "runs": [{"name": "raw"}, {"name": "true", "calibration": "true.yaml"}]}]}  # fmt: skip
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(spec))
    out = tmp_path / "out"
    r = runner.invoke(app, ["study", str(tmp_path / "s.yaml"), "--out", str(out)])
    assert r.exit_code == 0, r.output
    df = pd.read_csv(out / "results.csv").set_index("run")
    for run in ("raw", "true"):
        # the simulated VLP-16's 2 cm range noise, and the 5 cm voxels of the map: a few cm about the
        # walls' planes; a map blurred by a wrong pose would be far wider
        assert 1.0 < df.loc[run, "wall_spread_cm"] < 8.0
        assert np.isfinite(df.loc[run, "map_entropy"])
        assert df.loc[run, "gt_ate_m"] < 0.05  # 0.5 % of the path, the LIO's own bound
    # the true model leaves the IMU its noise only: its attitude against the truth is no worse
    assert df.loc["true", "gt_ate_rot_deg"] <= df.loc["raw", "gt_ate_rot_deg"] + 0.01


def test_log_study_refuses_workers(tmp_path: Path, shared_data: Path) -> None:
    f = _study(tmp_path, shared_data, [{"name": "raw"}])
    assert "--workers: a study of recorded logs runs its runs one after" in _cli_error(
        tmp_path, f, "--workers", "2"
    )


def _synthetic_imu(n: int = 2000) -> Any:
    """An SI log of a moving platform: gravity in a tilting body frame plus 0.2 m/s^2 of motion, turn
    rates up to about 1 rad/s."""
    from imuslam.interfaces import ImuLog

    rng = np.random.default_rng(3)
    t = np.arange(n) * 5_000_000
    up = rng.normal(size=(n, 3)) * 0.2 + np.array([0.0, 0.0, 1.0])
    accel = 9.81 * up / np.linalg.norm(up, axis=1, keepdims=True) + rng.normal(size=(n, 3)) * 0.2
    return ImuLog(t, accel, rng.uniform(-1.0, 1.0, (n, 3)), "m/s^2", "rad/s", "synthetic")


def test_injected_errors_are_the_simulators_and_a_calibration_undoes_them() -> None:
    from imuslam.sim.imu_errors import SEED000_ACCEL, SEED000_GYRO
    from imuslam.study.logstudy import gimbal_calibration_seed000, inject_seed000

    imu = _synthetic_imu()
    bad = inject_seed000(imu)
    # the model's own inverse: x_O = T K (x_S + b) gives the recorded values back to round-off
    a, g = SEED000_ACCEL, SEED000_GYRO
    true = ImuCalibration(
        TriadModel(a.T, a.K, a.b, a.bias_sign), TriadModel(g.T, g.K, g.b, g.bias_sign)
    )
    back = true.correct(bad)
    assert np.abs(back.accel - imu.accel).max() < 1e-12
    assert np.abs(back.gyro - imu.gyro).max() < 1e-12
    # the injected errors are large: 0.05 rad/s of gyro bias, up to 9 % of axis misalignment
    assert np.abs(bad.gyro - imu.gyro).max() > 0.05
    # a calibration estimated from a simulated 40-pose gimbal session: its scale and misalignment
    # known to a few 1e-4 (the calibrate command's uncertainties), so at 1 rad/s and 10 m/s^2 a few
    # 1e-4 rad/s and about 1e-3 m/s^2 are left; the bounds are 4x that, 25x under the injected errors
    cal = gimbal_calibration_seed000(0, "multipose")
    rec = cal.correct(bad)
    assert np.abs(rec.gyro - imu.gyro).max() < 2e-3
    assert np.abs(rec.accel - imu.accel).max() < 1e-2


def test_a_log_in_counts_needs_a_calibration(tmp_path: Path) -> None:
    """A log in raw counts given to an estimator as is, or corrected by a calibration in other units."""
    from imuslam.errors import InputError
    from imuslam.interfaces import ImuLog
    from imuslam.study.logconfig import RunSpec
    from imuslam.study.logstudy import _run_imu

    n = 100
    counts = ImuLog(np.arange(n) * 10_000_000, np.full((n, 3), 32768.0), np.full((n, 3), 32768.0),
                    "counts", "counts", "log.txt")  # fmt: skip
    with pytest.raises(InputError, match=r"runs\[0\] \(raw\): the log's IMU is in raw counts"):
        _run_imu(counts, RunSpec(name="raw"), "runs[0] (raw)", "")
    si = _calibration(tmp_path / "si.yaml")
    with pytest.raises(
        InputError, match=r"calibration: log.txt: the calibration applies to accel in m/s"
    ):
        _run_imu(counts, RunSpec(name="c", calibration=str(si)), "runs[1] (c)", "")
    assert _run_imu(counts, RunSpec(name="off", use_imu=False), "w", "") is counts


def test_a_gimbal_session_without_a_calibration_is_an_estimator_failure(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The simulated session that corrects a run's IMU ends without a calibration: the calibrator
    failed on a session it made itself (exit 3), not a bad study file (exit 2)."""
    from types import SimpleNamespace

    import imuslam.imu.online_sim as online_sim
    import imuslam.imu.poseplan as poseplan
    from imuslam.errors import EstimatorError, InputError
    from imuslam.study.logstudy import gimbal_calibration_seed000

    monkeypatch.setattr(poseplan, "optimise_order", lambda model, plan, iterations: plan)
    none = SimpleNamespace(calibrator=SimpleNamespace(current=None))
    monkeypatch.setattr(online_sim, "run_simulated_robot", lambda *args: none)
    gimbal_calibration_seed000.cache_clear()
    try:
        with pytest.raises(
            EstimatorError, match="gimbal_seed 7: the simulated online session"
        ) as e:
            gimbal_calibration_seed000(7)
        assert not isinstance(e.value, InputError)
    finally:
        gimbal_calibration_seed000.cache_clear()


@pytest.mark.slow  # the VO over 95 stereo pairs, the filter four times: about 10-20 s
def test_log_study_vio_on_euroc(tmp_path: Path, shared_data: Path) -> None:
    """vio over the real EuRoC V1_01 excerpt: an identity calibration changes nothing; seed 000's
    errors injected make the IMU alone drift; a gimbal calibration of those errors gives it back."""
    _calibration(tmp_path / "identity.yaml")
    spec = {"logs": [{"name": "euroc", "path": str(shared_data / "euroc_V1_01_micro_kimera"),
                      "estimator": "vio", "align": "first",
                      "gt": str(shared_data / "euroc_gt_openvins" / "V1_01_easy_original.txt"),
                      "runs": [{"name": "original"}, {"name": "identity", "calibration": "identity.yaml"},
                               {"name": "corrupted", "inject": "seed000"},
                               {"name": "recal", "inject": "seed000", "gimbal_calibration": "seed000",
                                "gimbal_method": "multipose"}]}]}  # fmt: skip
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(spec))
    out = tmp_path / "out"
    r = runner.invoke(app, ["study", str(tmp_path / "s.yaml"), "--out", str(out)])
    assert r.exit_code == 0, r.output
    df = pd.read_csv(out / "results.csv").set_index("run")
    cols = ["gt_ate_m", "gt_ate_rot_deg", "gt_imu_ate_m"]
    assert (df.loc["identity", cols] == df.loc["original", cols]).all()
    # the fused VIO follows the truth to a few mm over the excerpt's 4 cm path (the VO carries it)
    assert df.loc["original", "gt_ate_m"] < 0.005
    # the injected errors (0.14 m/s^2 of accelerometer bias, 9 % of gyro misalignment) at least
    # double the IMU's own drift over 4.7 s
    orig, bad, rec = (df.loc[k, "gt_imu_ate_m"] for k in ("original", "corrupted", "recal"))
    assert bad > 1.5 * orig
    # the calibration leaves about 1e-3 m/s^2: 0.5 * 1e-3 * 4.7^2 = 0.01 m over the excerpt
    assert abs(rec - orig) < 0.02
