"""Poses over time: the one trajectory record every reader returns and every evaluator reads."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imuslam.errors import InputError
from imuslam.geometry import quat_from_matrix, quat_to_matrix

FloatArray = NDArray[np.float64]

__all__ = ["Trajectory"]


@dataclass
class Trajectory:
    """Poses of a body b in a world w over time.

    t_ns: (N,) int64 stamps, ns. p_w: (N, 3) positions, m. R_w_b: (N, 3, 3) rotations mapping body
    vectors into the world; ``quat_wxyz`` (N, 4) gives the same attitudes as Hamilton quaternions, and
    :meth:`from_quat` builds a trajectory from them.
    """

    t_ns: NDArray[np.int64]
    p_w: FloatArray
    R_w_b: FloatArray
    source: str = "<memory>"

    def __post_init__(self) -> None:
        self.t_ns = np.asarray(self.t_ns, dtype=np.int64)
        self.p_w = np.asarray(self.p_w, dtype=float)
        self.R_w_b = np.asarray(self.R_w_b, dtype=float)
        n = len(self.t_ns)
        if self.p_w.shape != (n, 3) or self.R_w_b.shape != (n, 3, 3):
            raise InputError(
                f"{self.source}: expected N times, (N, 3) positions and (N, 3, 3) rotations"
            )
        bad = ~(np.isfinite(self.p_w).all(axis=1) & np.isfinite(self.R_w_b).all(axis=(1, 2)))
        if bad.any():
            raise InputError(f"{self.source}: pose {int(np.argmax(bad))} is NaN or infinite")

    @classmethod
    def from_quat(
        cls, t_ns: ArrayLike, p_w: ArrayLike, quat_wxyz: ArrayLike, source: str = "<memory>"
    ) -> Trajectory:
        """From stamps (N,) ns, positions (N, 3) m and Hamilton quaternions (N, 4) w x y z."""
        q = np.asarray(quat_wxyz, dtype=float)
        if q.ndim != 2 or q.shape[1] != 4:
            raise ValueError(f"{source}: expected (N, 4) quaternions w x y z, got {q.shape}")
        return cls(np.asarray(t_ns), np.asarray(p_w, dtype=float), quat_to_matrix(q), source)

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    @property
    def t_s(self) -> FloatArray:
        """(N,) times in seconds (absolute); whole and fractional seconds are added last, which gives
        the same double as parsing the decimal stamp of a text file."""
        whole = self.t_ns // 1_000_000_000
        return (
            whole.astype(np.float64) + (self.t_ns - whole * 1_000_000_000).astype(np.float64) * 1e-9
        )

    @property
    def quat_wxyz(self) -> FloatArray:
        """(N, 4) Hamilton quaternions w x y z of ``R_w_b``."""
        return quat_from_matrix(self.R_w_b)

    def subset(self, idx: NDArray[np.int64]) -> Trajectory:
        return Trajectory(self.t_ns[idx], self.p_w[idx], self.R_w_b[idx], self.source)

    def of_mounted_frame(self, T_b_f: NDArray[np.float64]) -> Trajectory:
        """The trajectory of a frame ``f`` rigidly mounted at ``T_b_f`` (4, 4) on this trajectory's body:
        ``R_w_f = R_w_b R_b_f``, ``p_w_f = p_w + R_w_b p_b_f`` (e.g. the LiDAR's from the IMU's and
        ``T_i_l``)."""
        T = np.asarray(T_b_f, dtype=np.float64)
        return Trajectory(
            self.t_ns, self.p_w + self.R_w_b @ T[:3, 3], self.R_w_b @ T[:3, :3], self.source
        )

    @property
    def path_length(self) -> float:
        """Length of the path through the positions, m."""
        return float(np.sum(np.linalg.norm(np.diff(self.p_w, axis=0), axis=1)))
