"""Operations shared by SE(2) and SE(3) on homogeneous matrices (..., n+1, n+1): compose, inverse,
between, act. :mod:`se2` and :mod:`se3` re-export them."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

__all__ = ["act", "between", "compose", "inverse"]


def compose(T_a_b: ArrayLike, T_b_c: ArrayLike) -> FloatArray:
    """``T_a_c = T_a_b T_b_c``."""
    return np.asarray(T_a_b, dtype=float) @ np.asarray(T_b_c, dtype=float)


def inverse(T_a_b: ArrayLike) -> FloatArray:
    """``T_b_a`` = [R^T, -R^T t] (no general matrix inverse)."""
    T = np.asarray(T_a_b, dtype=float)
    n = T.shape[-1] - 1
    Rt = np.swapaxes(T[..., :n, :n], -1, -2)
    out = np.zeros(T.shape)
    out[..., :n, :n] = Rt
    out[..., :n, n] = -np.einsum("...ij,...j->...i", Rt, T[..., :n, n])
    out[..., n, n] = 1.0
    return out


def between(T_w_a: ArrayLike, T_w_b: ArrayLike) -> FloatArray:
    """``T_a_b = T_w_a^-1 T_w_b``: the pose of b seen from a."""
    return compose(inverse(T_w_a), T_w_b)


def act(T_a_b: ArrayLike, p_b: ArrayLike) -> FloatArray:
    """Points (..., n) in b mapped into a: ``p_a = R p_b + t``. A single T with (N, n) points works."""
    T = np.asarray(T_a_b, dtype=float)
    p = np.asarray(p_b, dtype=float)
    n = T.shape[-1] - 1
    if T.ndim == 2:
        return p @ T[:n, :n].T + T[:n, n]
    return np.einsum("...ij,...j->...i", T[..., :n, :n], p) + T[..., :n, n]
