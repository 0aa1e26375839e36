"""PCA9685 register writes against the datasheet, the simulated gimbal, and RPLIDAR scan binning."""

import numpy as np
import pytest

from imuslam.hw.gimbal import (
    LED0_ON_L,
    MODE1,
    PRESCALE,
    Pca9685Gimbal,
    ServoSpec,
    SimulatedGimbal,
    prescale_for,
)
from imuslam.hw.rplidar import scan_from_measurements


class FakeBus:
    def __init__(self) -> None:
        self.regs: dict[int, int] = {MODE1: 0x11}
        self.writes: list[tuple[int, int]] = []

    def read_byte_data(self, addr: int, reg: int) -> int:
        return self.regs.get(reg, 0)

    def write_byte_data(self, addr: int, reg: int, val: int) -> None:
        assert 0 <= val <= 255
        self.regs[reg] = val
        self.writes.append((reg, val))


def test_pca9685_prescale_and_pulses() -> None:
    # datasheet: prescale = round(25e6 / (4096 * 50)) - 1 = 121 for 50 Hz
    assert prescale_for(50.0) == 121
    bus = FakeBus()
    g = Pca9685Gimbal(ServoSpec(0), ServoSpec(1), bus=bus)
    assert (PRESCALE, 121) in bus.writes
    # the prescale is written while the chip sleeps
    i = bus.writes.index((PRESCALE, 121))
    assert bus.writes[i - 1][0] == MODE1 and bus.writes[i - 1][1] & 0x10
    g.move_to((0.0, 90.0))
    # 0 deg -> 1500 us -> 1500 / 20000 * 4096 = 307.2 -> 307 counts; 90 deg -> 2500 us -> 512
    off0 = bus.regs[LED0_ON_L + 2] | (bus.regs[LED0_ON_L + 3] << 8)
    off1 = bus.regs[LED0_ON_L + 6] | (bus.regs[LED0_ON_L + 7] << 8)
    assert (off0, off1) == (307, 512)
    assert g.angles_deg() == (0.0, 90.0)


def test_simulated_gimbal_quantisation_and_speed() -> None:
    g = SimulatedGimbal(speed_dps=60.0)
    g.move_to((10.04, 200.0))
    r, p = g.angles_deg()
    assert r == pytest.approx(round(10.04 / (360 / 4096)) * 360 / 4096)
    assert p == pytest.approx(2048 * 360 / 4096)  # clipped at the +180 deg limit
    path = g.trajectory((0.0, 0.0), (30.0, 0.0), np.array([0.0, 0.25, 0.5, 1.0]))
    np.testing.assert_allclose(path[:, 0], [0.0, 15.0, 30.0, 30.0], atol=360 / 4096)  # 60 deg/s
    # from (r, 180) to (60, 0): the pitch joint turns 180 deg at 60 deg/s
    assert g.settle_time_s((60.0, 0.0)) == pytest.approx(180.0 / 60.0, rel=1e-3)


def test_rplidar_binning() -> None:
    meas = [
        (15, 0.0, 1000.0),
        (15, 90.0, 2000.0),
        (15, 90.1, 1500.0),
        (0, 45.0, 500.0),
        (15, 10.0, 50.0),
    ]
    s = scan_from_measurements(meas, 0)
    ang = s.angle_min + np.arange(len(s.ranges)) * s.angle_increment
    front = np.argmin(np.abs(ang - 0.0))
    right = np.argmin(np.abs(ang + np.pi / 2))  # 90 deg clockwise = -90 deg in REP-103
    assert s.ranges[front] == pytest.approx(1.0)
    assert s.ranges[right] == pytest.approx(1.5)  # nearest return wins the bin
    assert np.isfinite(s.ranges).sum() == 2  # quality 0 and below range_min dropped


def test_pca9685_resolution_is_about_044_deg_per_count() -> None:
    """One count of the 12-bit counter is 1/4096 of the 20 ms period (4.883 us); a 500-2500 us servo spans
    180 deg, so a count is 4.883 / 2000 x 180 = 0.4395 deg (0.879 deg for a joint mapped over 360 deg),
    5x-10x coarser than seed 000's 0.088 deg; the pose planner predicts at the angles it can reach."""
    from imuslam.imu.poseplan import PlanModel

    g = Pca9685Gimbal(ServoSpec(0), ServoSpec(1, min_deg=-180, max_deg=180), bus=FakeBus())
    assert g.servos[0].resolution_deg(50.0) == pytest.approx(20000 / 4096 / 2000 * 180, rel=1e-12)
    assert g.resolution_deg == pytest.approx(20000 / 4096 / 2000 * 360, rel=1e-12)
    model = PlanModel.seed000()
    coarse = PlanModel(model.nominal, resolution_deg=g.resolution_deg)
    reached = coarse.reachable(np.array([[10.3, -47.2]]))
    np.testing.assert_allclose(
        reached / g.resolution_deg, np.round(reached / g.resolution_deg), atol=1e-9
    )
    assert np.all(np.abs(reached - [[10.3, -47.2]]) <= g.resolution_deg / 2)
