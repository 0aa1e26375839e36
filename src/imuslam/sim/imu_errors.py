"""The forward IMU error model for simulation: true (orthogonal, corrected) values -> raw sensor output.

The correction model (MISSION.md part A; Tedaldi et al., ICRA 2014, eqs. 1-6) is
``x_O = T K (x_S + b)`` (``bias_sign="plus"``, the seed's convention) or ``x_O = T K (x_S - b)``
(``"minus"``, imu_tk's). Its inverse gives the raw output a simulated sensor reports:
``x_S = (T K)^-1 x_O - b`` or ``+ b``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]
BiasSign = Literal["plus", "minus"]


@dataclass(frozen=True)
class TriadErrors:
    """Errors of one sensor triad in the correction model ``x_O = T K (x_S ± b)``.

    T: (3, 3) misalignment, K: (3,) scale factors, b: (3,) bias in raw units.
    """

    T: FloatArray
    K: FloatArray
    b: FloatArray
    bias_sign: BiasSign = "plus"


# Seed 000, table 2 (WitMotion BWT901CL on a 2-axis gimbal), correction model T K (x + b).
# T_a is upper triangular (body frame = orthogonalised accelerometer frame).
SEED000_ACCEL = TriadErrors(
    T=np.array([[1.0, -0.000609969, 0.00265592], [0.0, 1.0, 0.000762083], [0.0, 0.0, 1.0]]),
    K=np.array([1.00244, 1.00253, 1.00135]),
    b=np.array([-0.136491, 0.041374, -0.023922]),
)
SEED000_GYRO = TriadErrors(
    T=np.array(
        [[1.0, 0.0645335, 0.0378812], [-0.0617748, 1.0, 0.0264526], [0.0673617, 0.0892894, 1.0]]
    ),
    K=np.array([1.00632, 1.03577, 1.01391]),
    b=np.array([-0.028206, -0.051448, -0.010394]),
)

# BWT901CL-class noise. The module is built on an InvenSense MPU-9250, whose datasheet gives an
# accelerometer noise density of 300 ug/sqrt(Hz) and a gyro noise density of 0.01 dps/sqrt(Hz); the
# discrete standard deviation at rate f is density * sqrt(f). Output LSBs: 16 g / 32768 and
# 2000 dps / 32768 (WitMotion protocol scale factors).
BWT901CL_ACCEL_DENSITY = 300e-6 * 9.80665  # m/s^2/sqrt(Hz)
BWT901CL_GYRO_DENSITY = np.deg2rad(0.01)  # rad/s/sqrt(Hz)
BWT901CL_ACCEL_LSB = 16.0 * 9.80665 / 32768.0  # m/s^2
BWT901CL_GYRO_LSB = np.deg2rad(2000.0 / 32768.0)  # rad/s
BWT901CL_ACCEL_RANGE = 16.0 * 9.80665  # m/s^2
BWT901CL_GYRO_RANGE = np.deg2rad(2000.0)  # rad/s


def raw_from_true(
    true_o: ArrayLike,
    T: ArrayLike,
    K: ArrayLike,
    b: ArrayLike,
    bias_sign: BiasSign = "plus",
) -> FloatArray:
    """Raw output ``x_S`` (N, 3) of a triad whose corrected (true) value is ``true_o`` (N, 3).

    Inverse of ``x_O = T diag(K) (x_S ± b)``; ``b`` may be (3,) or (N, 3) (a time-varying bias).
    """
    M = np.asarray(T, dtype=float) @ np.diag(np.asarray(K, dtype=float))
    x = np.linalg.solve(M, np.asarray(true_o, dtype=float).T).T
    bias = np.asarray(b, dtype=float)
    return x - bias if bias_sign == "plus" else x + bias


def raw_from_errors(true_o: ArrayLike, errors: TriadErrors) -> FloatArray:
    """:func:`raw_from_true` with the parameters of a :class:`TriadErrors`."""
    return raw_from_true(true_o, errors.T, errors.K, errors.b, errors.bias_sign)


def add_sensor_noise(
    raw: ArrayLike,
    rng: np.random.Generator,
    white_std: float | ArrayLike,
    quant_step: float | None = None,
    saturation: float | None = None,
) -> FloatArray:
    """White Gaussian noise (std per axis), then saturation at ``±saturation`` and quantisation.

    raw: (N, 3) raw samples; returns a new (N, 3) array in the same units.
    """
    x = np.asarray(raw, dtype=float)
    out = x + rng.normal(size=x.shape) * np.asarray(white_std, dtype=float)
    if saturation is not None:
        out = np.clip(out, -saturation, saturation)
    if quant_step is not None and quant_step > 0:
        out = np.round(out / quant_step) * quant_step
    return out
