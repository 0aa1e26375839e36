"""The in-memory IMU log every reader returns and every estimator consumes."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError

__all__ = ["AccelUnit", "GyroUnit", "ImuLog"]

AccelUnit = Literal["m/s^2", "g", "counts"]
GyroUnit = Literal["rad/s", "deg/s", "counts"]


@dataclass
class ImuLog:
    """A synchronous IMU log.

    t_ns: (N,) int64 sample times, ns, strictly increasing after reading.
    accel: (N, 3) accelerometer samples, sensor frame, in ``accel_unit``.
    gyro: (N, 3) gyroscope samples, sensor frame, in ``gyro_unit``.
    source: where the data came from (a path, a bag and topic), for messages and provenance.
    warnings: what the reader noticed and repaired (re-timed stamps, dropped duplicates), for reports.
    """

    t_ns: NDArray[np.int64]
    accel: NDArray[np.float64]
    gyro: NDArray[np.float64]
    accel_unit: AccelUnit = "m/s^2"
    gyro_unit: GyroUnit = "rad/s"
    source: str = "<memory>"
    warnings: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.t_ns = np.asarray(self.t_ns, dtype=np.int64)
        self.accel = np.asarray(self.accel, dtype=float)
        self.gyro = np.asarray(self.gyro, dtype=float)
        n = self.t_ns.shape[0]
        if self.t_ns.ndim != 1 or self.accel.shape != (n, 3) or self.gyro.shape != (n, 3):
            raise InputError(
                f"{self.source}: expected t_ns (N,), accel (N, 3), gyro (N, 3); got "
                f"{self.t_ns.shape}, {self.accel.shape}, {self.gyro.shape}"
            )

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    @property
    def t_s(self) -> NDArray[np.float64]:
        """(N,) sample times in seconds from the first sample."""
        return (self.t_ns - self.t_ns[0]).astype(float) * 1e-9

    @property
    def rate_hz(self) -> float:
        """Mean sample rate, Hz."""
        if len(self) < 2:
            return float("nan")
        return float((len(self) - 1) / ((self.t_ns[-1] - self.t_ns[0]) * 1e-9))

    def to_si(self) -> ImuLog:
        """The log in m/s^2 and rad/s (from g and deg/s); raw counts need a calibration first."""
        if "counts" in (self.accel_unit, self.gyro_unit):
            raise InputError(
                f"{self.source}: the log is in raw counts; calibrate it first (imuslam calibrate)"
            )
        a = self.accel * (9.80665 if self.accel_unit == "g" else 1.0)
        w = self.gyro * (np.pi / 180.0 if self.gyro_unit == "deg/s" else 1.0)
        return ImuLog(self.t_ns.copy(), a, w, "m/s^2", "rad/s", self.source, list(self.warnings))

    def slice(self, start: int, stop: int) -> ImuLog:
        """Samples ``start:stop`` as a new log sharing units and provenance."""
        return ImuLog(
            self.t_ns[start:stop].copy(),
            self.accel[start:stop].copy(),
            self.gyro[start:stop].copy(),
            self.accel_unit,
            self.gyro_unit,
            self.source,
            list(self.warnings),
        )
