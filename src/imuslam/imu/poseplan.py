"""Gimbal pose plans that determine the 18 calibration parameters better with the same poses.

The predicted covariance of a plan follows the two fits of ``imu/calibrate/`` at nominal parameters:
each pose adds ``m / sigma_a^2 J^T J`` to the accelerometer's information (J the gravity-norm Jacobian of
its mean raw sample, m samples per pose); each move between consecutive poses adds ``J^T J / sigma_r^2`` to
the gyroscope's (J the Jacobian of the predicted-minus-measured gravity direction after integrating the
noise-free gimbal motion; sigma_r^2 = 2 sigma_a^2 / (g^2 m) + sigma_g^2 T / f for a move of T seconds at
rate f), and the accelerometer's uncertainty reaches the gyro through the measured directions, as the
calibrator reports it. The accelerometer's information depends only on the set of poses, the gyro's on
their order: :func:`optimise_order` keeps a well-spread set (a Fibonacci sphere) and orders it so that
every gyro parameter is better determined than in the lattice's own order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imuslam.imu.calibrate.accel import accel_residual_jacobian
from imuslam.imu.calibrate.gyro import gyro_residuals
from imuslam.imu.model import ImuCalibration, TriadModel
from imuslam.interfaces.gimbal import GIMBAL_RESOLUTION_DEG
from imuslam.sim.imu_errors import (
    BWT901CL_ACCEL_DENSITY,
    BWT901CL_GYRO_DENSITY,
    SEED000_ACCEL,
    SEED000_GYRO,
)
from imuslam.sim.multipose import (
    gimbal_kinematics,
    gimbal_up_i,
    min_jerk,
    move_duration_s,
)

FloatArray = NDArray[np.float64]


@dataclass
class PlanModel:
    """Nominal sensor and gimbal used to predict a plan's information."""

    nominal: ImuCalibration
    g: float = 9.80665
    rate_hz: float = 100.0
    samples_per_pose: int = 100
    sigma_a: float = BWT901CL_ACCEL_DENSITY * 10.0  # per sample at 100 Hz, m/s^2
    sigma_g: float = BWT901CL_GYRO_DENSITY * 10.0  # per sample at 100 Hz, rad/s
    joint_speed_dps: float = 90.0
    min_move_s: float = 1.0
    # angle step of the gimbal's joints, deg: seed 000's gimbal 360 / 4096 = 0.088; a hobby servo on a
    # PCA9685 about 0.44 (hw/gimbal.py, ``Pca9685Gimbal.resolution_deg``). Plans are predicted at the
    # angles the gimbal can reach (:meth:`reachable`).
    resolution_deg: float = GIMBAL_RESOLUTION_DEG

    def reachable(self, angles_deg: FloatArray) -> FloatArray:
        """The joint angles (P, 2) the gimbal actually reaches for commanded ``angles_deg`` (P, 2)."""
        return np.asarray(
            np.round(np.asarray(angles_deg, float) / self.resolution_deg) * self.resolution_deg
        )

    @classmethod
    def seed000(cls) -> PlanModel:
        a, g = SEED000_ACCEL, SEED000_GYRO
        return cls(ImuCalibration(TriadModel(a.T, a.K, a.b), TriadModel(g.T, g.K, g.b)))

    def accel_info(self, angles_deg: FloatArray) -> FloatArray:
        """Information (P, 9, 9) of each pose for the accelerometer parameters."""
        f = self.g * gimbal_up_i(self.reachable(angles_deg))
        raw = self.nominal.accel.invert(f)
        sign = 1.0 if self.nominal.accel.bias_sign == "plus" else -1.0
        _, J = accel_residual_jacobian(self.nominal.accel_params, raw, self.g, sign)
        return self.samples_per_pose / self.sigma_a**2 * J[:, :, None] * J[:, None, :]

    def gyro_terms(
        self, start_deg: FloatArray, targets_deg: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """For the move from ``start_deg`` to each target: ``w J^T J`` and ``w J^T D`` (P, 9, 9), with J the
        Jacobian of the gravity-direction residual in the gyro parameters, D its Jacobian in the
        accelerometer parameters (through the measured directions) and w = 1 / sigma_r^2."""
        P = len(targets_deg)
        JtJ = np.zeros((P, 9, 9))
        JtD = np.zeros((P, 9, 9))
        th = self.nominal.gyro_params
        step = np.concatenate([np.full(6, 1e-6), np.abs(th[6:9]) * 1e-6])
        tha = self.nominal.accel_params
        step_a = np.concatenate([np.full(3, 1e-6), np.abs(tha[3:6]) * 1e-6, np.full(3, 1e-6)])
        sign = 1.0 if self.nominal.accel.bias_sign == "plus" else -1.0
        start_deg = self.reachable(start_deg)
        for i, tgt in enumerate(self.reachable(targets_deg)):
            d = tgt - start_deg
            T = move_duration_s(d, self.joint_speed_dps, self.min_move_s)
            t = np.arange(0.0, T + 1e-9, 1.0 / self.rate_hz)
            s, ds = min_jerk(t / T)
            R, f, w = gimbal_kinematics(start_deg + s[:, None] * d, (ds / T)[:, None] * d, self.g)
            w_raw = self.nominal.gyro.invert(w) - self.nominal.gyro.invert(np.zeros((1, 3)))
            u0, u1 = f[:1] / self.g, f[-1:] / self.g
            stack = np.repeat(th[None], 10, axis=0)
            stack[1:] += np.diag(step)
            r = gyro_residuals(stack, w_raw, t, np.array([[0, len(t) - 1]]), u0, u1)
            J = ((r[1:] - r[0]) / step[:, None]).T  # (3, 9)
            # D: measured directions from the calibrated accelerometer means, rotation fixed
            R01 = R[0].T @ R[-1]
            raw = self.nominal.accel.invert(np.vstack([f[0], f[-1]]))
            D = np.zeros((3, 9))
            for j in range(9):
                tp = tha.copy()
                tp[j] += step_a[j]
                Tm = np.array([[1.0, -tp[0], tp[1]], [0.0, 1.0, -tp[2]], [0.0, 0.0, 1.0]])
                m = ((raw + sign * tp[6:9]) * tp[3:6]) @ Tm.T
                uu = m / np.linalg.norm(m, axis=1, keepdims=True)
                D[:, j] = (R01.T @ uu[0] - uu[1] - (R01.T @ u0[0] - u1[0])) / step_a[j]
            var = (
                2 * self.sigma_a**2 / (self.g**2 * self.samples_per_pose)
                + self.sigma_g**2 * T / self.rate_hz
            )
            JtJ[i] = J.T @ J / var
            JtD[i] = J.T @ D / var
        return JtJ, JtD

    def gyro_info(self, start_deg: FloatArray, targets_deg: FloatArray) -> FloatArray:
        """Information (P, 9, 9) of the move from ``start_deg`` to each target, gyro parameters."""
        return self.gyro_terms(start_deg, targets_deg)[0]

    def gyro_cov(self, JtJ: FloatArray, JtD: FloatArray, cov_accel: FloatArray) -> FloatArray:
        """Gyro covariance (9, 9) from summed terms: noise part plus the accelerometer calibration's
        uncertainty carried through the measured directions (as ``imu/calibrate/`` reports it)."""
        Ainv = np.linalg.inv(JtJ)
        return np.asarray(Ainv + Ainv @ JtD @ cov_accel @ JtD.T @ Ainv, dtype=np.float64)

    def predicted_std(self, plan_deg: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Predicted 1-sigma (accelerometer (9,), gyroscope (9,)) of a plan, as the calibration reports it."""
        p = np.asarray(plan_deg, float)
        cov_a = np.linalg.pinv(self.accel_info(p).sum(axis=0))
        JtJ = np.zeros((9, 9))
        JtD = np.zeros((9, 9))
        for k in range(len(p) - 1):
            a, b = self.gyro_terms(p[k], p[k + 1 : k + 2])
            JtJ += a[0]
            JtD += b[0]
        return np.sqrt(np.diag(cov_a)), np.sqrt(np.diag(self.gyro_cov(JtJ, JtD, cov_a)))


def optimise_order(
    model: PlanModel,
    poses_deg: FloatArray,
    target_gyro_std: FloatArray | None = None,
    iterations: int = 4000,
    seed: int = 0,
) -> FloatArray:
    """The same poses (P, 2), the first kept first, in the order that best determines the gyroscope.

    The accelerometer's information depends only on the set of poses, so it is unchanged; the gyro's terms
    are sums over consecutive moves. Start from a greedy D-optimal order, then improve it by local search
    (2-opt reversals and swaps) on the worst ratio of predicted to target variance when
    ``target_gyro_std`` (9,) is given, else on the log det of the predicted gyro covariance.
    """
    p = np.asarray(poses_deg, float)
    P = len(p)
    terms = [model.gyro_terms(p[i], p) for i in range(P)]
    JtJ = np.stack([t[0] for t in terms])
    JtD = np.stack([t[1] for t in terms])
    cov_a = np.linalg.pinv(model.accel_info(p).sum(axis=0))

    def cost(order: list[int]) -> float:
        i, j = order[:-1], order[1:]
        C = model.gyro_cov(JtJ[i, j].sum(axis=0), JtD[i, j].sum(axis=0), cov_a)
        if target_gyro_std is None:
            return float(np.linalg.slogdet(C)[1])
        v = np.diag(C) / target_gyro_std**2
        return float(np.max(v) + 1e-3 * np.sum(v))

    rest = list(range(1, P))
    order = [0]
    Ig = np.zeros((9, 9))
    prior = np.eye(9) * 1e-6 * np.trace(JtJ.mean(axis=(0, 1))) / 9
    while rest:
        cand = JtJ[order[-1], rest]
        k = int(np.argmax(np.linalg.slogdet(Ig + prior + cand)[1]))
        Ig = Ig + cand[k]
        order.append(rest.pop(k))
    rng = np.random.default_rng(seed)
    best = cost(order)
    for _ in range(iterations):
        i, j = sorted(rng.choice(np.arange(1, P), size=2, replace=False))
        if rng.uniform() < 0.5:
            trial = order[:i] + order[i : j + 1][::-1] + order[j + 1 :]
        else:
            trial = order.copy()
            trial[i], trial[j] = trial[j], trial[i]
        c = cost(trial)
        if c < best:
            best, order = c, trial
    return p[order]


def plan_for_target(
    model: PlanModel,
    target_accel_std: FloatArray,
    target_gyro_std: FloatArray,
    min_poses: int = 12,
    max_poses: int = 50,
    iterations: int = 1500,
) -> FloatArray:
    """The shortest plan (a Fibonacci sphere of N poses, ordered by :func:`optimise_order`) whose predicted
    standard deviations all meet the targets (accelerometer (9,), gyroscope (9,)).

    Raises ValueError when even ``max_poses`` poses cannot meet them.
    """
    from imuslam.sim.multipose import sphere_plan_deg

    lo, hi = min_poses, max_poses
    best: FloatArray | None = None
    while lo <= hi:  # the accelerometer's stds fall monotonically with N: bisect on N
        n = (lo + hi) // 2
        plan = optimise_order(model, sphere_plan_deg(n), target_gyro_std, iterations)
        sa, sg = model.predicted_std(plan)
        if np.all(sa <= target_accel_std) and np.all(sg <= target_gyro_std):
            best, hi = plan, n - 1
        else:
            lo = n + 1
    if best is None:
        raise ValueError(
            f"no plan of at most {max_poses} poses meets the target standard deviations"
        )
    return best
