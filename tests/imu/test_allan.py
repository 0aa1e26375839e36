"""Allan deviation against allantools, and the noise terms against synthetic truth and a real MPU6050."""

from pathlib import Path

import allantools
import numpy as np
import pytest

from imuslam.errors import InputError
from imuslam.imu.allan import (
    _oavar_kernel,
    allan,
    cluster_sizes,
    fit_noise_terms,
    overlapped_adev,
)
from imuslam.interfaces.imu import ImuLog
from imuslam.io.matlab import read_mat_buffers


def test_equals_allantools_oadev() -> None:
    rng = np.random.default_rng(0)
    y = rng.normal(size=20_000) + np.cumsum(rng.normal(size=20_000)) * 0.01
    ms = cluster_sizes(len(y), 60)
    taus, ad, mm = overlapped_adev(y, 100.0, ms)
    t2, ad2, _, _ = allantools.oadev(y, rate=100.0, data_type="freq", taus=taus)
    np.testing.assert_array_equal(np.round(t2 * 100).astype(np.int64), mm)
    np.testing.assert_allclose(ad, ad2, rtol=1e-9)


def _oavar_reference(x: np.ndarray, m: int) -> np.ndarray:
    """The sum of SP 1065 eq. 11 written out with numpy slices, one tau at a time (the slow reference)."""
    d = x[2 * m :] - 2.0 * x[m:-m] + x[: -2 * m]
    return np.sum(d * d, axis=0)


@pytest.mark.parametrize("block", [1, 7, 64, 8192])
def test_blocked_kernel_equals_reference(block: int) -> None:
    """Blocks smaller and larger than the log, a log that is not a multiple of the block, unsorted and
    repeated cluster sizes, three axes of different scale: each sum equals the numpy one to rounding
    (reassociated sums of ~1e3 positive terms: relative 1e-12 is 1e4 ulp)."""
    rng = np.random.default_rng(4)
    y = rng.normal(size=(1001, 3)) * np.array([1.0, 1e-3, 1e3]) + np.array([5.0, -2.0, 0.0])
    x = np.vstack([np.zeros((1, 3)), np.cumsum(y - y.mean(axis=0), axis=0)])
    ms = np.array([3, 1, 500, 250, 3, 17, 64, 499], dtype=np.int64)
    got = _oavar_kernel(np.ascontiguousarray(x.T), ms, block)
    want = np.stack([_oavar_reference(x, int(m)) for m in ms])
    np.testing.assert_allclose(got, want, rtol=1e-12)


def test_axes_analysed_together_equal_one_at_a_time() -> None:
    rng = np.random.default_rng(5)
    y = rng.normal(size=(30_000, 2)) + np.cumsum(rng.normal(size=(30_000, 2)), axis=0) * 1e-2
    taus, ad, _ = overlapped_adev(y, 200.0)
    for a in range(2):
        _, ad1, _ = overlapped_adev(y[:, a], 200.0)
        np.testing.assert_allclose(ad[:, a], ad1, rtol=1e-12)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_white_noise_and_random_walk_recovered(seed: int) -> None:
    """N = 2e-3 /sqrt(Hz), K = 5e-4 sqrt(Hz) at 100 Hz for 2e6 samples (5.6 h). The crossover sits at
    tau = sqrt(3) N / K = 7 s; K is read over tau up to ~5e3 s (>= 4 clusters), whose scatter in
    simulation is ~3 % (1 sigma), so 10 % holds with > 3 sigma margin; N is known to ~0.1 %."""
    fs, N, K, n = 100.0, 2e-3, 5e-4, 2_000_000
    rng = np.random.default_rng(seed)
    y = N * np.sqrt(fs) * rng.normal(size=n) + np.cumsum(K / np.sqrt(fs) * rng.normal(size=n))
    taus, ad, _ = overlapped_adev(y, fs)
    terms = fit_noise_terms(taus, ad, n, fs)
    assert terms.white == pytest.approx(N, rel=0.01)
    assert terms.random_walk is not None and terms.random_walk == pytest.approx(K, rel=0.10)


def test_real_mpu6050_static_log(shared_data: Path) -> None:
    """A 10-minute static MPU6050 log (g, deg/s, jittery ~99 Hz), analysed with no tuning.

    Datasheet densities: accelerometer 400 ug/sqrt(Hz), gyro 0.005 dps/sqrt(Hz). This unit measures
    300-500 ug/sqrt(Hz) and about 0.01 dps/sqrt(Hz); the test keeps each axis within a factor 3 of the
    datasheet (a consumer part's spread) and checks the unit conversion: g would be 9.8x too small.
    """
    d = (
        shared_data
        / "sunsided_mpu6050_hmc5883l"
        / "set-2"
        / "unmoved-with-x-pointing-forward-10min"
    )
    log = read_mat_buffers(d / "mpu6050_accelerometer.mat", d / "mpu6050_gyroscope.mat")
    res = allan(log)
    acc_ug = np.array([t.white for t in res.accel_terms]) / 9.80665 * 1e6
    gyr_dps = np.rad2deg([t.white for t in res.gyro_terms])
    assert np.all((acc_ug > 400 / 3) & (acc_ug < 400 * 3))
    assert np.all((gyr_dps > 0.005 / 3) & (gyr_dps < 0.005 * 3))
    assert any("vary" in w for w in res.warnings)  # the jittery sampling is reported
    k = res.kalibr()
    # the mean rate from the file's own stamps, read here with h5py: (N - 1) / (t_N - t_1)
    import h5py

    with h5py.File(d / "mpu6050_accelerometer.mat", "r") as h:
        t_file = np.asarray(h["accelBuffer"])[0]
    assert k["update_rate"] == pytest.approx((len(t_file) - 1) / (t_file[-1] - t_file[0]), abs=1e-3)
    print(f"MPU6050 white noise: accel {np.round(acc_ug).astype(int)} ug/sqrt(Hz), gyro "
          f"{np.round(gyr_dps, 4)} deg/s/sqrt(Hz)")  # fmt: skip
    assert k["gyroscope_noise_density"] == pytest.approx(float(np.deg2rad(gyr_dps.max())))


def test_too_short_is_an_error() -> None:
    log = ImuLog(
        np.arange(100) * 10_000_000, np.zeros((100, 3)), np.zeros((100, 3)), source="short.csv"
    )
    with pytest.raises(InputError, match="short.csv"):
        allan(log)


@pytest.mark.slow  # Monte Carlo over seeds
def test_random_walk_uncertainty_matches_its_spread() -> None:
    """White noise + rate random walk, logs of 2e5 samples: the spread of the fitted K over 100 seeded logs
    (known to ~7 %) against the 1-sigma the analysis reports for 5 of them (its parametric bootstrap, 5 x 40
    replicas: ~5 %), so their ratio is known to sqrt(7^2 + 5^2) = 8.6 %: an honest 1-sigma gives a ratio
    within 1 +- 3 x 0.086 = [0.74, 1.26]. (The least-squares covariance alone gives 2.6.) The ratio is
    printed (pytest -s)."""
    fs, N, K, n = 100.0, 2e-3, 2e-3, 200_000
    ks, rels = [], []
    for seed in range(100):
        rng = np.random.default_rng(100 + seed)
        y = N * np.sqrt(fs) * rng.normal(size=n) + np.cumsum(K / np.sqrt(fs) * rng.normal(size=n))
        taus, ad, _ = overlapped_adev(y, fs)
        terms = fit_noise_terms(taus, ad, n, fs, bootstrap=40 if seed < 5 else 0)
        assert terms.random_walk is not None and terms.random_walk_rel_std is not None
        ks.append(terms.random_walk)
        if seed < 5:
            rels.append(terms.random_walk_rel_std)
    ratio = (np.std(ks, ddof=1) / K) / np.mean(rels)
    print(f"K: spread over 100 logs {np.std(ks, ddof=1) / K:.3f}, reported 1-sigma {np.mean(rels):.3f}, "
          f"ratio {ratio:.2f}")  # fmt: skip
    assert 1 - 3 * 0.086 < ratio < 1 + 3 * 0.086
