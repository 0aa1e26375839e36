"""Shared fixtures: the real recorded data beside the checkout (``../shared/data``)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Path of ``../shared/data``. In CI it must exist; on a user's fresh clone the test is skipped."""
    if not SHARED_DATA.is_dir():
        if os.environ.get("CI"):
            raise RuntimeError(f"{SHARED_DATA} is missing in CI: the real-data tests cannot run")
        pytest.skip(f"real recorded data not found at {SHARED_DATA}")
    return SHARED_DATA
