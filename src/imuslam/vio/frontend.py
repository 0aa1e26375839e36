"""Stereo visual odometry on rectified image pairs (seed 004's front end).

Per frame: features of the left image (SIFT keypoints, ORB as an option) are matched into the right
image along the rectified row by ZNCC and triangulated (``z = f b / d``); the disparity's slopes around
each point give its local surface, and the disparity is refined with the window slanted by them. On the
next frame the features are tracked in the left image by ZNCC on a two-level pyramid around a
constant-velocity prediction, each patch compared through the affine map that its surface and the
predicted motion give it (a near floor patch grows and shears between frames); the
motion between the frames comes from RANSAC on the 3D-2D correspondences (``cv2.solvePnPRansac``), then a
Gauss-Newton refinement in which every point is weighted by its reprojection covariance: tracking noise
plus its triangulation covariance carried through the projection (far points count less); the inliers
whose residual is beyond the 99 % quantile of its own covariance (what the fit leaves of that one: data
snooping) are dropped and the fit repeated. The inverse normal matrix, scaled by the a-posteriori
variance factor when that exceeds one, is the pose covariance; carried through to the body frame it
gives the measurement: mean body angular rate and linear velocity over the frame interval with their
6x6 covariance (rotation first).

Frames: ``r`` is the rectified left camera (x right, y down, z forward), ``b`` the body (IMU).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from imuslam.geometry.so3_nb import exp_nb, log_nb
from imuslam.interfaces.sources import StereoRectification
from imuslam.vio.motion_nb import huber_terms, normal_terms, snooped_q
from imuslam.vio.zncc import disparity_slopes, slanted_disparity, stereo_match, track

FloatArray = NDArray[np.float64]
log_ = logging.getLogger(__name__)


class VoConfig(BaseModel):
    """Front-end settings (pixels of the rectified images)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    detector: Literal["sift", "orb"] = "sift"
    max_features: int = Field(300, ge=20, le=10000, description="features kept per frame")
    redetect_below: float = Field(
        0.7, gt=0, le=1, description="detect when fewer tracks than this share"
    )
    cell_px: int = Field(
        16, ge=4, le=256, description="at most one new feature per cell of this size"
    )
    patch_half: int = Field(5, ge=2, le=32, description="ZNCC patch half-size at full resolution")
    patch_half_coarse: int = Field(
        3, ge=2, le=32, description="ZNCC patch half-size at half resolution"
    )
    search_coarse_px: int = Field(
        8, ge=1, le=64, description="tracking search radius at half resolution"
    )
    search_fine_px: int = Field(2, ge=1, le=16, description="refinement radius at full resolution")
    min_zncc: float = Field(0.8, gt=-1, lt=1, description="tracking acceptance")
    stereo_min_zncc: float = Field(0.8, gt=-1, lt=1)
    stereo_uniqueness: float = Field(0.97, gt=0, le=1, description="second peak below this x best")
    min_disparity: float = Field(2.0, ge=0.5, description="px; nearer than f b / this")
    max_disparity: float = Field(120.0, gt=2)
    ransac_px: float = Field(2.0, gt=0)
    refit: bool = Field(
        True,
        description="after the motion fit, drop the RANSAC inliers whose reprojection residual is "
        "beyond refit_prob of its covariance and fit again",
    )
    refit_prob: float = Field(0.99, gt=0.5, lt=1)
    refit_snooping: bool = Field(
        True,
        description="test each residual against its own covariance C - J A^-1 J^T, what the fit "
        "leaves of C (Baarda's data snooping), instead of C: a point with high leverage (few near "
        "points carry the translation) drags the fit to itself and leaves a small residual that C "
        "alone would pass",
    )
    refit_huber_k: float = Field(
        0.0,
        ge=0,
        description="0: off. Else, after the refit, a Huber-weighted fit (iteratively reweighted): "
        "the points whose residual is beyond this many sigmas of its covariance (Mahalanobis norm) "
        "weigh k / norm, so that tracks just inside the refit's test pull the fit less. On the "
        "rendered robot k = 2 trims the VO error's tails on 7 of 11 seeds and brings the filter's "
        "mean NIS into its band on 72 of 80 cells against 69, but the seeds' mean errors scatter "
        "more and the NHC cut falls from 51 to 45 %: off by default (README, VIO)",
    )
    min_inliers: int = Field(12, ge=6)
    pixel_sigma: float = Field(
        0.25, gt=0, description="prior 1-sigma of tracking and stereo matching, px (grows per pair)"
    )
    warp: bool = Field(
        True,
        description="track each patch through the affine map its surface (from the disparity's slopes) "
        "and the predicted motion give it, instead of a pure shift",
    )
    slanted_stereo: bool = Field(
        True,
        description="refine each disparity with the window slanted by the disparity's slopes (surfaces "
        "not facing the camera, such as the floor ahead)",
    )
    plane_step_px: int = Field(
        3, ge=1, le=32, description="px; the disparity's slopes span twice this"
    )
    blur_sigma: float = Field(
        1.0,
        ge=0,
        le=10,
        description="Gaussian pre-blur for matching, px: without it, interpolation averaging "
        "the image noise pulls sub-pixel peaks toward half pixels (0.08 px of disparity measured)",
    )


@dataclass
class VoMeasurement:
    """Motion between frames at ``t0_ns`` and ``t1_ns``: mean body angular rate ``omega_b`` (rad/s) and
    mean linear velocity ``vel_b`` (m/s, in the body frame at mid-interval), covariance (6, 6) of
    ``[omega_b, vel_b]``; ``T_b0_b1`` the relative body pose; ``n_inliers`` RANSAC inliers. ``cov_fit``
    (6, 6) is the motion fit's covariance at the prior pixel sigma, ``(J^T W J)^-1`` carried to the rates,
    and ``var_factor`` the fit's a-posteriori variance factor (weighted residual chi-square over its
    2 n - 6 degrees of freedom): ``cov = cov_fit * max(var_factor, 1)``."""

    t0_ns: int
    t1_ns: int
    omega_b: FloatArray
    vel_b: FloatArray
    cov: FloatArray
    T_b0_b1: FloatArray
    n_inliers: int
    cov_fit: FloatArray | None = None
    var_factor: float = 1.0

    @property
    def t_mid_ns(self) -> int:
        return (self.t0_ns + self.t1_ns) // 2

    @property
    def dt(self) -> float:
        return (self.t1_ns - self.t0_ns) * 1e-9


@dataclass
class VoStats:
    """Counts over a run."""

    frames: int = 0
    measurements: int = 0
    skipped_few_features: int = 0
    skipped_few_inliers: int = 0
    tracked: list[int] = field(default_factory=list)
    inliers: list[int] = field(default_factory=list)
    # wall-clock seconds spent per part of :meth:`StereoVO.process`, summed over the run: "images"
    # (conversion, blur, pyramid), "track" (prediction, warp maps, ZNCC tracking), "motion" (RANSAC,
    # the fit, the body rates and their covariance), "detect", "stereo" (matching, triangulation)
    seconds: dict[str, float] = field(
        default_factory=lambda: dict.fromkeys(
            ("images", "track", "motion", "detect", "stereo"), 0.0
        )
    )


def _lap(seconds: dict[str, float], part: str, tic: float) -> float:
    """Add the time since ``tic`` to ``seconds[part]``; returns now."""
    now = time.perf_counter()
    seconds[part] += now - tic
    return now


def _se3(R: FloatArray, t: FloatArray) -> FloatArray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def _inv(T: FloatArray) -> FloatArray:
    return _se3(T[:3, :3].T, -T[:3, :3].T @ T[:3, 3])


class StereoVO:
    """Frame-to-frame stereo VO. Feed rectified pairs in time order with :meth:`process`."""

    def __init__(self, rect: StereoRectification, cfg: VoConfig | None = None) -> None:
        import cv2

        self.rect = rect
        self.cfg = cfg or VoConfig()
        c = self.cfg
        if c.detector == "sift":
            self._det: Any = cv2.SIFT_create(  # type: ignore[attr-defined]
                nfeatures=2 * c.max_features, contrastThreshold=0.02
            )
        else:
            self._det = cv2.ORB_create(  # type: ignore[attr-defined]
                nfeatures=2 * c.max_features, fastThreshold=10
            )
        self.stats = VoStats()
        #: the last pair's tracks: the previous frame's features (N, 2) px, where they were found in
        #: this one (N, 2) px (NaN: lost), and the indices of the motion fit's inliers; None: no tracking
        self.last_tracks: tuple[FloatArray, FloatArray, NDArray[np.int64]] | None = None
        self._refit_chi2 = -2.0 * np.log(1.0 - c.refit_prob)  # chi-square (2 dof) quantile
        self.T_b_r = _se3(rect.R_b_r, rect.p_b_r)
        self.T_r_b = _inv(self.T_b_r)
        self._prev: dict[str, Any] | None = None
        self._T_rel = np.eye(4)  # last T_{r_k, r_{k-1}}, the constant-velocity prediction

    # -- features -------------------------------------------------------------------------------
    def _detect(self, img_u8: NDArray[np.uint8], have: FloatArray, n_want: int) -> FloatArray:
        import cv2

        c = self.cfg
        mask = np.full(img_u8.shape, 255, np.uint8)
        m = c.patch_half + 3
        mask[:m], mask[-m:], mask[:, :m], mask[:, -m:] = 0, 0, 0, 0
        for u, v in have:
            cv2.circle(mask, (int(u), int(v)), c.cell_px // 2 + 2, 0, -1)
        # detection at half resolution: OpenCV's SIFT doubles its input first, so this costs what a
        # full-resolution SIFT starting at octave 0 would; ZNCC then works at full resolution
        half = cv2.pyrDown(img_u8)
        kps = self._det.detect(
            half, cv2.resize(mask, (half.shape[1], half.shape[0]), interpolation=cv2.INTER_NEAREST)
        )
        if not kps:
            return np.zeros((0, 2))
        pts = 2.0 * np.array([k.pt for k in kps], float)
        resp = np.array([k.response for k in kps], float)
        order = np.argsort(-resp)
        pts = pts[order]
        cell = (pts[:, 1] // c.cell_px).astype(np.int64) * 10_000 + (pts[:, 0] // c.cell_px).astype(
            np.int64
        )
        _, first = np.unique(cell, return_index=True)
        first.sort()
        return pts[first[:n_want]]

    def _triangulate(
        self,
        left: NDArray[Any],
        right: NDArray[Any],
        uv: FloatArray,
        d_pred: FloatArray,
    ) -> tuple[FloatArray, FloatArray]:
        """Stereo-match and triangulate ``uv`` (N, 2); ``d_pred`` (N,) predicted disparity (NaN: search
        the whole range). Returns [u, v, X, Y, Z, m_x, m_y, m_z] rows of the matched points (``m`` the
        local surface, :meth:`_plane`; zeros without ``warp``) and their 3x3 covariances."""
        c, r = self.cfg, self.rect
        known = np.isfinite(d_pred)
        margin = np.maximum(3.0, 0.2 * np.where(known, d_pred, 0.0))
        d_lo = np.where(known, np.maximum(d_pred - margin, c.min_disparity), c.min_disparity)
        d_hi = np.where(known, np.minimum(d_pred + margin, c.max_disparity), c.max_disparity)
        d, _ = stereo_match(
            left, right, uv, c.patch_half, d_lo, d_hi, c.stereo_min_zncc, c.stereo_uniqueness
        )
        ok = np.isfinite(d) & (d >= c.min_disparity)
        uv, d = uv[ok], d[ok]
        slopes = np.full((len(d), 2), np.nan)
        if c.warp or c.slanted_stereo:
            slopes = disparity_slopes(left, right, uv, d, c.patch_half, c.plane_step_px)
        if c.slanted_stereo:
            d = slanted_disparity(left, right, uv, d, slopes, c.patch_half)
            ok = np.isfinite(d) & (d >= c.min_disparity)
            uv, d, slopes = uv[ok], d[ok], slopes[ok]
        f, cx, cy, b = r.K[0, 0], r.K[0, 2], r.K[1, 2], r.baseline
        z = f * b / d
        plane = self._plane(uv, d, slopes) if c.warp else np.zeros((len(d), 3))
        X = np.stack([(uv[:, 0] - cx) * z / f, (uv[:, 1] - cy) * z / r.K[1, 1], z], axis=1)
        # triangulation covariance from (u, v, d) with sigma, sigma, sqrt(2) sigma (d = u_l - u_r)
        s2 = c.pixel_sigma**2
        J = np.zeros((len(d), 3, 3))
        J[:, 0, 0] = b / d
        J[:, 0, 2] = -(uv[:, 0] - cx) * b / d**2
        J[:, 1, 1] = b / d
        J[:, 1, 2] = -(uv[:, 1] - cy) * b / d**2
        J[:, 2, 2] = -f * b / d**2
        S = np.diag([s2, s2, 2 * s2])
        cov = J @ S @ np.swapaxes(J, 1, 2)
        return np.concatenate([uv, X, plane], axis=1), cov

    def _plane(self, uv: FloatArray, d: FloatArray, slopes: FloatArray) -> FloatArray:
        """The local surface of each point as ``m`` (N, 3) with ``m . X = 1`` on it (``m = n / rho`` for
        the plane ``n . X = rho``), from the disparity's gradient: on a plane the rectified disparity is
        affine in the pixel, ``d = f b m . K^-1 [u, v, 1]``, so its slopes give ``m_x = d_u / b``,
        ``m_y = d_v f_y / (f_x b)``. The slopes come from matches ``plane_step_px`` away on either side;
        where one fails or the slopes are implausible the patch is taken as facing the camera
        (``m = [0, 0, 1 / z]``)."""
        r = self.rect
        fx, fy, cx, cy, b = r.K[0, 0], r.K[1, 1], r.K[0, 2], r.K[1, 2], r.baseline
        du, dv = slopes[:, 0], slopes[:, 1]
        m = np.zeros((len(d), 3))
        m[:, 2] = d / (fx * b)
        good = np.isfinite(du) & np.isfinite(dv) & (np.abs(du) < 2.0) & (np.abs(dv) < 2.0)
        mx, my = du / b, dv * fy / (fx * b)
        m[good, 0] = mx[good]
        m[good, 1] = my[good]
        m[good, 2] -= mx[good] * (uv[good, 0] - cx) / fx + my[good] * (uv[good, 1] - cy) / fy
        return m

    # -- motion ---------------------------------------------------------------------------------
    def _refine(
        self, X: FloatArray, covX: FloatArray, uv: FloatArray, R: FloatArray, t: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, float, FloatArray]:
        """Weighted Gauss-Newton on T_{r_k, r_{k-1}} (left perturbation [dtheta, dt]); returns R, t, the
        6x6 covariance of the perturbation at the prior pixel sigma, the a-posteriori variance factor
        (chi-square over 2 n - 6) and each point's residual chi-square (2 dof) under its covariance (with
        ``refit_snooping``, under the residual's own covariance). The per-point terms are compiled
        (:mod:`imuslam.vio.motion_nb`)."""
        K = self.rect.K
        s2 = self.cfg.pixel_sigma**2
        n = len(X)
        cov: FloatArray = np.eye(6)
        X = np.ascontiguousarray(X, dtype=float)
        covX = np.ascontiguousarray(covX, dtype=float)
        uv = np.ascontiguousarray(uv, dtype=float)
        for it in range(4):
            A, g, q, C, Jd, res = normal_terms(
                X, covX, uv, np.ascontiguousarray(R, dtype=float), np.ascontiguousarray(t, dtype=float),
                K[0, 0], K[1, 1], K[0, 2], K[1, 2], s2,
            )  # fmt: skip
            try:
                cov = np.asarray(np.linalg.inv(A), dtype=np.float64)
            except np.linalg.LinAlgError:
                break
            if it == 3:
                break
            dx = cov @ g
            dR = exp_nb(np.ascontiguousarray(dx[:3]))
            R, t = dR @ R, dR @ t + dx[3:]
            if np.linalg.norm(dx) < 1e-10:
                break
        # a-posteriori variance factor: when the residuals say the pixels matched worse than the prior
        # sigma (blur, weak texture, motion), the covariance grows with them; it never shrinks below the
        # prior, which also covers what the residuals cannot show (sub-pixel biases shared by a frame)
        dof = max(2 * n - 6, 1)
        vf = float(q.sum()) / dof
        if self.cfg.refit_snooping and n > 6:
            # each residual under its own covariance C - J A^-1 J^T (Baarda 1968, "A testing procedure
            # for use in geodetic networks"; the deleted residual's test of Cook and Weisberg 1982):
            # chi-square(2) for a good point whatever its leverage; where the fit leaves a point
            # (almost) nothing to test, C itself
            q = snooped_q(C, Jd, res, cov)
        return R, t, cov, vf, q

    def _fit(
        self,
        X: FloatArray,
        covX: FloatArray,
        uv: FloatArray,
        ii: NDArray[np.int64],
        R: FloatArray,
        t: FloatArray,
    ) -> tuple[FloatArray, FloatArray, FloatArray, float, NDArray[np.int64]]:
        """:meth:`_refine` on the points ``ii`` from (R, t); with ``refit``, the points whose residual
        chi-square is beyond the ``refit_prob`` quantile are dropped and the fit repeated once: RANSAC's
        pixel threshold lets through tracks several pixel sigmas off, which the weighted fit would
        trust. With ``refit_huber_k``, the points kept are then fitted once more with Huber's weights
        (:meth:`_huber`). Returns R, t, the covariance, the variance factor and the points kept."""
        c = self.cfg
        R, t, cov, vf, q = self._refine(X[ii], covX[ii], uv[ii], R, t)
        if c.refit:
            keep = q <= self._refit_chi2
            if not keep.all() and keep.sum() >= c.min_inliers:
                ii = ii[keep]
                R, t, cov, vf, _ = self._refine(X[ii], covX[ii], uv[ii], R, t)
        if c.refit_huber_k > 0 and len(ii) > 6:
            robust = self._huber(X[ii], covX[ii], uv[ii], R, t)
            if robust is not None:
                R, t, cov = robust
        return R, t, cov, vf, ii

    def _huber(
        self, X: FloatArray, covX: FloatArray, uv: FloatArray, R: FloatArray, t: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray] | None:
        """Three iteratively reweighted Gauss-Newton steps from (R, t) with Huber's weights
        (:func:`imuslam.vio.motion_nb.huber_terms`, ``refit_huber_k``); returns R, t and the covariance
        ``A^-1 B A^-1`` at the prior pixel sigma (M-estimation's sandwich, Huber 1967), or None where
        the weighted normal equations are singular."""
        K = self.rect.K
        s2 = self.cfg.pixel_sigma**2
        X = np.ascontiguousarray(X, dtype=float)
        covX = np.ascontiguousarray(covX, dtype=float)
        uv = np.ascontiguousarray(uv, dtype=float)

        def terms(R: FloatArray, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
            _, _, q, C, Jd, res = normal_terms(
                X, covX, uv, np.ascontiguousarray(R, dtype=float), np.ascontiguousarray(t, dtype=float),
                K[0, 0], K[1, 1], K[0, 2], K[1, 2], s2,
            )  # fmt: skip
            return huber_terms(C, Jd, res, q, self.cfg.refit_huber_k)  # type: ignore[no-any-return]

        try:
            for _ in range(3):
                A, g, _ = terms(R, t)
                dx = np.linalg.solve(A, g)
                dR = exp_nb(np.ascontiguousarray(dx[:3]))
                R, t = dR @ R, dR @ t + dx[3:]
            A, _, B = terms(R, t)
            Ainv = np.linalg.inv(A)
        except np.linalg.LinAlgError:
            return None
        return R, t, np.asarray(Ainv @ B @ Ainv, dtype=np.float64)

    def _affine(self, uv: FloatArray, m: FloatArray, T: FloatArray) -> FloatArray | None:
        """Local maps (N, 2, 2) from previous to current pixel offsets around ``uv`` under the predicted
        motion ``T`` = T_{r_k, r_{k-1}}: the surface ``m . X = 1`` maps by the plane-induced homography
        ``H = K (R + t m^T) K^-1`` (Hartley & Zisserman, "Multiple View Geometry", 2nd ed., eq. 13.2),
        whose Jacobian at ``uv`` is ``(H[:2, :2] - q H[2, :2]) / w`` with ``[q w, w] = H [uv, 1]``. None
        before the first motion is known (no prediction to warp by)."""
        if np.allclose(T, np.eye(4)):
            return None
        K = self.rect.K
        Hs = K @ (T[:3, :3][None] + T[:3, 3][None, :, None] * m[:, None, :]) @ np.linalg.inv(K)
        p = np.c_[uv, np.ones(len(uv))]
        y = np.einsum("nij,nj->ni", Hs, p)
        w = y[:, 2]
        q = y[:, :2] / w[:, None]
        A = (Hs[:, :2, :2] - q[:, :, None] * Hs[:, 2, None, :2]) / w[:, None, None]
        bad = ~(np.isfinite(A).all(axis=(1, 2)) & (w > 0))
        A[bad] = np.eye(2)
        return A

    def _to_body(self, T_k_km1: FloatArray, dt: float) -> FloatArray:
        """[omega_b, vel_b] (6,) from the rectified-camera motion T_{r_k, r_{k-1}}."""
        T_bb = self.T_b_r @ _inv(T_k_km1) @ self.T_r_b  # T_{b_{k-1}, b_k}
        rot = log_nb(np.ascontiguousarray(T_bb[:3, :3]))
        vel = exp_nb(-0.5 * rot) @ T_bb[:3, 3] / dt  # displacement seen from mid-interval
        return np.concatenate([rot / dt, vel])

    def process(
        self, t_ns: int, left_u8: NDArray[np.uint8], right_u8: NDArray[np.uint8]
    ) -> VoMeasurement | None:
        """One rectified stereo pair (uint8, H x W). Returns the motion since the previous pair, or None
        (first frame, or a frame skipped for too few features / inliers: counted in :attr:`stats`)."""
        import cv2

        c = self.cfg
        st = self.stats
        st.frames += 1
        self.last_tracks = None
        sec = st.seconds
        tic = time.perf_counter()
        left: Any = left_u8.astype(np.float32)
        right: Any = right_u8.astype(np.float32)
        if c.blur_sigma > 0:
            left = cv2.GaussianBlur(left, (0, 0), c.blur_sigma)
            right = cv2.GaussianBlur(right, (0, 0), c.blur_sigma)
        left1 = cv2.pyrDown(left)
        tic = _lap(sec, "images", tic)
        meas: VoMeasurement | None = None
        uv_keep = np.zeros((0, 2))
        d_keep = np.zeros(0)
        prev = self._prev
        if prev is not None:
            X = prev["X"]
            Tp = self._T_rel
            Yp = X @ Tp[:3, :3].T + Tp[:3, 3]
            K = self.rect.K
            pred = np.where(
                (Yp[:, 2:3] > 0.05),
                Yp[:, :2] / np.maximum(Yp[:, 2:3], 0.05) * np.diag(K)[:2] + K[:2, 2],
                prev["uv"],
            )
            affine = self._affine(prev["uv"], prev["plane"], Tp) if c.warp else None
            uv_new, _ = track(
                prev["img0"], prev["img1"], left, left1, prev["uv"], pred, c.patch_half,
                c.patch_half_coarse, c.search_coarse_px, c.search_fine_px, c.min_zncc, affine,
            )  # fmt: skip
            tic = _lap(sec, "track", tic)
            self.last_tracks = (prev["uv"], uv_new, np.zeros(0, np.int64))
            ok = np.isfinite(uv_new[:, 0])
            st.tracked.append(int(ok.sum()))
            dt = (t_ns - prev["t_ns"]) * 1e-9
            if ok.sum() < c.min_inliers:
                st.skipped_few_features += 1
                self._T_rel = np.eye(4)
            else:
                Xo, uvo, covo = X[ok], uv_new[ok], prev["covX"][ok]
                rvec0, _ = cv2.Rodrigues(Tp[:3, :3])
                found, rvec, tvec, inl = cv2.solvePnPRansac(
                    Xo, uvo, K, None, rvec0.copy(), Tp[:3, 3].reshape(3, 1).copy(),
                    useExtrinsicGuess=True, iterationsCount=100, reprojectionError=c.ransac_px,
                    confidence=0.999, flags=cv2.SOLVEPNP_ITERATIVE,
                )  # fmt: skip
                n_in = 0 if (not found or inl is None) else len(inl)
                if n_in < c.min_inliers:
                    st.skipped_few_inliers += 1
                    self._T_rel = np.eye(4)
                else:
                    ii = inl.ravel().astype(np.int64)
                    R0, _ = cv2.Rodrigues(rvec)
                    R, t, cov_d, vf, ii = self._fit(
                        Xo, covo, uvo, ii, np.asarray(R0, float), np.asarray(tvec, float).ravel()
                    )
                    n_in = len(ii)
                    T = _se3(R, t)
                    self._T_rel = T
                    z0 = self._to_body(T, dt)
                    J = np.empty((6, 6))
                    eps = 1e-6
                    for j in range(6):
                        dx = np.zeros(6)
                        dx[j] = eps
                        dR = exp_nb(dx[:3].copy())
                        J[:, j] = (self._to_body(_se3(dR @ R, dR @ t + dx[3:]), dt) - z0) / eps
                    T_bb = self.T_b_r @ _inv(T) @ self.T_r_b
                    cov_z = J @ cov_d @ J.T
                    meas = VoMeasurement(
                        prev["t_ns"], t_ns, z0[:3], z0[3:], cov_z * max(vf, 1.0), T_bb, n_in,
                        cov_z, vf,
                    )  # fmt: skip
                    st.measurements += 1
                    st.inliers.append(n_in)
                    keep = np.flatnonzero(ok)[ii]
                    self.last_tracks = (prev["uv"], uv_new, keep)
                    uv_keep = uv_new[keep]
                    z_pred = X[keep] @ R[2] + t[2]
                    d_keep = self.rect.f * self.rect.baseline / np.maximum(z_pred, 1e-3)
            tic = _lap(sec, "motion", tic)
        # next frame's features: the tracked inliers plus new detections, triangulated here
        if len(uv_keep) < c.redetect_below * c.max_features:
            new = self._detect(left_u8, uv_keep, c.max_features - len(uv_keep))
            if len(new):
                uv_keep = np.concatenate([uv_keep, new])
                d_keep = np.concatenate([d_keep, np.full(len(new), np.nan)])
            tic = _lap(sec, "detect", tic)
        uvX, covX = self._triangulate(left, right, uv_keep, d_keep)
        _lap(sec, "stereo", tic)
        self._prev = {
            "t_ns": t_ns, "img0": left, "img1": left1, "uv": uvX[:, :2].copy(),
            "X": uvX[:, 2:5].copy(), "plane": uvX[:, 5:].copy(), "covX": covX,
        }  # fmt: skip
        return meas
