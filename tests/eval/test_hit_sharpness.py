"""The grid-free map score (``eval.mapquality.hit_sharpness``) against hits placed at known distances
from the walls of seed 000's 8 m room."""

from __future__ import annotations

import numpy as np

from imuslam.eval.mapquality import hit_sharpness
from imuslam.sim.world import room_8x8

HEIGHT = 1.5  # above the room's boxes (at most 1.2 m): only the four walls are near


def _wall_hits(offsets: np.ndarray) -> np.ndarray:
    """Hits on the inner face of the wall at y = +4 m (x in [-3, 3]) moved by ``offsets`` across it."""
    x = np.linspace(-3.0, 3.0, len(offsets))
    return np.column_stack([x, 4.0 + offsets])


def test_hits_on_the_walls_score_zero_and_an_offset_scores_itself() -> None:
    world = room_8x8()
    on = hit_sharpness(_wall_hits(np.zeros(200)), world, HEIGHT)
    assert on.rms_m < 1e-12 and on.hits == 200
    inside = hit_sharpness(_wall_hits(np.full(200, -0.03)), world, HEIGHT)  # 3 cm into the room
    assert abs(inside.rms_m - 0.03) < 1e-12


def test_wall_width_is_the_5_to_95_spread_of_the_hits() -> None:
    """Hits spread uniformly over +-w across the wall (inside the room only: -w..0, so that the distance
    to the wall is the offset): their 5-95 % width is 0.9 w, and their RMS distance w / sqrt(3)."""
    w = 0.06
    rng = np.random.default_rng(0)
    off = -rng.uniform(0.0, w, 20000)
    q = hit_sharpness(_wall_hits(off), room_8x8(), HEIGHT)
    n = len(off)
    # 3 sigma of the sampling error: a uniform quantile's is w sqrt(p (1 - p) / n), the width holds two;
    # the mean square's is w^2 sqrt(4 / 45) / sqrt(n), halved relative to the RMS
    tol_width = 3 * np.sqrt(2) * w * np.sqrt(0.05 * 0.95 / n)
    tol_rms = 3 * w**2 * np.sqrt(4 / 45) / np.sqrt(n) / (2 * w / np.sqrt(3))
    assert abs(q.wall_width_m - 0.9 * w) < tol_width
    assert abs(q.rms_m - w / np.sqrt(3)) < tol_rms
