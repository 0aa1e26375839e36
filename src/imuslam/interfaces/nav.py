"""Navigation state and IMU bias: what an inertial estimator carries from one step to the next."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

__all__ = ["ImuBias", "NavState"]


@dataclass
class NavState:
    """Position p_n (3,) m, velocity v_n (3,) m/s in the navigation frame n, attitude R_n_b (3, 3)."""

    p_n: FloatArray
    v_n: FloatArray
    R_n_b: FloatArray

    def copy(self) -> NavState:
        return NavState(self.p_n.copy(), self.v_n.copy(), self.R_n_b.copy())


@dataclass
class ImuBias:
    """Additive IMU biases, measured = true + bias: accel_b (3,) m/s^2, gyro_b (3,) rad/s."""

    accel_b: FloatArray = field(default_factory=lambda: np.zeros(3))
    gyro_b: FloatArray = field(default_factory=lambda: np.zeros(3))
