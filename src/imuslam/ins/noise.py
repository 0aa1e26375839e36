"""The inertial sensor's noise densities the filters propagate."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.io.yamlfile import read_yaml

FloatArray = NDArray[np.float64]


@dataclass
class KfNoise:
    """Continuous noise densities: accel (m/s^2/sqrt(Hz)), gyro (rad/s/sqrt(Hz)), bias random walks."""

    accel: float = 3e-3
    gyro: float = 2e-4
    accel_bias_rw: float = 1e-4
    gyro_bias_rw: float = 2e-5

    def __post_init__(self) -> None:
        for name in ("accel", "gyro", "accel_bias_rw", "gyro_bias_rw"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise InputError(f"noise '{name}' must be a positive number, got {v}")

    @property
    def q(self) -> FloatArray:
        """[accel^2, gyro^2, accel_bias_rw^2, gyro_bias_rw^2] for :func:`propagate_covariance`."""
        return np.array([self.accel**2, self.gyro**2, self.accel_bias_rw**2, self.gyro_bias_rw**2])

    @classmethod
    def from_kalibr_yaml(cls, path: str | Path) -> KfNoise:
        """Read a Kalibr ``imu.yaml`` (as ``imuslam allan`` writes): the four noise fields."""
        p = Path(path)
        if not p.is_file():
            raise InputError(f"{p}: no such noise file")
        d = read_yaml(p, "a Kalibr imu.yaml (noise densities and random walks)")
        keys = ("accelerometer_noise_density", "gyroscope_noise_density", "accelerometer_random_walk",
                "gyroscope_random_walk")  # fmt: skip
        vals = []
        for k in keys:
            v = d.get(k) if isinstance(d, dict) else None
            if not isinstance(v, (int, float)) or isinstance(v, bool):
                raise InputError(f"{p}: field '{k}' must be a number (Kalibr imu.yaml), got {v!r}")
            vals.append(float(v))
        try:
            return cls(*vals)
        except InputError as e:
            raise InputError(f"{p}: {e}") from None

    @classmethod
    def from_log(cls, accel: FloatArray, gyro: FloatArray, rate_hz: float,
                 floor: KfNoise | None = None) -> KfNoise:  # fmt: skip
        """White-noise densities as the log shows them, vibration included, never below ``floor``.

        The Allan variance at the shortest cluster time tau0 = 1 / rate is E[(x[k+1] - x[k])^2] / 2, and
        for white noise of density N it equals N^2 / tau0 (IEEE Std 952-1997, annex C), so
        N = std(diff x) / sqrt(2 rate). On a moving robot this sees the vibration that a bench Allan
        analysis does not (EuRoC's MAV: 0.04-0.10 m/s^2/sqrt(Hz) against the ADIS16448's 0.002), plus the
        signal's own change between samples, which is small at IMU rates. Axes are combined as RMS; the
        random walks cannot be seen in a short log and come from ``floor``.
        """
        fl = floor or cls()
        a = np.asarray(accel, float)
        w = np.asarray(gyro, float)
        if a.ndim != 2 or a.shape[1] != 3 or a.shape != w.shape:
            raise ValueError(
                f"noise estimate needs (N, 3) accel and gyro, got {a.shape} and {w.shape}"
            )
        if len(a) < 3:
            raise InputError(f"noise estimate needs at least 3 samples, got {len(a)}")
        if not (np.isfinite(rate_hz) and rate_hz > 0):
            raise InputError(f"noise estimate needs a positive sample rate, got {rate_hz}")

        def density(x: FloatArray) -> float:
            return float(np.sqrt(np.mean(np.var(np.diff(x, axis=0), axis=0)) / (2.0 * rate_hz)))

        return cls(
            max(density(a), fl.accel), max(density(w), fl.gyro), fl.accel_bias_rw, fl.gyro_bias_rw
        )
