"""2-axis servo gimbals (the protocol is :class:`imuslam.interfaces.gimbal.Gimbal`): a PCA9685 (I2C PWM) driver for hobby servos, and a simulated gimbal.

Why the PCA9685: one cheap, common board drives both servos with hardware-timed 50 Hz PWM from a
Raspberry Pi's I2C bus, so servo pulses do not jitter with the Pi's CPU load (software PWM on GPIO does).
Register map and prescale formula from the NXP PCA9685 datasheet (rev. 4), sections 7.3.1 and 7.3.5:
``prescale = round(25 MHz / (4096 * f)) - 1``; LEDn_ON/OFF at ``0x06 + 4 n``.

Resolution. The PCA9685's 12-bit counter spans the whole 20 ms PWM period at 50 Hz, 4.88 us per count,
while a hobby servo's 500-2500 us pulse spans only 180 deg: one count is 0.44 deg (0.88 deg for a joint
mapped over 360 deg). Seed 000's gimbal resolves 0.088 deg (4096 steps per turn), 5-10x finer. The
calibration does not use the gimbal angles (only that the IMU is still at each pose), so this coarser
step changes which poses are reached, not the result; :attr:`Pca9685Gimbal.resolution_deg` gives it to
the pose planner (``PlanModel.resolution_deg``), which predicts a plan's covariance at the reachable angles.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imuslam.interfaces.gimbal import (
    GIMBAL_RESOLUTION_DEG,
    PITCH_LIMITS_DEG,
    ROLL_LIMITS_DEG,
)

FloatArray = NDArray[np.float64]

MODE1, PRESCALE, LED0_ON_L = 0x00, 0xFE, 0x06
SLEEP, AUTO_INCREMENT, RESTART = 0x10, 0x20, 0x80
OSC_HZ = 25_000_000


def prescale_for(freq_hz: float) -> int:
    """PCA9685 PRESCALE register value for a PWM frequency (datasheet eq. 1)."""
    return int(round(OSC_HZ / (4096.0 * freq_hz))) - 1


@dataclass
class ServoSpec:
    """A hobby servo: pulse width (us) at the ends of its range and the angle range (deg)."""

    channel: int
    min_pulse_us: float = 500.0
    max_pulse_us: float = 2500.0
    min_deg: float = -90.0
    max_deg: float = 90.0
    speed_dps: float = 300.0

    def resolution_deg(self, freq_hz: float = 50.0) -> float:
        """Angle of one PCA9685 count (1 / 4096 of the PWM period) for this servo, deg."""
        us_per_count = 1e6 / freq_hz / 4096.0
        return (
            us_per_count * (self.max_deg - self.min_deg) / (self.max_pulse_us - self.min_pulse_us)
        )

    def pulse_us(self, angle_deg: float) -> float:
        a = float(np.clip(angle_deg, self.min_deg, self.max_deg))
        return self.min_pulse_us + (a - self.min_deg) / (self.max_deg - self.min_deg) * (
            self.max_pulse_us - self.min_pulse_us
        )


class Pca9685Gimbal:
    """Two servos on a PCA9685 board at I2C ``address`` of ``bus`` (an smbus2.SMBus or anything with
    ``write_byte_data`` / ``read_byte_data``)."""

    def __init__(
        self,
        roll: ServoSpec,
        pitch: ServoSpec,
        bus: Any = None,
        address: int = 0x40,
        freq_hz: float = 50.0,
    ) -> None:
        if bus is None:
            from smbus2 import SMBus  # optional dependency: pip install imuslam[hw]

            bus = SMBus(1)
        self.bus, self.address, self.freq_hz = bus, address, freq_hz
        self.servos = (roll, pitch)
        self.limits_deg = ((roll.min_deg, roll.max_deg), (pitch.min_deg, pitch.max_deg))
        # where the servos stand at power-up is unknown until the first command
        self._angles: tuple[float, float] | None = None
        old = self.bus.read_byte_data(address, MODE1)
        self.bus.write_byte_data(
            address, MODE1, (old & ~RESTART) | SLEEP
        )  # prescale is writable asleep
        self.bus.write_byte_data(address, PRESCALE, prescale_for(freq_hz))
        self.bus.write_byte_data(address, MODE1, old & ~SLEEP)
        time.sleep(0.0005)  # oscillator start-up, 500 us
        self.bus.write_byte_data(address, MODE1, (old & ~SLEEP) | RESTART | AUTO_INCREMENT)

    def counts(self, pulse_us: float) -> int:
        """12-bit OFF count of a pulse at the configured frequency."""
        period_us = 1e6 / self.freq_hz
        return int(round(pulse_us / period_us * 4096))

    def _set(self, channel: int, off: int) -> None:
        base = LED0_ON_L + 4 * channel
        for reg, val in (
            (base, 0),
            (base + 1, 0),
            (base + 2, off & 0xFF),
            (base + 3, (off >> 8) & 0x0F),
        ):
            self.bus.write_byte_data(self.address, reg, val)

    def move_to(self, angles_deg: tuple[float, float]) -> None:
        for servo, a in zip(self.servos, angles_deg, strict=True):
            self._set(servo.channel, self.counts(servo.pulse_us(a)))
        self._angles = (float(angles_deg[0]), float(angles_deg[1]))

    @property
    def resolution_deg(self) -> float:
        """The coarser joint's angle per PWM count, deg (about 0.44 for a 180 deg servo at 50 Hz)."""
        return max(s.resolution_deg(self.freq_hz) for s in self.servos)

    def angles_deg(self) -> tuple[float, float]:
        return self._angles if self._angles is not None else (0.0, 0.0)

    def settle_time_s(self, target_deg: tuple[float, float]) -> float:
        """Time to reach ``target_deg`` from the last commanded angles; before any command, from the far
        end of each joint's range (the servos' position at power-up is unknown)."""
        if self._angles is None:
            d = max((s.max_deg - s.min_deg) / s.speed_dps for s in self.servos)
        else:
            d = max(
                abs(t - a) / s.speed_dps
                for t, a, s in zip(target_deg, self._angles, self.servos, strict=True)
            )
        return d + 0.3  # mechanical settling after the move


@dataclass
class SimulatedGimbal:
    """A gimbal with a servo's resolution and speed limit; the simulator drives the IMU with its angles."""

    resolution_deg: float = GIMBAL_RESOLUTION_DEG
    speed_dps: float = 90.0
    limits_deg: tuple[tuple[float, float], tuple[float, float]] = (
        ROLL_LIMITS_DEG,
        PITCH_LIMITS_DEG,
    )
    _angles: tuple[float, float] = (0.0, 0.0)
    history: list[tuple[float, float]] = field(default_factory=list)

    def quantise(self, angles_deg: tuple[float, float]) -> tuple[float, float]:
        (r0, r1), (p0, p1) = self.limits_deg
        r = float(np.clip(angles_deg[0], r0, r1))
        p = float(np.clip(angles_deg[1], p0, p1))
        q = self.resolution_deg
        return (round(r / q) * q, round(p / q) * q)

    def move_to(self, angles_deg: tuple[float, float]) -> None:
        self._angles = self.quantise(angles_deg)
        self.history.append(self._angles)

    def angles_deg(self) -> tuple[float, float]:
        return self._angles

    def settle_time_s(self, target_deg: tuple[float, float]) -> float:
        t = self.quantise(target_deg)
        return max(abs(t[0] - self._angles[0]), abs(t[1] - self._angles[1])) / self.speed_dps

    def trajectory(
        self, start_deg: tuple[float, float], target_deg: tuple[float, float], t_s: FloatArray
    ) -> FloatArray:
        """Joint angles (N, 2) at times t_s (from the start of the move) under the speed limit."""
        a, b = np.asarray(self.quantise(start_deg)), np.asarray(self.quantise(target_deg))
        T = max(float(np.max(np.abs(b - a))) / self.speed_dps, 1e-9)
        s = np.clip(np.asarray(t_s) / T, 0.0, 1.0)[:, None]
        return np.round((a + s * (b - a)) / self.resolution_deg) * self.resolution_deg
