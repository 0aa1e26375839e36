"""``imuslam align`` on real EuRoC data with its ground truth, and its input errors."""

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from imuslam.cli import app

runner = CliRunner()


def _euroc(shared_data: Path) -> Path:
    return shared_data / "euroc_V1_02_imu_gt_kimera" / "mav0"


@pytest.mark.parametrize("method", ["kf", "rwnn"])
def test_align_euroc_against_ground_truth(shared_data: Path, tmp_path: Path, method: str) -> None:
    """V1_02 IMU, its ground-truth positions as aiding (2 mm) and its ground-truth state as truth, noise as
    the log shows it: every final bias within 3 of its sigma of gt0's, the plots and series written."""
    d = _euroc(shared_data)
    gt = str(d / "gt0" / "data.csv")
    r = runner.invoke(app, ["align", str(d / "imu0" / "data.csv"), "--method", method, "--aiding", gt,
                            "--aiding-std", "0.002", "--truth", gt, "--g", "9.81", "--out", str(tmp_path)])  # fmt: skip
    assert r.exit_code == 0, r.output
    res = json.loads((tmp_path / "metrics.json").read_text())
    assert np.all(np.abs(res["accel_bias_error_sigmas"]) < 3) and np.all(
        np.abs(res["gyro_bias_error_sigmas"]) < 3
    )
    assert res["noise"]["source"] == "from the log"
    for f in ("biases.png", "attitude_error.png", "estimates.csv", "corrected_imu.csv"):
        assert (tmp_path / f).stat().st_size > 0
    est = np.loadtxt(tmp_path / "estimates.csv", delimiter=",", skiprows=1)
    assert est.shape[1] == 16 and np.allclose(est[-1, 1:4], res["accel_bias"], rtol=1e-6)
    # the one writer's files: metrics.json (no copy of it under another name), config.yaml, the
    # filter's poses as TUM
    assert sorted(p.name for p in tmp_path.glob("[!.]*.json")) == ["metrics.json"]
    # the terminal: the final heading error against the truth, the random walks with their units
    text = " ".join(r.output.split())
    heading = res["attitude_error_deg"][2]
    assert f"heading {heading:+.3f} deg" in text
    assert "m/s^3/sqrt(Hz)" in text and "rad/s^2/sqrt(Hz)" in text
    assert f"method: {method}" in (tmp_path / "config.yaml").read_text()
    tum = [ln for ln in (tmp_path / "trajectory.tum").read_text().splitlines() if ln[0] != "#"]
    assert len(tum) == len(est) and len(tum[0].split()[0].split(".")[1]) == 9


def test_align_euroc_datasheet_noise_is_overconfident(shared_data: Path, tmp_path: Path) -> None:
    """The same run with the datasheet noise (a sensor at rest) on the vibrating MAV: at least one
    accelerometer bias lands more than 3 sigma from gt0's, which the check above would catch."""
    d = _euroc(shared_data)
    gt = str(d / "gt0" / "data.csv")
    r = runner.invoke(app, ["align", str(d / "imu0" / "data.csv"), "--aiding", gt, "--aiding-std", "0.002",
                            "--truth", gt, "--g", "9.81", "--noise", "datasheet", "--out", str(tmp_path)])  # fmt: skip
    assert r.exit_code == 0, r.output
    res = json.loads((tmp_path / "metrics.json").read_text())
    assert np.any(np.abs(res["accel_bias_error_sigmas"]) > 3)


def test_align_bad_truth_and_noise_files_are_named(shared_data: Path, tmp_path: Path) -> None:
    d = _euroc(shared_data)
    imu, gt = str(d / "imu0" / "data.csv"), str(d / "gt0" / "data.csv")
    short = tmp_path / "short.csv"
    short.write_text("#t,x,y,z\n1403715524922140000,0.5,1.9,0.9\n")
    r = runner.invoke(
        app, ["align", imu, "--aiding", gt, "--truth", str(short), "--out", str(tmp_path / "o")]
    )
    assert r.exit_code == 2 and "short.csv" in r.output and "17 columns" in r.output
    assert not (tmp_path / "o" / "metrics.json").exists()
    yml = tmp_path / "imu.yaml"
    yml.write_text(
        "accelerometer_noise_density: 0.002\ngyroscope_noise_density: 0.0002\naccelerometer_random_walk: 0.0001\n"
    )
    r = runner.invoke(
        app, ["align", imu, "--aiding", gt, "--noise", str(yml), "--out", str(tmp_path / "o")]
    )
    assert r.exit_code == 2 and "gyroscope_random_walk" in r.output
    r = runner.invoke(app, ["align", imu, "--init", "aiding", "--out", str(tmp_path / "o")])
    assert r.exit_code == 2 and "--init aiding needs a trajectory" in r.output


def test_align_bag_with_pose_topic_writes_a_corrected_bag(tmp_path: Path) -> None:
    """A simulated hand-held MCAP (IMU + ground-truth PoseStamped): the poses aid, and the output is the
    input bag with only the IMU topic replaced (same message counts, biases removed)."""
    from rosbags.highlevel import AnyReader

    from imuslam.sim.scenario import run_scenario

    run_scenario("handheld", 10.0, tmp_path / "sim", seed=1, progress=False)
    bag = tmp_path / "sim" / "bag"
    r = runner.invoke(app, ["align", str(bag), "--topic", "/imu/data", "--aiding", str(bag), "--aiding-topic",
                            "/ground_truth", "--aiding-std", "0.005", "--out", str(tmp_path / "a")])  # fmt: skip
    assert r.exit_code == 0, r.output
    res = json.loads((tmp_path / "a" / "metrics.json").read_text())

    def counts(p: Path) -> dict[str, int]:
        with AnyReader([p]) as rd:
            return {c.topic: c.msgcount for c in rd.connections}

    assert counts(tmp_path / "a" / "corrected_imu") == counts(bag)
    with AnyReader([tmp_path / "a" / "corrected_imu"]) as rd, AnyReader([bag]) as rb:
        ci = [c for c in rd.connections if c.topic == "/imu/data"]
        cb = [c for c in rb.connections if c.topic == "/imu/data"]
        m1 = rd.deserialize(next(iter(rd.messages(connections=ci)))[2], ci[0].msgtype)
        m0 = rb.deserialize(next(iter(rb.messages(connections=cb)))[2], cb[0].msgtype)
    w0 = np.array([m0.angular_velocity.x, m0.angular_velocity.y, m0.angular_velocity.z])
    w1 = np.array([m1.angular_velocity.x, m1.angular_velocity.y, m1.angular_velocity.z])
    np.testing.assert_allclose(w0 - w1, res["gyro_bias"], atol=1e-9)
