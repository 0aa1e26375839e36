"""Tables parsed in a forked child beside the caller's imports: the same result and errors as in place."""

import os
import sys
from pathlib import Path

import numpy as np
import pytest

from imuslam.errors import InputError
from imuslam.io import text
from imuslam.io.text import cancel_prefetch, prefetch_tables, read_table

pytestmark = pytest.mark.skipif(
    not sys.platform.startswith("linux"), reason="the prefetch forks on Linux only"
)


@pytest.fixture(autouse=True)
def _two_cores(monkeypatch: pytest.MonkeyPatch) -> None:
    # the fork path is taken from two usable cores: exercise it on a one-core runner too
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1})


def _write(path: Path, n: int, seed: int, bad_line: int | None = None) -> np.ndarray:
    rng = np.random.default_rng(seed)
    data = np.column_stack([np.arange(n) * 0.01, rng.normal(33000.0, 50.0, size=(n, 3))])
    rows = [" ".join(f"{v:.7e}" for v in r) for r in data]
    if bad_line is not None:
        rows[bad_line - 1] = rows[bad_line - 1].replace(" ", " x", 1)
    path.write_text("\n".join(rows) + "\n")
    return data


def test_prefetched_tables_equal_the_tables_parsed_in_place(tmp_path: Path) -> None:
    a, g = tmp_path / "acc.mat", tmp_path / "gyro.mat"
    da = _write(a, 30_000, 0)  # about 1.6 MB each, above the prefetch threshold
    dg = _write(g, 30_000, 1)
    assert prefetch_tables([a, g], 4)
    got_g, lines_g = read_table(g, 4)  # read in any order
    got_a, lines_a = read_table(a, 4)
    assert not text._PENDING
    np.testing.assert_allclose(got_a, da, rtol=1e-7)  # 8 significant digits written
    np.testing.assert_allclose(got_g, dg, rtol=1e-7)
    np.testing.assert_array_equal(got_a, read_table(a, 4)[0])  # bit for bit as in place
    np.testing.assert_array_equal(lines_a, np.arange(1, 30_001))
    np.testing.assert_array_equal(lines_g, lines_a)


def test_a_bad_line_gives_the_same_error_as_in_place(tmp_path: Path) -> None:
    a, g = tmp_path / "acc.mat", tmp_path / "gyro.mat"
    _write(a, 30_000, 0, bad_line=20_123)
    _write(g, 30_000, 1)
    with pytest.raises(InputError) as direct:
        read_table(a, 4)
    assert prefetch_tables([a, g], 4)
    with pytest.raises(InputError) as fetched:
        read_table(a, 4)
    assert str(fetched.value) == str(direct.value)
    assert "line 20123" in str(fetched.value)
    assert read_table(g, 4)[0].shape == (30_000, 4)


def test_an_unread_prefetch_is_cancelled_and_its_child_reaped(tmp_path: Path) -> None:
    a, g = tmp_path / "acc.mat", tmp_path / "gyro.mat"
    _write(a, 30_000, 0)
    _write(g, 30_000, 1)
    assert prefetch_tables([a, g], 4)
    pid = next(iter(text._PENDING.values())).pid
    cancel_prefetch()
    assert not text._PENDING
    with pytest.raises(ChildProcessError):  # reaped: no zombie left behind
        os.waitpid(pid, os.WNOHANG)
    assert read_table(a, 4)[0].shape == (30_000, 4)  # parsed in place


def test_small_files_and_other_arguments_are_parsed_in_place(tmp_path: Path) -> None:
    a = tmp_path / "small.mat"
    _write(a, 100, 0)
    assert not prefetch_tables([a], 4)
    big = tmp_path / "big.mat"
    _write(big, 30_000, 2)
    assert prefetch_tables([big], 4)
    # another column count is another request: parsed here, the prefetch stays pending
    with pytest.raises(InputError, match="expected 7"):
        read_table(big, 7)
    assert text._PENDING
    cancel_prefetch()
