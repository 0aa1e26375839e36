"""Online calibration on a simulated robot whose IMU errors drift over an hour; calibration history."""

import os
from pathlib import Path

import numpy as np
import pytest

from imuslam.imu.history import CalibrationHistory
from imuslam.imu.online import OnlineConfig, StillDetector
from imuslam.imu.online_sim import T0_NS, Drift, run_simulated_robot
from imuslam.imu.poseplan import PlanModel, optimise_order
from imuslam.imu.static import windowed_variance_norm
from imuslam.sim.multipose import sphere_plan_deg

CFG = OnlineConfig()  # seed 000: T_init 50 s
CHI2_9_999 = 27.88  # 99.9 % quantile of chi-square with 9 degrees of freedom


def _run(drift: Drift, seed: int, tmp_path: Path | None = None):  # type: ignore[no-untyped-def]
    """One simulated hour, the 40 poses in the order ``imuslam online`` flies them."""
    rng = np.random.default_rng(seed)
    hist = CalibrationHistory(tmp_path) if tmp_path else None
    plan = optimise_order(PlanModel.seed000(), sphere_plan_deg(40, rng), iterations=1000)
    return run_simulated_robot(plan, 3600.0, drift, rng, CFG, hist)


def test_no_trigger_below_threshold() -> None:
    """z accelerometer bias drifting 0.02 m/s^2 in the hour: below the 0.03 m/s^2 threshold, never flagged."""
    run = _run(Drift(accel_bias_per_h=np.array([0.0, 0.0, 0.02])), 1)
    kinds = [e.kind for e in run.calibrator.events]
    assert kinds.count("calibrated") == 1 and "drift" not in kinds
    assert len(run.calibrator.drift_stats) >= 10


def test_trigger_above_threshold_and_track_truth(tmp_path: Path) -> None:
    """0.05 m/s^2 per hour on z (plus gyro bias and scale drift): the monitor fires only once the true
    gravity-norm error exceeds 0.03 m/s^2, the robot recalibrates, and every calibration agrees with the
    truth of its session within its covariance (chi-square, 9 dof, 99.9 %)."""
    drift = Drift(
        accel_bias_per_h=np.array([0.0, 0.0, 0.05]),
        gyro_bias_per_h=np.full(3, 0.001),
        scale_per_h=2e-4,
    )
    run = _run(drift, 2, tmp_path)
    cal = run.calibrator
    ev = [e for e in cal.events if e.kind == "drift"]
    assert len(ev) >= 1
    first = (ev[0].t_ns - T0_NS) * 1e-9
    truth = drift.truth_at(first)
    session_cal = CalibrationHistory(tmp_path).load(1)
    # true gravity-norm error of the first calibration at home pose (z up) when it fired
    raw = truth.accel.invert(np.array([[0.0, 0.0, 9.80665]]))
    true_err = abs(np.linalg.norm(session_cal.correct_accel(raw)) - 9.80665)
    assert true_err > CFG.max_norm_error
    # no drift event while the true error was below the threshold
    for s in cal.drift_stats:
        if s["t_s"] - T0_NS * 1e-9 < first:
            r = drift.truth_at(s["t_s"] - T0_NS * 1e-9).accel.invert(
                np.array([[0.0, 0.0, 9.80665]])
            )
            assert (
                abs(np.linalg.norm(session_cal.correct_accel(r)) - 9.80665)
                < CFG.max_norm_error + 0.01
            )
    versions = CalibrationHistory(tmp_path).versions()
    assert len(versions) == len(run.sessions) >= 2
    for v, (t0, t1) in zip(versions, run.sessions, strict=True):
        c = CalibrationHistory(tmp_path).load(v)
        # the truth at the time the calibration's bias refers to (the mean of its poses' times when
        # it carries a drift term, session-relative), else the session's middle
        t_ref = c.notes.get("accel_bias_drift_t_ref_s")
        tr = drift.truth_at(0.5 * (t0 + t1) if t_ref is None else t0 + float(t_ref))
        e = c.accel_params - tr.accel_params
        assert c.cov_accel is not None and e @ np.linalg.solve(c.cov_accel, e) < CHI2_9_999
        eg = c.gyro_params - tr.gyro_params
        assert c.cov_gyro is not None and eg @ np.linalg.solve(c.cov_gyro, eg) < CHI2_9_999
        # Each version carries its cross-validated score: held-out poses at the BWT901CL noise floor
        # (~0.03 deg per pair, ~0.002 m/s^2 per pose; twice that for the parameters' own error).
        cv = c.notes["cross_validation"]
        assert cv["folds"] == 5 and cv["poses"] >= 20
        assert 0 < cv["direction_rms_deg"] < 0.1 and 0 < cv["norm_rms_mps2"] < 0.005


def test_streaming_detector_equals_batch() -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(size=(500, 3)) + 100.0
    det = StillDetector(101)
    s = np.array([det.push(v) for v in x])
    ref = windowed_variance_norm(x, 50)
    # the streaming value at sample k is the batch value centred 50 samples earlier
    np.testing.assert_allclose(s[100:], ref[50:-50], rtol=1e-9)


def test_history_lookup_and_crash_safety(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from imuslam.imu.model import ImuCalibration, TriadModel
    from imuslam.sim.imu_errors import SEED000_ACCEL, SEED000_GYRO

    h = CalibrationHistory(tmp_path)
    for i, date in enumerate(["2026-01-01T00:00:00+00:00", "2026-03-01T00:00:00+00:00"]):
        c = ImuCalibration(TriadModel(SEED000_ACCEL.T, SEED000_ACCEL.K * (1 + i), SEED000_ACCEL.b),
                           TriadModel(SEED000_GYRO.T, SEED000_GYRO.K, SEED000_GYRO.b), date=date)  # fmt: skip
        assert h.add(c) == i + 1
    assert h.in_force("2026-02-01T00:00:00+00:00").accel.K[0] == SEED000_ACCEL.K[0]  # type: ignore[union-attr]
    assert h.closest("2026-02-20T00:00:00+00:00").accel.K[0] == 2 * SEED000_ACCEL.K[0]  # type: ignore[union-attr]
    assert h.in_force("2025-12-31T00:00:00+00:00") is None

    def boom(*_: object) -> None:
        raise OSError("power cut")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError, match="power cut"):
        h.add(h.load(2))
    monkeypatch.undo()
    assert h.versions() == [1, 2]
    assert h.latest().accel.K[0] == 2 * SEED000_ACCEL.K[0]  # type: ignore[union-attr]
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "v0001.yaml",
        "v0002.yaml",
    ]  # no leftovers


def test_without_gimbal_gyro_bias_refreshed_from_still_moments() -> None:
    """No gimbal: the gyro bias drifts by 0.01 rad/s; a still moment flags it and the bias alone is
    re-estimated, to the accuracy its still moment allows (noise 1.75e-3 rad/s / sqrt(600): 7e-5 rad/s)."""
    from imuslam.imu.model import ImuCalibration, TriadModel
    from imuslam.sim.imu_errors import SEED000_ACCEL, SEED000_GYRO
    from imuslam.sim.multipose import GimbalImuStream

    drift = Drift(gyro_bias_per_h=np.array([0.01, -0.01, 0.005]))
    rng = np.random.default_rng(4)
    stream = GimbalImuStream(rng, drift.errors_at)
    start = ImuCalibration(TriadModel(SEED000_ACCEL.T, SEED000_ACCEL.K, SEED000_ACCEL.b),
                           TriadModel(SEED000_GYRO.T, SEED000_GYRO.K, SEED000_GYRO.b))  # fmt: skip
    from imuslam.imu.online import OnlineCalibrator

    cal = OnlineCalibrator(sphere_plan_deg(40), None, CFG, current=start)
    stream.skip(3600.0)
    t, a, w = stream.read(600)
    for i in range(len(t)):
        cal.step(int(t[i]), a[i], w[i])
    cal._end_still(int(t[-1]))
    kinds = [e.kind for e in cal.events]
    assert "drift" in kinds and "calibrated" in kinds
    true_b = drift.errors_at(3600.0)[1].b
    assert cal.current is not None
    np.testing.assert_allclose(cal.current.gyro.b, true_b, atol=5 * 7e-5 * 1.04)
    np.testing.assert_array_equal(cal.current.accel.K, start.accel.K)


class _ServoBoard:
    """I2C bus of a PCA9685 whose channels 0 and 1 drive the simulated gimbal: the OFF count written to a
    channel is a pulse width, hence a joint angle (the servo's linear map); writing channel 1's last
    register moves the gimbal. Records when each move ends on the IMU's clock."""

    def __init__(self, stream, servos, freq_hz: float = 50.0) -> None:  # type: ignore[no-untyped-def]
        from imuslam.hw.gimbal import LED0_ON_L, MODE1

        self.stream, self.servos, self.freq = stream, servos, freq_hz
        self.led0 = LED0_ON_L
        self.regs: dict[int, int] = {MODE1: 0x11}
        self.target = [0.0, 0.0]
        self.arrivals_ns: list[int] = []

    def read_byte_data(self, addr: int, reg: int) -> int:
        return self.regs.get(reg, 0)

    def write_byte_data(self, addr: int, reg: int, val: int) -> None:
        self.regs[reg] = val
        ch, r = divmod(reg - self.led0, 4)
        if reg < self.led0 or ch > 1 or r != 3:
            return
        off = self.regs[reg - 1] | ((val & 0x0F) << 8)
        pulse_us = off / 4096 * 1e6 / self.freq
        s = self.servos[ch]
        self.target[ch] = s.min_deg + (pulse_us - s.min_pulse_us) / (
            s.max_pulse_us - s.min_pulse_us
        ) * (s.max_deg - s.min_deg)
        if ch == 1:
            T = self.stream.command(np.array(self.target))
            self.arrivals_ns.append(self.stream.t0_ns + int(round((self.stream.t_s + T) * 1e9)))


class _WitMotionPort:
    """A serial port with a BWT901CL behind it: each read returns the next few samples of the simulated
    IMU on the gimbal as WitMotion packets; ``now_ns`` is the host clock at that read (epoch time)."""

    def __init__(self, stream, per_read: int = 5) -> None:  # type: ignore[no-untyped-def]
        self.stream, self.per_read = stream, per_read
        self.is_open = True
        self.in_waiting = 22 * per_read
        self.now_ns = stream.t0_ns
        self.written = b""

    def read(self, n: int) -> bytes:
        from imuslam.hw.witmotion import encode_imu

        t, a, w = self.stream.read(self.per_read)
        self.now_ns = int(t[-1])
        return b"".join(encode_imu(a[i], w[i]) for i in range(len(t)))

    def write(self, b: bytes) -> None:
        self.written += b

    def close(self) -> None:
        self.is_open = False


def test_hardware_path_waits_for_the_gimbal_before_t_init() -> None:
    """The robot's code path (WitMotion reader on a serial port, PCA9685 gimbal on an I2C bus, the loop of
    ``imuslam online``) against a simulated gimbal and IMU behind fake serial and I2C devices, on an epoch
    clock, with seed 000's defaults (40 poses, T_init 50 s). The servos power up far from the first pose:
    the session's samples start only once the gimbal has arrived there, and the gyro bias from T_init is
    the true one within 4 sigma of the reported covariance."""
    from imuslam.hw.gimbal import Pca9685Gimbal, ServoSpec
    from imuslam.hw.witmotion import WitMotionImu
    from imuslam.imu.online import OnlineCalibrator
    from imuslam.imu.online_session import run_online
    from imuslam.sim.imu_errors import SEED000_GYRO
    from imuslam.sim.multipose import GimbalImuStream

    rng = np.random.default_rng(4)
    servos = (ServoSpec(0, speed_dps=90.0), ServoSpec(1, min_deg=-180, max_deg=180, speed_dps=90.0))
    # min-jerk moves peak at 1.875x their mean rate: the servo's 90 deg/s is its mean rate
    stream = GimbalImuStream(rng, joint_speed_dps=90.0 * 1.875, resolution_deg=1e-9, t0_ns=T0_NS)
    stream.angles = np.array([70.0, 150.0])  # where the servos stand at power-up
    board = _ServoBoard(stream, servos)
    port = _WitMotionPort(stream)
    imu = WitMotionImu("/dev/fake", serial_port=port, clock_ns=lambda: port.now_ns)
    gimbal = Pca9685Gimbal(*servos, bus=board)
    plan = sphere_plan_deg(40)

    def done(c: OnlineCalibrator) -> bool:
        return c.phase == "monitor" or stream.t_s > 900.0

    cal = run_online(imu, gimbal, plan, OnlineConfig(), None, 100.0, stop=done)
    assert cal.current is not None and cal.phase == "monitor"
    first = cal.events[0]
    assert first.kind == "session_start" and first.t_ns >= T0_NS
    log = cal.session_log()
    assert log.t_ns[0] >= board.arrivals_ns[0]  # T_init begins once the gimbal is at the first pose
    # ... and no later than the driver's worst case for a first move (360 deg at 90 deg/s, + 0.3 s)
    assert log.t_ns[0] - first.t_ns <= 4.3e9 + 1e7
    assert cal.last_result is not None and len(cal.last_result.intervals) >= 38
    assert cal.current.cov_gyro_bias is not None
    sd = np.sqrt(np.diag(cal.current.cov_gyro_bias))
    err = cal.current.gyro.b - SEED000_GYRO.b
    assert np.all(np.abs(err) < 4 * sd), (err, sd)
