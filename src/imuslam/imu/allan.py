"""Overlapped Allan deviation and the IEEE-952 noise terms read off its log-log plot.

Overlapped Allan variance of rate samples y (N, at rate f, tau0 = 1 / f) through the integrated signal
x_k = tau0 * sum_{i<k} y_i (Riley, "Handbook of Frequency Stability Analysis", NIST SP 1065, eq. 11):

    sigma^2(m tau0) = sum_{k=0}^{N-2m} (x_{k+2m} - 2 x_{k+m} + x_k)^2 / (2 (m tau0)^2 (N + 1 - 2m))

Noise terms (IEEE Std 952-1997, annex C): white noise (angle / velocity random walk) N from the
slope -1/2 line, sigma = N / sqrt(tau), read at tau = 1 s; bias instability B = min sigma / 0.664;
rate random walk K from the slope +1/2 line, sigma = K sqrt(tau / 3), read at tau = 3 s.
Confidence: the relative 1-sigma of an overlapped Allan deviation with n = N / m clusters is about
1 / sqrt(2 (n - 1)) (Riley, SP 1065, eq. 34 for white noise, used as the working approximation here).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.interfaces.imu import ImuLog

FloatArray = NDArray[np.float64]


# Samples of x per block: the blocks are the parallel work items, and one block's x[k0 : k0 + B] (64 KiB), with the slices that the
# short taus read beside it, stays in the L1 / L2 cache while every tau reads it, instead of x streaming
# from memory once per tau (bench/allan.py: 1e7 samples, 100 taus).
BLOCK = 8192


@numba.njit(fastmath={"reassoc", "contract"}, inline="always")
def _block_sum(x: FloatArray, m: int, k0: int, k1: int) -> float:  # pragma: no cover - compiled
    """sum_{k0 <= k < k1} (x_{k+2m} - 2 x_{k+m} + x_k)^2 of a 1-D ``x``.

    Three slices indexed by the loop's own counter: an index ``k + m`` is a signed integer that numba
    wraps when negative, and that per-element select keeps LLVM from vectorising the loop (scalar loads,
    0.4-0.7e9 terms/s per core against 3e9 with the slices); reassociation lets it split the sum into
    vector lanes."""
    a = x[k0 + 2 * m : k1 + 2 * m]
    b = x[k0 + m : k1 + m]
    c = x[k0:k1]
    s = 0.0
    for k in range(k1 - k0):
        d = a[k] - 2.0 * b[k] + c[k]
        s += d * d
    return s


@numba.njit(cache=True, parallel=True, fastmath={"reassoc", "contract"})
def _oavar_kernel(
    xt: FloatArray, ms: NDArray[np.int64], block: int
) -> FloatArray:  # pragma: no cover - compiled
    """Sum of squared second differences of ``xt`` (A, n+1) for each cluster size in ``ms``; (len(ms), A).

    Parallel over blocks of ``block`` start indices k (all axes), each block summing every tau; the
    per-block sums are added in block order, so the result does not depend on the thread count."""
    A, n1 = xt.shape
    T = ms.shape[0]
    nb = (n1 + block - 1) // block
    part = np.zeros((A * nb, T))
    for i in numba.prange(A * nb):
        a = i // nb
        k0 = (i % nb) * block
        for j in range(T):
            k1 = min(k0 + block, n1 - 2 * ms[j])
            if k1 > k0:
                part[i, j] = _block_sum(xt[a], ms[j], k0, k1)
    out = np.zeros((T, A))
    for a in range(A):
        for i in range(a * nb, (a + 1) * nb):
            for j in range(T):
                out[j, a] += part[i, j]
    return out


def cluster_sizes(n: int, n_taus: int = 100, max_fraction: float = 0.5) -> NDArray[np.int64]:
    """About ``n_taus`` log-spaced unique cluster sizes m from 1 to ``max_fraction * n``."""
    top = max(int(n * max_fraction) // 2 * 2, 1)
    ms = np.unique(np.round(np.logspace(0, np.log10(max(top, 1)), n_taus)).astype(np.int64))
    return ms[(ms >= 1) & (2 * ms < n)]


def overlapped_adev(
    y: FloatArray, rate_hz: float, ms: NDArray[np.int64] | None = None
) -> tuple[FloatArray, FloatArray, NDArray[np.int64]]:
    """Overlapped Allan deviation of rate samples ``y`` (N,) or (N, A) at ``rate_hz``.

    Returns (taus (T,), adev (T,) or (T, A), ms (T,)) for the cluster sizes ``ms`` (log-spaced by default).
    """
    yy = np.asarray(y, dtype=float)
    single = yy.ndim == 1
    if single:
        yy = yy[:, None]
    n = yy.shape[0]
    if n < 3:
        raise ValueError(f"{n} samples: the Allan deviation needs at least 3")
    tau0 = 1.0 / rate_hz
    mm = cluster_sizes(n) if ms is None else np.asarray(ms, dtype=np.int64)
    mm = mm[(mm >= 1) & (2 * mm < n)]
    # Integrate relative to the mean: the second differences are unchanged and the sums stay well scaled.
    x = np.zeros((yy.shape[1], n + 1))  # one contiguous row per axis
    x[:, 1:] = np.cumsum(yy - yy.mean(axis=0), axis=0).T * tau0
    s = _oavar_kernel(x, mm, BLOCK)
    taus = mm * tau0
    var = s / (2.0 * (taus[:, None] ** 2) * (n + 1 - 2 * mm)[:, None])
    adev = np.sqrt(var)
    return taus, (adev[:, 0] if single else adev), mm


@dataclass
class NoiseTerms:
    """Noise coefficients of one axis, each with a 1-sigma relative uncertainty.

    white: N, unit/sqrt(Hz) (rad/s/sqrt(Hz) = rad/sqrt(s) for a gyro); bias_instability: B, unit;
    random_walk: K, unit*sqrt(Hz) (None when the log is too short to show the +1/2 slope).
    """

    white: float
    white_rel_std: float
    bias_instability: float
    bias_instability_tau_s: float
    bias_instability_rel_std: float
    random_walk: float | None
    random_walk_rel_std: float | None


def _local_slope(taus: FloatArray, adev: FloatArray) -> FloatArray:
    lt, la = np.log10(taus), np.log10(adev)
    return np.gradient(la, lt)


def _bootstrap_rw_rel(
    white: float, rw: float, n_samples: int, rate_hz: float, reps: int
) -> float | None:
    """Relative 1-sigma of the fitted K by a parametric bootstrap: ``reps`` series of white noise N and rate
    random walk K as long as the log, analysed and fitted as the log was. The long taus that carry K are
    correlated with one another, which the least-squares covariance ignores (it understates the spread of
    K about 2.5x in simulation); the bootstrap does not. The series are simulated at a reduced rate (at most
    40,000 samples): both terms' Allan deviations do not depend on the rate, only the shortest tau does."""
    span = n_samples / rate_hz
    fs = min(rate_hz, 200_000 / span)
    n = int(span * fs)
    if n < 1000:
        return None
    rng = np.random.default_rng(0)
    ks = []
    for _ in range(reps):
        y = white * np.sqrt(fs) * rng.normal(size=n) + np.cumsum(
            rw / np.sqrt(fs) * rng.normal(size=n)
        )
        taus, ad, _ = overlapped_adev(y, fs)
        k = fit_noise_terms(taus, ad, n, fs, bootstrap=0).random_walk
        if k is not None:
            ks.append(k)
    return float(np.std(ks) / rw) if len(ks) >= max(reps // 2, 2) else None


def fit_noise_terms(
    taus: FloatArray, adev: FloatArray, n_samples: int, rate_hz: float, bootstrap: int = 40
) -> NoiseTerms:
    """IEEE-952 coefficients from one Allan deviation curve.

    The Allan variance of white noise + bias instability + rate random walk is, to a good approximation,
    ``sigma^2(tau) = N^2 / tau + c0 + (K^2 / 3) tau`` (IEEE 952, annex C); the three coefficients are a
    weighted linear least-squares fit over the curve (weights from the relative uncertainty of each
    point). The 1-sigma of N comes from the fit's covariance, inflated by the square root of the number of
    points per octave of tau, since neighbouring overlapped estimates are correlated; that of K from a
    parametric bootstrap of ``bootstrap`` replicas (:func:`_bootstrap_rw_rel`; 0: the covariance, which
    understates it).
    """
    var = adev**2
    clusters = n_samples / (taus * rate_hz)
    rel = 1.0 / np.sqrt(2.0 * np.maximum(clusters - 1.0, 1.0))
    ok = clusters >= 4
    A = np.stack([1.0 / taus, np.ones_like(taus), taus / 3.0], axis=1)[ok]
    sw = 1.0 / (2.0 * rel[ok] * var[ok])  # sqrt of the weights: 1 / std(var)
    coef, *_ = np.linalg.lstsq(A * sw[:, None], var[ok] * sw, rcond=None)
    cov = np.linalg.pinv((A * sw[:, None]).T @ (A * sw[:, None]))
    octaves = max(np.log2(taus[ok][-1] / taus[ok][0]), 1.0)
    inflate = np.sqrt(max(ok.sum() / octaves, 1.0))
    imin = int(np.argmin(adev))
    if coef[0] > 0:
        white = float(np.sqrt(coef[0]))
        white_rel = float(0.5 * np.sqrt(cov[0, 0]) / coef[0] * inflate)
    else:  # no slope -1/2 region: read the first point
        white = float(adev[0] * np.sqrt(taus[0]))
        white_rel = float(rel[0])
    rw: float | None = None
    rw_rel: float | None = None
    if coef[2] > 0 and np.sqrt(cov[2, 2]) < 0.5 * coef[2]:
        rw = float(np.sqrt(coef[2]))
        rw_rel = float(0.5 * np.sqrt(cov[2, 2]) / coef[2] * inflate)
        if bootstrap > 0:
            rw_rel = _bootstrap_rw_rel(white, rw, n_samples, rate_hz, bootstrap) or rw_rel
    return NoiseTerms(
        white, white_rel, float(adev[imin] / 0.664), float(taus[imin]), float(rel[imin]), rw, rw_rel
    )


@dataclass
class AllanResult:
    """Allan deviation of the six axes of a log and the noise terms of each, in SI units.

    taus: (T,) s; accel_adev / gyro_adev: (T, 3) in m/s^2 and rad/s (counts if the log is in counts).
    """

    taus: FloatArray
    accel_adev: FloatArray
    gyro_adev: FloatArray
    accel_terms: list[NoiseTerms]
    gyro_terms: list[NoiseTerms]
    rate_hz: float
    accel_unit: str
    gyro_unit: str
    source: str
    n_samples: int
    warnings: list[str] = field(default_factory=list)

    def kalibr(self, rostopic: str = "/imu0") -> dict[str, Any]:
        """Kalibr ``imu.yaml`` fields: the worst axis of each noise term (conservative); a random walk
        the log is too short to show is bounded from the longest tau."""

        def worst(terms: list[NoiseTerms], rw: bool, adev: FloatArray) -> float:
            v = [t.random_walk if rw else t.white for t in terms]
            vv = [x for x in v if x is not None]
            if vv:
                return float(max(vv))
            # No +1/2 slope within the log: the random walk is at most what the longest tau shows,
            # K <= sigma(tau) sqrt(3 / tau) (IEEE 952-1997, annex C), a conservative value.
            return float(np.max(adev[-1]) * np.sqrt(3.0 / self.taus[-1]))

        return {
            "accelerometer_noise_density": worst(self.accel_terms, False, self.accel_adev),
            "accelerometer_random_walk": worst(self.accel_terms, True, self.accel_adev),
            "gyroscope_noise_density": worst(self.gyro_terms, False, self.gyro_adev),
            "gyroscope_random_walk": worst(self.gyro_terms, True, self.gyro_adev),
            "rostopic": rostopic,
            "update_rate": float(round(self.rate_hz, 3)),
        }


_TO_SI = {"g": 9.80665, "m/s^2": 1.0, "deg/s": np.pi / 180.0, "rad/s": 1.0, "counts": 1.0}


def _check_static(acc: FloatArray, t_s: FloatArray, source: str, max_deg: float = 3.0) -> None:
    """InputError when gravity's direction moves by more than ``max_deg`` between tenths of the log:
    an Allan analysis of a moving IMU measures the motion, not the noise. (Means of a tenth of a
    static log differ by noise / sqrt(N / 10), and a thermal bias drift of 0.05 m/s^2 by 0.3 deg.)"""
    edges = np.linspace(0, len(acc), 11).astype(int)
    means = np.stack([acc[a:b].mean(axis=0) for a, b in zip(edges[:-1], edges[1:], strict=True)])
    u = means / np.linalg.norm(means, axis=1, keepdims=True)
    ang = np.rad2deg(np.arccos(np.clip(u @ u[0], -1.0, 1.0)))
    if ang.max() > max_deg:
        j = int(np.argmax(ang))
        raise InputError(
            f"{source}: not a static log: gravity's direction moves {ang[j]:.1f} deg between the first "
            f"tenth and the one from {t_s[edges[j]]:.0f} s; an Allan analysis needs the IMU still"
        )


def allan(log: ImuLog, n_taus: int = 100) -> AllanResult:
    """Allan deviation of every axis of a static log, converted to SI (counts stay counts)."""
    n = len(log)
    if n < 1000:
        raise InputError(
            f"{log.source}: {n} samples; an Allan analysis needs a long static log (>= 1000)"
        )
    rate = log.rate_hz
    dt = np.diff(log.t_ns)
    jitter = float(np.std(dt) / np.mean(dt))
    warnings = list(log.warnings)
    if jitter > 0.05:
        warnings.append(
            f"{log.source}: sample intervals vary by {100 * jitter:.0f} % (std/mean); the analysis assumes "
            f"uniform sampling at the mean rate {rate:.2f} Hz"
        )
    acc = log.accel * _TO_SI[log.accel_unit]
    gyr = log.gyro * _TO_SI[log.gyro_unit]
    _check_static(acc, log.t_s, log.source)
    ms = cluster_sizes(n, n_taus)
    taus, adev, _ = overlapped_adev(np.hstack([acc, gyr]), rate, ms)
    terms = [fit_noise_terms(taus, adev[:, j], n, rate) for j in range(6)]
    return AllanResult(
        taus, adev[:, :3], adev[:, 3:], terms[:3], terms[3:], rate,
        "counts" if log.accel_unit == "counts" else "m/s^2",
        "counts" if log.gyro_unit == "counts" else "rad/s",
        log.source, n, warnings,
    )  # fmt: skip
