"""Joint refinement stage: the two-step calibration refined as one weighted least squares of both triads
(``imu/joint.py``), with its optional terms (g-sensitivity, accelerometer bias drift) kept only when
significant and the gravity-norm weight chosen when the data ask for it.

Imported only by the joint method: it loads scipy.special and the compiled integrator.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.special import chdtri  # chi-square quantile (scipy.stats costs ~1 s to import)

from imuslam.imu.calibrate.accel import AccelFit, accel_model_parts
from imuslam.imu.calibrate.config import CalibrationConfig, Estimate
from imuslam.imu.calibrate.gyro import GyroFit, gyro_rate_matrix, motion_compensated_means
from imuslam.imu.joint import JointFit, JointInputs, JointSettings, joint_refine, measured_noise
from imuslam.imu.model import TriadModel, misalignment_matrix
from imuslam.imu.rk4 import integrate_segments
from imuslam.interfaces.imu import ImuLog

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass
class JointPoses:
    """What the joint fit compares, pose by pose and rotation by rotation.

    segs: (S, 2) sample ranges integrated between the poses; pose_means / gyro_means: (K, 3) raw
    accelerometer mean and raw gyro mean (less the still-period bias) of each pose's still part; pose_n:
    (K,) samples in it; pose_t: (K,) time of each pose's middle, s; noise: the measured 1-sigma of every
    residual (``measured_noise``) or None; f_c: (N, 3) calibrated specific force ((1, 3) zeros without
    the g-sensitivity term).
    """

    segs: IntArray
    pose_means: FloatArray
    gyro_means: FloatArray
    pose_n: FloatArray
    pose_t: FloatArray
    noise: tuple[FloatArray, FloatArray, FloatArray] | None
    f_c: FloatArray


def joint_poses(
    log_: ImuLog,
    accel: AccelFit,
    accel_model: TriadModel,
    gyro: GyroFit,
    n_init: int,
    cfg: CalibrationConfig,
) -> JointPoses:
    """The poses and rotations of the joint fit from the two-step calibration."""
    acc, t_s, rate = log_.accel, log_.t_s, log_.rate_hz
    iv, sg = accel.detection.valid, gyro.segments
    pairs, w, theta_a, theta_g = sg.pairs, sg.w, accel.theta, gyro.theta
    f_c = accel_model.apply(acc) if cfg.gyro_g_sensitivity else np.zeros((1, 3))
    # Each pose is referred to the middle sample of its interval, and the gyro is integrated from
    # one pose's middle to the next's (still parts included: the bias is estimated). The slow ends
    # of motion the accelerometer detector took for still are turned back into the pose's frame at
    # that middle sample with the gyro (motion-compensated means), instead of being cut at a guess.
    # The static-rate means use each pose's still part only: between the ends of the gyro segments
    # that reach into its interval while the rate is above the still-period noise.
    segs = sg.segs_rest if cfg.gyro_ends == "rest" else sg.segs
    still = iv.copy()
    still[pairs[:, 1], 0] = np.maximum(still[pairs[:, 1], 0], segs[:, 1])
    still[pairs[:, 0], 1] = np.minimum(still[pairs[:, 0], 1], segs[:, 0])
    short = still[:, 1] - still[:, 0] < 20
    still[short] = iv[short]
    if cfg.joint_poses == "middle":
        refs = (iv[:, 0] + iv[:, 1]) // 2
        segs = np.stack([refs[pairs[:, 0]], refs[pairs[:, 1]]], axis=1)
        pose_means = motion_compensated_means(
            acc, accel_model, w @ gyro_rate_matrix(theta_g[:9]).T, t_s, iv, refs
        )
    else:  # "still": plain means of the still parts, gyro segments between them
        pose_means = np.stack([acc[s : e + 1].mean(axis=0) for s, e in still])
    gyro_means = np.stack([w[s : e + 1].mean(axis=0) for s, e in still])
    pose_n = (still[:, 1] - still[:, 0] + 1).astype(float)
    noise = None
    if cfg.joint_weights == "measured":
        sig_a = np.std(acc[: n_init + 1], axis=0, ddof=1) * np.abs(theta_a[3:6])
        sig_w = np.std(log_.gyro[: n_init + 1], axis=0, ddof=1) * np.abs(theta_g[6:9])
        noise = measured_noise(sig_a, sig_w, pose_n, t_s[segs[:, 1]] - t_s[segs[:, 0]], 1.0 / rate)
    pose_t = t_s[(iv[:, 0] + iv[:, 1]) // 2]
    return JointPoses(segs, pose_means, gyro_means, pose_n, pose_t, noise, f_c)


def wald(jf: JointFit, a: int, b: int, x: FloatArray) -> float:
    """Wald statistic x^T C^-1 x of the parameters [a, b) of the fit (Koch 1999, sec. 4.2)."""
    try:
        return float(x @ np.linalg.solve(jf.cov[a:b, a:b], x))
    except np.linalg.LinAlgError:
        return float("inf")


class JointRefinement:
    """The joint fit over fixed poses, refitted as its optional terms are tested.

    Steps: :meth:`fit` (one weighted least squares), :meth:`select_terms` (Wald tests of the
    g-sensitivity and the drift), :meth:`balance_norm` (the gravity-norm weight), :meth:`estimate`.
    """

    def __init__(
        self,
        log_: ImuLog,
        accel: AccelFit,
        gyro: GyroFit,
        poses: JointPoses,
        cfg: CalibrationConfig,
    ) -> None:
        self.log_, self.accel, self.gyro, self.poses, self.cfg = log_, accel, gyro, poses, cfg
        self.sign = 1.0 if cfg.bias_sign == "plus" else -1.0
        self.use_g = cfg.gyro_g_sensitivity
        self.with_drift = cfg.accel_bias_drift is not False
        self.lam = 1.0 if cfg.norm_weight == "auto" else float(cfg.norm_weight)
        self.n_b = 3 if (cfg.estimate_gyro_bias or cfg.gyro_g_sensitivity) else 0
        self.wald_notes: dict[str, float] = {}

    def fit(self, with_g: bool, with_drift: bool, norm_weight: float = 1.0) -> JointFit:
        """One joint weighted least squares with the given optional terms."""
        cfg, p, sg = self.cfg, self.poses, self.gyro.segments
        inputs = JointInputs(
            means=p.pose_means, gyro_means=p.gyro_means, w=sg.w, f=p.f_c, t_s=self.log_.t_s,
            segs=p.segs, pairs=sg.pairs, theta_a0=self.accel.theta, theta_g0=self.gyro.theta[:9],
            pose_t=p.pose_t if with_drift else None,
            pose_n=p.pose_n if cfg.weigh_by_length else None, noise=p.noise,
        )  # fmt: skip
        settings = JointSettings(
            g=cfg.g,
            sign=self.sign,
            estimate_bias=cfg.estimate_gyro_bias or cfg.gyro_g_sensitivity,
            estimate_g_sensitivity=with_g,
            norm_weight=norm_weight,
        )
        return joint_refine(inputs, settings, integrate_segments)

    def select_terms(self) -> JointFit:
        """Optional terms are fitted and kept only if significant (Wald test at 99.9 %): an insignificant
        g-sensitivity or bias drift only adds variance to the parameters that matter."""
        cfg, n_b = self.cfg, self.n_b
        jf = self.fit(self.use_g, self.with_drift, self.lam)
        test_g = self.use_g and cfg.g_sensitivity_test
        test_d = self.with_drift and cfg.accel_bias_drift == "auto"
        if test_g and test_d:
            # Closed testing (Marcus, Peritz & Gabriel 1976, Biometrika 63): a term is kept only if the
            # hypothesis "neither term" is rejected too (one Wald test of G and the drift together, 12
            # dof, 99.9 %), so the chance of keeping any term on a log that has neither is at most
            # 0.1 %, where two separate tests allow 0.2 %.
            a = 18 + n_b
            w_both = wald(jf, a, a + 12, np.concatenate([jf.G.ravel(), jf.drift]))
            log.debug("g-sensitivity and drift together: Wald statistic %.1f (12 dof)", w_both)
            self.wald_notes["g_sensitivity_and_accel_bias_drift_12dof"] = w_both
            if w_both < float(chdtri(12, 1.0 - 0.999)):
                self.use_g = test_g = self.with_drift = test_d = False
                jf = self.fit(False, False, self.lam)
        if test_g:
            w_G = wald(jf, 18 + n_b, 27 + n_b, jf.G.ravel())
            log.debug("g-sensitivity Wald statistic %.1f (9 dof)", w_G)
            self.wald_notes["g_sensitivity_9dof"] = w_G
            if w_G < float(chdtri(9, 1.0 - 0.999)):
                self.use_g = False
                log.debug("g-sensitivity not significant (Wald %.1f): left out", w_G)
                jf = self.fit(False, self.with_drift, self.lam)
        if test_d:
            a = 18 + n_b + (9 if self.use_g else 0)
            w_d = wald(jf, a, a + 3, jf.drift)
            log.debug("accelerometer bias drift Wald statistic %.1f (3 dof)", w_d)
            self.wald_notes["accel_bias_drift_3dof"] = w_d
            if w_d < float(chdtri(3, 1.0 - 0.999)):
                self.with_drift = False
                log.debug("accelerometer bias drift not significant (Wald %.1f): left out", w_d)
                jf = self.fit(self.use_g, False, self.lam)
        return jf

    def norm_rms(self, th: FloatArray) -> float:
        """Gravity-norm RMS over the poses of the accelerometer ``th`` with a constant bias."""
        T, Kd, off = accel_model_parts(th, self.sign)
        e = np.linalg.norm(((self.poses.pose_means + off) * Kd) @ T.T, axis=1) - self.cfg.g
        return float(np.sqrt(np.mean(e**2)))

    def balance_norm(self, jf: JointFit) -> JointFit:
        """An unmodelled error (in-session drift) makes the rotations and the gravity norms disagree;
        the calibration file keeps one constant bias, so its gravity norm is kept no worse than the
        norm-only (two-step) fit's on the same poses, at the least cost in direction."""
        if not (self.cfg.norm_weight == "auto" and jf.accel_misfit):
            return jf
        ref = self.norm_rms(self.accel.theta)
        for lam in (2.0, 4.0, 8.0):
            self.lam = lam
            if self.norm_rms(jf.theta_a) <= ref:
                break
            jf = self.fit(self.use_g, self.with_drift, lam)
        log.debug("gravity-norm weight %g (norm-only fit: %.5f m/s^2)", self.lam, ref)
        return jf

    def estimate(self, jf: JointFit) -> Estimate:
        """The calibration of the fit ``jf``, with the directions and residuals it implies."""
        cfg, sg, p = self.cfg, self.gyro.segments, self.poses
        notes: dict[str, object] = {"gravity_norm_weight": self.lam}
        if self.wald_notes:
            notes["wald_statistics"] = self.wald_notes
        if self.with_drift:
            # the fitted bias is the one at the mean of the poses' times (their average bias)
            notes |= {
                "accel_bias_drift_per_s": jf.drift.tolist(),
                "accel_bias_drift_t_ref_s": float(np.mean(p.pose_t)),
            }
        theta_a = jf.theta_a
        cov_bias = (
            jf.cov[18:21, 18:21]
            if cfg.estimate_gyro_bias or cfg.gyro_g_sensitivity
            else self.gyro.cov_bias
        )
        log.debug("joint fit noise levels: %s", jf.sigmas)
        accel_model = TriadModel(
            misalignment_matrix(*theta_a[:3]), theta_a[3:6], theta_a[6:9], cfg.bias_sign
        )
        means_c = accel_model.apply(p.pose_means)
        u = means_c / np.linalg.norm(means_c, axis=1, keepdims=True)
        iv, nmin = self.accel.detection.valid, cfg.samples_per_interval
        idx = (iv[:, 0][:, None] + np.arange(nmin)[None, :]).ravel()
        r_a = cfg.g - np.linalg.norm(accel_model.apply(self.log_.accel[idx]), axis=1)
        return Estimate(
            theta_a=theta_a,
            theta_g=jf.theta_g,
            db=jf.db,
            G=jf.G if self.use_g else None,
            bias_total=sg.gyro_bias + jf.db,
            cov_a=jf.cov[:9, :9],
            cov_g=jf.cov[9:18, 9:18],
            cov_bias=cov_bias,
            accel_model=accel_model,
            u0=u[sg.pairs[:, 0]],
            u1=u[sg.pairs[:, 1]],
            segs=p.segs,
            r_a=r_a,
            f_c=p.f_c,
            notes=notes,
        )


def refine_jointly(
    log_: ImuLog,
    accel: AccelFit,
    accel_model: TriadModel,
    gyro: GyroFit,
    n_init: int,
    cfg: CalibrationConfig,
) -> Estimate:
    """The joint stage: poses, term selection, gravity-norm weight, estimate."""
    poses = joint_poses(log_, accel, accel_model, gyro, n_init, cfg)
    ref = JointRefinement(log_, accel, gyro, poses, cfg)
    jf = ref.balance_norm(ref.select_terms())
    return ref.estimate(jf)
