"""One interface for alignment: feed a (calibrated) IMU log and aiding, get attitude, bias estimates with
their covariance over time, and the corrected IMU.

Methods: ``none`` (free strapdown from the given initial state), ``kf`` (error-state KF, ``ins/kf.py``),
``stkf`` (the same with strong tracking), ``rwnn`` (the RWNN observer, ``ins/rwnn.py``; 1-sigma from its least-squares learning);
static levelling and gyrocompassing (``coarse``) is :func:`imuslam.ins.coarse.coarse_align`, which gives
the initial attitude the others start from.
Aiding: position (m, in n), velocity (m/s, in n) or ``zupt`` (the IMU is still: zero velocity and zero
angular rate), each with a time stamp and a 1-sigma.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.ins.aiding import AidingKind
from imuslam.ins.core import ErrorLayout
from imuslam.ins.kf import (
    AidingEpochs,
    FilterDivergence,
    FilterStart,
    KfNoise,
    StrongTracking,
    eskf_batch,
)
from imuslam.ins.rwnn import RwnnConfig, run_rwnn
from imuslam.ins.strapdown import integrate
from imuslam.interfaces.imu import ImuLog
from imuslam.interfaces.nav import NavState

FloatArray = NDArray[np.float64]
Method = Literal["none", "kf", "stkf", "rwnn"]
METHODS = ("none", "coarse", "kf", "stkf", "rwnn")


@dataclass
class Aiding:
    """Aiding measurements: t_s (M,) s, kind 'position' | 'velocity' | 'zupt', values (M, 3), std (m or m/s)."""

    t_s: FloatArray
    kind: str
    values: FloatArray
    std: float

    def __post_init__(self) -> None:
        if self.kind not in tuple(AidingKind):
            raise ValueError(f"aiding kind '{self.kind}'; expected position, velocity or zupt")
        self.kind = AidingKind(self.kind)
        self.t_s = np.asarray(self.t_s, dtype=float)
        self.values = np.asarray(self.values, dtype=float)
        if self.t_s.ndim != 1 or self.values.shape != (len(self.t_s), 3):
            raise ValueError(
                f"aiding: expected times (M,) and values (M, 3), got {self.t_s.shape} and {self.values.shape}"
            )
        bad = ~(np.isfinite(self.t_s) & np.isfinite(self.values).all(axis=1))
        if bad.any():
            raise InputError(f"aiding measurement {int(np.argmax(bad))} is NaN or infinite")
        if np.any(np.diff(self.t_s) < 0):
            k = int(np.argmax(np.diff(self.t_s) < 0)) + 1
            raise InputError(
                f"aiding measurement {k} goes back in time ({self.t_s[k]:.6f} s after {self.t_s[k - 1]:.6f} s)"
            )
        if not (np.isfinite(self.std) and self.std > 0):
            raise InputError(f"aiding 1-sigma must be positive, got {self.std}")


@dataclass
class AlignmentResult:
    """Estimates at the aiding times: t_s (M,), accel_bias / gyro_bias (M, 3) and their 1-sigma (M, 3),
    R_n_b (M, 3, 3), p_n, v_n (M, 3); fading factors (STKF, else ones); the final state; the aiding
    update's normalised innovation squared against its predicted covariance (M,; kf and stkf, else NaN):
    its mean is the aiding's dimension (3) when the stated noise is right, far below when it is overstated
    (then strong tracking never fades: ``docs/study_evidence.md``)."""

    method: str
    t_s: FloatArray
    accel_bias: FloatArray
    accel_bias_std: FloatArray
    gyro_bias: FloatArray
    gyro_bias_std: FloatArray
    R_n_b: FloatArray
    p_n: FloatArray
    v_n: FloatArray
    fading: FloatArray
    final: NavState
    nis: FloatArray

    def corrected(self, log: ImuLog) -> ImuLog:
        """The log with the final bias estimates removed (measured = true + bias)."""
        return ImuLog(log.t_ns, log.accel - self.accel_bias[-1], log.gyro - self.gyro_bias[-1], log.accel_unit,
                      log.gyro_unit, log.source, list(log.warnings))  # fmt: skip


def run_alignment(
    log: ImuLog,
    aiding: Aiding,
    init: NavState,
    method: Method = "kf",
    noise: KfNoise | None = None,
    P0_diag: FloatArray | None = None,  # in the layout's order [theta, p, v, b_a, b_g (, g)]
    g: float = 9.80665,
    estimate_gravity: bool = False,
    stkf_beta: float = 3.0,
    stkf_rho: float = 0.95,
    stkf_max_fading: float = 5.0,
    rwnn_config: RwnnConfig | None = None,
) -> AlignmentResult:
    """Run ``method`` over ``log`` (SI, body frame) with ``aiding`` from ``init`` at the first sample."""
    if log.accel_unit != "m/s^2" or log.gyro_unit != "rad/s":
        raise InputError(
            f"{log.source}: alignment needs m/s^2 and rad/s (calibrate or convert the log first)"
        )
    t = log.t_s
    if method == "none":
        P, V, R = integrate(t, log.accel, log.gyro, init, g)
        idx = np.clip(np.searchsorted(t, aiding.t_s), 0, len(t) - 1)
        z = np.zeros((len(idx), 3))
        return AlignmentResult("none", t[idx], z, z + np.inf, z, z + np.inf, R[idx], P[idx], V[idx], np.ones(len(idx)),
                               NavState(P[-1], V[-1], R[-1]), np.full(len(idx), np.nan))  # fmt: skip
    if method == "rwnn":
        r = run_rwnn(
            t,
            log.accel,
            log.gyro,
            aiding.t_s,
            aiding.values,
            aiding.kind,
            init.p_n,
            init.v_n,
            init.R_n_b,
            g,
            rwnn_config,
            aid_std=aiding.std,
            accel_noise=(noise or KfNoise()).accel,
        )
        idx = np.clip(np.searchsorted(t, aiding.t_s), 0, len(t) - 1)
        # the error estimates are the network's whole output (bias weights + nodes), their 1-sigma that of
        # the least-squares learning of the output weights
        return AlignmentResult("rwnn", t[idx], r.accel_error[idx], r.accel_error_std[idx], r.gyro_error[idx], r.gyro_error_std[idx], r.R_n_b[idx],
                               r.p_n[idx], r.v_n[idx], np.ones(len(idx)), NavState(r.p_n[idx[-1]], r.v_n[idx[-1]], r.R_n_b[idx[-1]]),
                               np.full(len(idx), np.nan))  # fmt: skip
    if method not in ("kf", "stkf"):
        raise ValueError(f"alignment method '{method}'; expected one of {', '.join(METHODS)}")
    if P0_diag is None:
        layout = ErrorLayout.full(gravity=estimate_gravity)
        p0 = layout.diag(theta=0.05**2, p=0.1**2, v=0.1**2, ba=0.2**2, bg=0.02**2, g=0.05**2)
    else:
        p0 = np.asarray(P0_diag, dtype=float)
        if len(p0) not in (15, 18):
            raise ValueError(f"P0_diag has {len(p0)} entries; expected 15 (or 18 with gravity)")
        layout = ErrorLayout.full(gravity=len(p0) == 18)
    nz = noise or KfNoise()
    q = nz.q
    aid_k = np.searchsorted(t, aiding.t_s)
    n_ok = int(np.argmax(aid_k >= len(t))) if np.any(aid_k >= len(t)) else len(aid_k)
    if n_ok == 0:
        raise InputError(f"{log.source}: no aiding measurement falls inside the log's time span")
    aid_k = aid_k[:n_ok].astype(np.int64)
    blk = aid_k - np.concatenate([[0], aid_k[:-1]]) + 1  # samples in each block, both ends
    zaru_std = nz.gyro * np.sqrt(log.rate_hz / blk)
    epochs = AidingEpochs(
        aid_k, aiding.values[:n_ok], AidingKind(aiding.kind), float(aiding.std), zaru_std
    )
    start = FilterStart(init.p_n.astype(float).copy(), init.v_n.astype(float).copy(), init.R_n_b,
                        np.zeros(3), np.zeros(3), np.zeros(3), np.diag(p0).astype(float))  # fmt: skip
    tracking = StrongTracking(method == "stkf", stkf_rho, stkf_beta, stkf_max_fading)
    res = eskf_batch(
        log.accel, log.gyro, t, epochs, start, np.array([0.0, 0.0, -g]), q, layout, tracking
    )
    bad = res.diverged_at
    if bad >= 0:
        raise FilterDivergence(
            f"filter diverged at sample {bad} (t = {t[min(bad, len(t) - 1)]:.3f} s): covariance not positive "
            "definite or state not finite; check the noise settings and the aiding"
        )
    return AlignmentResult(
        method, aiding.t_s[:n_ok], res.accel_bias, res.accel_bias_std, res.gyro_bias,
        res.gyro_bias_std, res.R_n_b, res.p_n, res.v_n, res.fading,
        NavState(res.final_p, res.final_v, res.final_R), res.nis,
    )  # fmt: skip
