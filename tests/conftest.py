"""Shared fixtures: the real recorded data beside the checkout (``../shared/data``)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

# Before any test module imports numpy: the command line's thread defaults (one OpenBLAS thread, passive
# OpenMP waits) then apply to the tests too. With two xdist workers on two cores, a second spinning BLAS
# thread per worker only costs CPU time.
from imuslam.threads import configure_process  # noqa: E402

configure_process()

# Property tests are reproducible: hypothesis derives its examples from each test's name, not from a random
# seed ("derandomize"). HYPOTHESIS_PROFILE=explore draws fresh examples when hunting for new failures.
settings.register_profile("ci", derandomize=True, deadline=None, print_blob=True)
settings.register_profile("explore", deadline=None, print_blob=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Path of ``../shared/data``. In CI it must exist; on a user's fresh clone the test is skipped."""
    if not SHARED_DATA.is_dir():
        if os.environ.get("CI"):
            raise RuntimeError(f"{SHARED_DATA} is missing in CI: the real-data tests cannot run")
        pytest.skip(f"real recorded data not found at {SHARED_DATA}")
    return SHARED_DATA


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--warm-kernels",
        action="store_true",
        help="with pytest-xdist: each worker first compiles one share of numba's kernels "
        "(tests/kernel_warmup.py), so no kernel is compiled by two workers at once (make test)",
    )


@pytest.fixture(scope="session", autouse=True)
def _kernels_compiled_in_shares(request: pytest.FixtureRequest) -> None:
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")  # gw0, gw1, ... in an xdist worker
    if request.config.getoption("--warm-kernels") and worker.startswith("gw"):
        from kernel_warmup import warm_share

        warm_share(int(worker[2:]), int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")))
