"""Measurements that linearise themselves at a state, and the chi-square gate of the updates."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from imuslam.ins.state import ErrorLayout, InsState

FloatArray = NDArray[np.float64]


@functools.lru_cache(maxsize=256)
def chi2_threshold(prob: float, dof: int) -> float:
    """The chi-square quantile: P(chi2_dof <= threshold) = prob (2 * gammaincinv(dof / 2, prob)).
    Cached: a filter gates every update with the same few (prob, dof) pairs."""
    from scipy.special import gammaincinv

    if not 0.0 < prob < 1.0:
        raise ValueError(f"gate probability must be in (0, 1), got {prob}")
    return float(2.0 * gammaincinv(0.5 * dof, prob))


def gate(
    r: FloatArray, H: FloatArray, R: FloatArray, P: FloatArray, prob: float
) -> tuple[bool, float]:
    """Chi-square gate: the normalised innovation squared nis = r^T (H P H^T + R)^-1 r against the
    ``prob`` quantile of chi2 with len(r) degrees of freedom. Returns (accepted, nis)."""
    S = H @ P @ H.T + R
    nis = float(r @ np.linalg.solve(S, r))
    return bool(nis <= chi2_threshold(prob, len(r))), nis


class Measurement(Protocol):
    """A measurement that linearises itself at a state (pyins' ``Measurement.compute_matrices``):
    innovation r = z - h(x) (k,), Jacobian H = dh/d(dx) (k, m) in the layout's error state, noise R
    (k, k). ``kind`` names the model (the strong tracking filter keeps one innovation covariance per
    kind)."""

    kind: str

    def linearize(
        self, x: InsState, layout: ErrorLayout
    ) -> tuple[FloatArray, FloatArray, FloatArray]: ...


_BLOCK_STATE = {"P": "p_n", "V": "v_n", "BA": "accel_bias", "BG": "gyro_bias", "G": "g_n"}


@dataclass
class BlockMeasurement:
    """A direct measurement of one 3-vector block of the state (``block``: P, V, BA, BG or G) with
    1-sigma ``std`` per axis: r = value - x_block, H = [0 .. I .. 0]."""

    value: FloatArray
    std: float
    kind: str
    block: str

    def linearize(
        self, x: InsState, layout: ErrorLayout
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        H = np.zeros((3, layout.dim))
        H[:, getattr(layout, self.block)] = np.eye(3)
        r = np.asarray(self.value, float) - getattr(x, _BLOCK_STATE[self.block])
        return r, H, np.eye(3) * self.std**2


class PositionMeasurement(BlockMeasurement):
    """Position in n, m."""

    def __init__(self, p_n: FloatArray, std: float) -> None:
        super().__init__(p_n, std, "position", "P")


class VelocityMeasurement(BlockMeasurement):
    """Velocity in n, m/s (zeros: a zero-velocity update)."""

    def __init__(self, v_n: FloatArray, std: float) -> None:
        super().__init__(v_n, std, "velocity", "V")


class ZeroAngularRate(BlockMeasurement):
    """On a still base the mean raw rate (3,) over a block is the gyro bias (earth rate neglected)."""

    def __init__(self, gyro_mean: FloatArray, std: float) -> None:
        super().__init__(gyro_mean, std, "zaru", "BG")


@dataclass
class UpdateResult:
    """What an update did: accepted by the gate, its nis (normalised innovation squared), the innovation
    r at the prior, the correction dx applied (zeros when rejected), and the iterations (1 for a plain
    update)."""

    accepted: bool
    nis: float
    r: FloatArray
    dx: FloatArray
    iterations: int = 1
