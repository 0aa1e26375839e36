"""What the LiDAR-inertial filter does when a sensor misbehaves: a gyro at its range, gaps in the IMU
log, a scan that constrains only some directions of the pose.

- Saturation: a MEMS gyro clips at its range (``filter.gyro_range_dps``; when unset, an axis whose
  largest magnitude is repeated by at least three samples is taken as clipped there). Samples within
  ``filter.gyro_clip_margin`` of the range on any axis (a calibration's scale and misalignment move a
  clipped value a few percent) are bridged: each axis by a least-squares quadratic in time through the
  0.1 s of unclipped samples on both sides of the run (a fast turn's rate is a hump), kept at or beyond
  the clipped value on a clipped axis (on a whole turn in 2 s, 337 deg/s at its peak and 43 deg of
  it clipped, the bridge restores 87 % of the loss; a hump is flatter than a parabola near its base,
  so the bridge falls short, never over); the bridge's error enters the attitude covariance (its 1-sigma
  a third of the bridged excess plus 2 % of the range, summed over the run as fully correlated), so the
  LiDAR update can pull the attitude back.
- Gaps: the propagation interpolates across a gap in the IMU log; over a gap longer than four sample
  periods the attitude, velocity and position covariances grow by what the interpolation cannot know
  (the change of the rate and of the specific force across the gap, at least 0.1 rad/s and 0.5 m/s^2).
- Degeneracy (Zhang, Kaess and Singh, "On degeneracy of optimization-based state estimation
  problems", ICRA 2016): the point-to-plane information of the pose, H^T R^-1 H on [p, theta] with the
  rotation scaled by 10 m (a radian at 10 m), is eigen-decomposed; a direction whose 1-sigma from the
  scan alone exceeds ``filter.degenerate_std`` is degenerate. With ``filter.degeneracy_guard`` the
  update's Jacobian is projected onto the other directions (Zhang's solution remapping in the Kalman
  form), so the filter keeps the IMU's prediction there instead of following the scan's noise; the
  degenerate scans and their directions are reported either way. The projection goes through the
  iterated update's one projector hook (``Eskf._update_prior``, :class:`GuardedEskf`), as the
  in-filter extrinsic's consider states do; only H's columns are projected, the prior is kept whole
  (a degenerate direction still moves with its prior correlation to the directions the scan fixes:
  the IMU's prediction, conditioned on what the scan does measure).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from imuslam.ins.core import ErrorLayout, Eskf
from imuslam.interfaces.imu import ImuLog

FloatArray = NDArray[np.float64]
LEVER_M = 10.0  # rotation scaled to metres at this distance in the degeneracy test
AXES = ("x", "y", "z", "roll", "pitch", "yaw")


def detect_range(gyro: FloatArray, min_repeats: int = 3) -> float | None:
    """The clipping level of a gyro log (rad/s), or None: the largest magnitude over the axes that at
    least ``min_repeats`` samples reach exactly (a clipped output repeats its limit; noise never
    repeats a float)."""
    best = None
    for a in range(gyro.shape[1]):
        m = float(np.max(np.abs(gyro[:, a])))
        if m > 0 and np.count_nonzero(np.abs(gyro[:, a]) >= m * (1 - 1e-9)) >= min_repeats:
            best = m if best is None else max(best, m)
    return best


def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """[start, stop) index pairs of the True runs of ``mask``."""
    d = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=True))


@dataclass
class ImuRepair:
    """The IMU log the filter propagates (clipped runs bridged), per sample the 1-sigma of the bridge's
    rate error (rad/s, 0 elsewhere), the gaps (start, end) s, the range used (rad/s or None), and
    one line per repair for the run's warnings."""

    imu: ImuLog
    t_s: FloatArray
    rate_sigma: FloatArray
    gaps: list[tuple[float, float, float, float]] = field(default_factory=list)
    range_rad_s: float | None = None
    n_clipped: int = 0
    notes: list[str] = field(default_factory=list)

    def extra_covariance(self, t0: float, t1: float) -> tuple[float, float, float]:
        """Variances (attitude rad^2, velocity (m/s)^2, position m^2) to add per axis for the samples
        bridged and the gaps crossed in (t0, t1]."""
        th = vel = pos = 0.0
        if self.n_clipped:
            i0, i1 = np.searchsorted(self.t_s, [t0, t1], side="right")
            s = self.rate_sigma[max(i0 - 1, 0) : i1]
            if np.any(s > 0):
                dt = np.diff(self.t_s[max(i0 - 1, 0) : i1 + 1])[: len(s)]
                th += float(np.sum(s[: len(dt)] * dt)) ** 2
        for a, b, sw, sa in self.gaps:
            lo, hi = max(a, t0), min(b, t1)
            if hi > lo:
                L = hi - lo
                th += (sw * L) ** 2
                vel += (sa * L) ** 2
                pos += (0.5 * sa * L * L) ** 2
        return th, vel, pos


def repair_imu(imu: ImuLog, range_dps: float | None, margin: float) -> ImuRepair:
    """Bridge the clipped gyro runs and list the gaps of ``imu`` (SI units), see the module doc."""
    t = imu.t_s
    gyro = imu.gyro.copy()
    rng = np.deg2rad(range_dps) if range_dps is not None else detect_range(gyro)
    sigma = np.zeros(len(t))
    notes: list[str] = []
    n_clip = 0
    if rng is not None:
        lim = rng * (1.0 - margin)
        mask = np.any(np.abs(gyro) >= lim, axis=1)
        n_clip = int(mask.sum())
        for i0, i1 in _runs(mask):
            flank = np.r_[np.flatnonzero(~mask[:i0] & (t[:i0] >= t[i0] - 0.1)),
                          i1 + np.flatnonzero(~mask[i1:] & (t[i1:] <= t[i1 - 1] + 0.1))]  # fmt: skip
            inside = np.arange(i0, i1)
            if len(flank) >= 3:
                tt = t[flank] - t[i0]
                V = np.vander(tt, 3)
                coef, *_ = np.linalg.lstsq(V, gyro[flank], rcond=None)
                fit = np.vander(t[inside] - t[i0], 3) @ coef
            else:  # no flank to fit: hold the clipped values
                fit = gyro[inside].copy()
            obs = gyro[inside]
            clipped = np.abs(obs) >= lim
            keep_out = np.where(clipped, np.sign(obs) * np.maximum(np.abs(fit), np.abs(obs)), fit)
            excess = np.linalg.norm(keep_out - obs, axis=1)
            gyro[inside] = keep_out
            sigma[inside] = excess / 3.0 + 0.02 * rng
        if n_clip:
            notes.append(f"{n_clip} gyro samples within {100 * margin:g} % of the range "
                         f"(+-{np.rad2deg(rng):.0f} deg/s) bridged, from t = {t[mask][0]:.2f} s to "
                         f"{t[mask][-1]:.2f} s")  # fmt: skip
    gaps = []
    dt = np.diff(t)
    if len(dt):
        nominal = float(np.median(dt))
        for i in np.flatnonzero(dt > 4 * nominal):
            sw = max(float(np.linalg.norm(gyro[i + 1] - gyro[i])), 0.1)
            sa = max(float(np.linalg.norm(imu.accel[i + 1] - imu.accel[i])), 0.5)
            gaps.append((float(t[i]), float(t[i + 1]), sw, sa))
    return ImuRepair(replace(imu, gyro=gyro), t, sigma, gaps, rng, n_clip, notes)


def inflate(P: FloatArray, layout: ErrorLayout, var: tuple[float, float, float]) -> FloatArray:
    """``P`` with the attitude, velocity and position variances ``var`` added on each axis."""
    th, vel, pos = var
    if th == vel == pos == 0.0:
        return P
    P = P.copy()
    for sl, v in ((layout.TH, th), (layout.V, vel), (layout.P, pos)):
        idx = np.arange(sl.start, sl.stop)
        P[idx, idx] += v
    return P


@dataclass
class Degeneracy:
    """One scan's test: the 1-sigma (m, rotation as m at 10 m) of the scan alone along each
    eigenvector of its pose information, weakest first, and the names of the degenerate directions."""

    sigma: FloatArray
    directions: list[str]


class DegeneracyGuard:
    """Tests a scan's pose information on the rows of the update's prior (R a vector of variances, or
    ones after whitening) and, when ``remap``, gives the projector of the update's Jacobian onto the
    well-constrained directions."""

    def __init__(self, layout: ErrorLayout, limit_m: float, remap: bool) -> None:
        self.layout, self.limit, self.remap = layout, limit_m, remap
        self.last: Degeneracy | None = None

    @property
    def _cols(self) -> NDArray[np.intp]:
        lay = self.layout
        return np.r_[np.arange(lay.P.start, lay.P.stop), np.arange(lay.TH.start, lay.TH.stop)]

    def test(self, H: FloatArray, R: FloatArray) -> tuple[Degeneracy, FloatArray | None]:
        """The test of rows (r, H, R) and the projector (6, 6) on [p, theta], or None if none is
        degenerate."""
        Hp = H[:, self._cols] * np.r_[np.ones(3), np.full(3, 1.0 / LEVER_M)]
        Rv = np.asarray(R, float)
        A = Hp.T @ (Hp / Rv[:, None]) if Rv.ndim == 1 else Hp.T @ np.linalg.solve(Rv, Hp)
        lam, V = np.linalg.eigh(A)
        sig = 1.0 / np.sqrt(np.maximum(lam, 1e-300))
        bad = sig > self.limit
        names = sorted({AXES[int(np.argmax(np.abs(V[:, j])))] for j in np.flatnonzero(bad)},
                       key=AXES.index)  # fmt: skip
        proj = None
        if np.any(bad):
            good = V[:, ~bad]
            S = np.r_[np.ones(3), np.full(3, LEVER_M)]  # back to [p, theta] units
            proj = (good @ good.T) * S[None, :] / S[:, None]
        return Degeneracy(sig, names), proj

    def projector(self, H: FloatArray, R: FloatArray) -> FloatArray | None:
        """The test of the update's prior rows (kept in ``last``) and, when ``remap`` and a direction
        is degenerate, the projector (dim, dim) of the error state's H columns (identity but on
        [p, theta]) for :attr:`GuardedEskf.projector`; None otherwise."""
        self.last, proj = self.test(H, R)
        if not self.remap or proj is None:
            return None
        T = np.eye(H.shape[1])
        T[np.ix_(self._cols, self._cols)] = proj
        return T


class GuardedEskf(Eskf):
    """``Eskf`` whose iterated update projects the Jacobian's columns by ``projector`` (dim, dim) when
    one is set (the degeneracy guard's, set before each scan's update): the update's projector hook
    ``_update_prior``, with the prior covariance unchanged."""

    projector: FloatArray | None = None

    def _update_prior(self, P: FloatArray) -> tuple[FloatArray | None, FloatArray]:
        return self.projector, P
