"""The room map the matcher tests search in (built once per module)."""

from __future__ import annotations

import numpy as np
import pytest
from slam2d_helpers import _map_from

from imuslam.slam2d.grid import ProbabilityGrid


@pytest.fixture(scope="module")
def room_grid() -> ProbabilityGrid:
    rng = np.random.default_rng(1)
    return _map_from(
        [np.array([0.0, 0.0, 0.0]), np.array([1.0, -0.5, 0.6]), np.array([-1.2, 0.8, -1.0])], rng
    )
