"""The grid neighbour search and the batched map sharpness against cKDTree's ball query and a loop of
np.cov over its neighbourhoods (the definition)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from imuslam.eval.mapquality import BallNeighbours, point_map_quality


def _reference(
    p: np.ndarray, q: np.ndarray, r: float, min_points: int = 10
) -> tuple[float, float, int]:
    """(mean map entropy, mean plane variance, queries) by cKDTree and np.cov, one query at a time."""
    ent, lam = [], []
    for nb in cKDTree(p).query_ball_point(q, r, workers=1):
        if len(nb) < min_points:
            continue
        ev = np.linalg.eigvalsh(np.cov(p[nb], rowvar=False))
        if ev[0] <= 0:
            continue
        ent.append(0.5 * (p.shape[1] * np.log(2 * np.pi * np.e) + np.sum(np.log(ev))))
        lam.append(ev[0])
    return float(np.mean(ent)), float(np.mean(lam)), len(lam)


@pytest.mark.parametrize("dim", [2, 3])
def test_ball_neighbours_are_cKDTrees(dim: int) -> None:
    rng = np.random.default_rng(4)
    p = rng.uniform(-3.0, 3.0, (4000, dim))
    p[:50] = np.round(p[:50], 1)  # points on cell borders and at exactly the radius of a query
    q = np.concatenate([p[:300], rng.uniform(-5.0, 5.0, (200, dim))])
    q[300] = 100.0  # far outside the grid
    start, idx = BallNeighbours(p, 0.3).query(q)
    ref = cKDTree(p).query_ball_point(q, 0.3, workers=1)
    assert len(start) == len(q) + 1
    for j, nb in enumerate(ref):
        assert np.array_equal(idx[start[j] : start[j + 1]], np.asarray(nb, np.int64)), j
    assert start[301] == start[300]  # the query far outside has none
    with pytest.raises(ValueError, match="finite"):
        BallNeighbours(p, 0.3).query(np.full((1, dim), np.nan))


@pytest.mark.parametrize("dim", [2, 3])
def test_point_map_quality_is_the_np_cov_loop(dim: int) -> None:
    rng = np.random.default_rng(5)
    n = 6000
    p = rng.uniform(0.0, 4.0, (n, dim))
    p[:, -1] = 0.02 * rng.normal(size=n) + (p[:, 0] > 2.0)  # two walls (planes in 3D)
    p[:20] = p[20]  # a neighbourhood of one point repeated: no spread
    q = p[rng.choice(n, 700, replace=False)]
    got = point_map_quality(p, 0.25, queries=q)
    ent, lam, nq = _reference(p, q, 0.25)
    assert got.queries == nq and got.points == n
    assert got.map_entropy == pytest.approx(ent, rel=1e-12)
    assert got.plane_variance_m2 == pytest.approx(lam, rel=1e-12)
    # a radius far below the spacing of points: no neighbourhood has enough points
    assert np.isnan(point_map_quality(p, 1e-6).map_entropy)
