"""Checks of poses read from any file (trajectory text, a bag's pose topic): time stamps that go forward,
positions that are finite and near the earth, unit quaternions; each failure an InputError naming the line
or pose."""

from __future__ import annotations

import logging

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.geometry import quat_to_matrix

FloatArray = NDArray[np.float64]
log = logging.getLogger(__name__)


def check_times(
    t_ns: NDArray[np.int64],
    source: str,
    lines: NDArray[np.int64] | None = None,
    max_repeat_frac: float = 0.01,
) -> None:
    """InputError naming the line (or pose) where time goes backwards, or where it first repeats when
    more than ``max_repeat_frac`` of the stamps repeat one before. A few repeats are real (motion-capture
    stamps rounded to 0.1 ms: one in TUM's fr2_desk ground truth, four in evo's V102 estimate) and are
    kept with a warning, as evo keeps them; many mean the file is broken and association would pair
    the wrong poses."""
    d = np.diff(t_ns)
    at = (lambda i: f"line {int(lines[i])}") if lines is not None else (lambda i: f"pose {i}")
    back = np.flatnonzero(d < 0)
    if back.size:
        i = int(back[0]) + 1
        raise InputError(
            f"{source}, {at(i)}: time goes backwards ({t_ns[i]} ns after {t_ns[i - 1]} ns); expected "
            "increasing time stamps"
        )
    rep = np.flatnonzero(d == 0)
    if rep.size > max_repeat_frac * len(t_ns):
        i = int(rep[0]) + 1
        raise InputError(
            f"{source}, {at(i)}: time repeats ({t_ns[i]} ns), and {rep.size - 1} more times; expected "
            "increasing time stamps"
        )
    if rep.size:
        log.warning(
            "%s: %d repeated time stamp(s), the first at %s", source, rep.size, at(int(rep[0]) + 1)
        )


#: Farther than any robot's map (earth-centred coordinates are 6.4e6 m): a larger position is corrupted.
MAX_ABS_POSITION_M = 1e8


def check_poses(
    p_w: FloatArray, q_wxyz: FloatArray, source: str, lines: NDArray[np.int64] | None = None
) -> tuple[FloatArray, FloatArray]:
    """Positions and rotation matrices; an absurd position or a quaternion that is not a unit one
    (norm off by more than 10 %, as a corrupted field makes it) is an InputError naming the line."""
    at = (lambda i: f"line {int(lines[i])}") if lines is not None else (lambda i: f"pose {i}")
    far = ~(np.abs(p_w) <= MAX_ABS_POSITION_M).all(axis=1)
    if far.any():
        i = int(np.argmax(far))
        raise InputError(
            f"{source}, {at(i)}: position {p_w[i].tolist()} m is not finite or beyond "
            f"{MAX_ABS_POSITION_M:g} m"
        )
    with np.errstate(over="ignore", invalid="ignore"):  # a corrupted 1e308 is reported below
        n = np.linalg.norm(q_wxyz, axis=1)
    bad = ~(np.abs(n - 1.0) <= 0.1)
    if bad.any():
        i = int(np.argmax(bad))
        raise InputError(
            f"{source}, {at(i)}: the quaternion has norm {n[i]:g}; expected a unit quaternion"
        )
    return p_w, quat_to_matrix(q_wxyz / n[:, None])
