"""Joint maximum-likelihood refinement of the accelerometer and gyroscope calibration.

Tedaldi 2014 solves the accelerometer from the gravity norm alone, then the gyroscope with the
accelerometer held fixed. But the gravity *directions* the gyro fit compares depend on the
accelerometer's misalignment and scales, which the norm barely constrains when the poses are few or
clustered; the rotations the gyro measures between poses carry that information. Here both triads (and
optionally a gyro bias correction) are estimated in one weighted least squares over

- the gravity norm of every static pose: ``r_i = (|T_a K_a (a_i ± b_a)| - g) / sigma_n``,
- the gravity direction predicted across every rotation: ``r_s = (R_s^T u_i - u_j) / sigma_d`` with
  ``u = h / |h|`` the calibrated direction of each pose and ``R_s`` the calibrated gyro integrated
  between the poses (Tedaldi 2014, eqs. 13-14),

- optionally, the gyro rate measured at every static pose: ``r_i = (M_g (w_i - db) - G f_i) / sigma_w``,
  which should be zero there; with ``db`` a bias correction and ``G`` the gyro's g-sensitivity (its bias
  moving with the specific force ``f``), which then also enters the rates integrated between poses:
  ``omega = M_g (w - db) - G f``,

with every residual weighted by its noise measured in the still period (``noise``, see
:func:`measured_noise`: white noise of each pose's mean, angle random walk over each rotation), so the
covariance ``(J^T W J)^-1`` holds when the model holds; each group's a-posteriori variance factor is then
tested (chi-square, 99.7 %) and a group whose misfit is significantly above its noise widens the
covariance (sandwich form). Without ``noise``, the noise levels of the groups are estimated from the
data by variance-component estimation (Foerstner 1979; Koch, Parameter Estimation and Hypothesis
Testing, 1999, sec. 3.6): ``sigma_k^2 = ||r_k||^2 / rho_k``, ``rho_k`` the redundancy of group k,
iterated with the least squares until the weights settle; that estimate has few degrees of freedom for
the accelerometer group and left its covariance about 10 % optimistic on simulation.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import solve_triangular
from scipy.special import chdtri  # chi-square quantile; scipy.stats costs ~1 s to import

from imuslam.imu.model import misalignment_matrix

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass
class JointFit:
    """Result of :func:`joint_refine`.

    theta_a: (9,) accelerometer parameters (order of ``ACCEL_PARAM_NAMES``, bias in the fit's sign).
    theta_g: (9,) gyro misalignments and scales (order of ``GYRO_PARAM_NAMES``).
    db: (3,) correction added to the gyro bias (raw units; zero when not estimated).
    G: (3, 3) gyro g-sensitivity, rad/s per m/s^2 (zero when not estimated).
    cov: (P, P) covariance of ``[theta_a, theta_g, db?, G?]`` (the optional blocks when estimated).
    sigmas: noise of each residual group (norm m/s^2, direction component, static rate rad/s).
    """

    theta_a: FloatArray
    theta_g: FloatArray
    db: FloatArray
    G: FloatArray
    cov: FloatArray
    sigmas: dict[str, float]
    drift: FloatArray  # (3,) accelerometer bias drift, raw units per s (zero when not estimated)
    norm_residual: FloatArray  # (K,) |h| - g, m/s^2
    dir_residual: FloatArray  # (S, 3) R^T u_i - u_j
    iterations: int
    # whether the accelerometer residuals exceed their measured noise significantly (chi-square, 99.7 %;
    # False without measured noise)
    accel_misfit: bool = False
    cost: float = float("nan")  # weighted sum of squared residuals at the solution


def _accel_h(theta_a: FloatArray, means: FloatArray, sign: float) -> FloatArray:
    T = misalignment_matrix(theta_a[0], theta_a[1], theta_a[2])
    return ((means + sign * theta_a[6:9]) * theta_a[3:6]) @ T.T


def _gyro_M(theta_g: FloatArray) -> FloatArray:
    return misalignment_matrix(*theta_g[:6]) * theta_g[6:9][None, :]


def _inv_normal(J: FloatArray) -> FloatArray:
    """``(J^T J)^-1`` by Cholesky (pseudo-inverse if J is rank deficient)."""
    N = J.T @ J
    try:
        L = np.linalg.cholesky(N)
    except np.linalg.LinAlgError:
        return np.asarray(np.linalg.pinv(N), dtype=np.float64)
    Li = solve_triangular(L, np.eye(len(N)), lower=True)
    return np.asarray(Li.T @ Li, dtype=np.float64)


def _hat_diagonal(J: FloatArray) -> FloatArray:
    """Diagonal of the hat matrix ``J (J^T J)^-1 J^T`` (each residual's share of the parameters)."""
    try:
        L = np.linalg.cholesky(J.T @ J)
    except np.linalg.LinAlgError:
        return np.asarray(np.einsum("ij,jk,ik->i", J, np.linalg.pinv(J.T @ J), J))
    Z = solve_triangular(L, J.T, lower=True)
    return np.asarray(np.sum(Z * Z, axis=0))


@dataclass
class JointInputs:
    """What :func:`joint_refine` fits.

    means: (K, 3) raw accelerometer mean of each static pose; gyro_means: (K, 3) raw gyro mean of each
        pose minus the still-period bias.
    w: (N, 3) gyro samples minus the still-period bias, raw units; f: (N, 3) calibrated specific force
        (m/s^2, from the starting accelerometer model; only the g-sensitivity term uses it); t_s: (N,) s.
    segs: (S, 2) sample ranges integrated between poses ``pairs`` (S, 2) (indices into ``means``).
    theta_a0: (9,) and theta_g0: (9,) the starting accelerometer and gyro parameters.
    accel_free: (9,) which accelerometer parameters the fit moves (default all); the others stay at
        ``theta_a0`` and get no covariance here (zero rows and columns).
    pose_t: (K,) time of each pose, s: when given, the accelerometer bias drifts linearly,
        ``b(t) = b + beta (t - t_mean)`` (beta a nuisance), and ``theta_a`` holds the bias at ``t_mean``,
        the mean of the poses' times: the bias averaged over the poses, the best constant to predict
        poses of the session with (the middle of their time span held out 0.0101 m/s^2 on t265 against
        0.0094, ``bench/calibrate_cv.py``).
    pose_n: (K,) samples averaged in each pose: its accelerometer and static-rate residuals are weighted
        by ``sqrt(n_i / mean(n))`` (white noise); default equal weights.
    noise: measured 1-sigma of every residual, ``(sigma_accel (K,), sigma_dir (S,), sigma_rate (K,))``
        (per component, calibrated units; from the still-period noise, see :func:`measured_noise`): each
        residual is weighted by it and the weights stay fixed (no variance components; ``pose_n`` is then
        ignored). At the solution each group's a-posteriori variance factor ``||r_k||^2 / rho_k`` is
        tested against chi-square with ``rho_k`` degrees of freedom (99.7 %); a group whose misfit
        exceeds its noise significantly (unmodelled errors: drift, vibration) gets the sandwich covariance
        ``N^-1 J^T C J N^-1`` with ``C`` its factor, so the reported covariance stays honest either way.
    """

    means: FloatArray
    gyro_means: FloatArray
    w: FloatArray
    f: FloatArray
    t_s: FloatArray
    segs: IntArray
    pairs: IntArray
    theta_a0: FloatArray
    theta_g0: FloatArray
    accel_free: NDArray[np.bool_] | None = None
    pose_t: FloatArray | None = None
    pose_n: FloatArray | None = None
    noise: tuple[FloatArray, FloatArray, FloatArray] | None = None


@dataclass(frozen=True)
class JointSettings:
    """How :func:`joint_refine` fits.

    g: gravity magnitude, m/s^2; sign: +1 or -1, the accelerometer bias sign of ``x_S ± b``;
    estimate_bias: fit a gyro bias correction (and the static-rate residuals); estimate_g_sensitivity:
    fit the gyro's g-sensitivity G (implies the static-rate residuals);
    norm_weight: factor (>= 1) on the weight of each pose's gravity-norm error ``|h_i| - g`` (the radial
        part of its accelerometer residual): rows ``sqrt(norm_weight^2 - 1) (|h_i| - g) w_i`` are added,
        so that part of the residual weighs ``norm_weight`` times its noise. A bias that drifts within
        the log is not in the model; where it is, the misalignments the rotations demand cost gravity
        norm, and this factor sets that trade (1: the measured-noise optimum).
    max_iter: Levenberg-Marquardt iterations at most.
    """

    g: float
    sign: float
    estimate_bias: bool
    estimate_g_sensitivity: bool
    norm_weight: float = 1.0
    max_iter: int = 50


class JointProblem:
    """The weighted least-squares problem of :func:`joint_refine`: parameters, residuals, Jacobian.

    The parameter vector is ``[theta_a (9), theta_g (9), db (3)?, G (9)?, drift (3)?, delta (2 K)]``, the
    last block each pose's gravity direction ``u_i = normalise(u0_i + B_i delta_i)`` with ``B_i`` (3, 2)
    an orthonormal tangent basis; only the ``free`` entries move. The residual groups are the poses'
    accelerometer, the rotations' directions, the poses' static rates and the extra gravity-norm rows,
    each scaled by its entry of ``weights`` (the variance components).
    """

    def __init__(
        self, inp: JointInputs, cfg: JointSettings, integrate: Callable[..., FloatArray]
    ) -> None:
        self.inp, self.cfg, self.integrate = inp, cfg, integrate
        means, theta_a0, theta_g0 = inp.means, inp.theta_a0, inp.theta_g0
        self.use_static = cfg.estimate_bias or cfg.estimate_g_sensitivity
        self.n_b = n_b = 3 if self.use_static else 0
        self.n_G = n_G = 9 if cfg.estimate_g_sensitivity else 0
        self.n_d = n_d = 3 if inp.pose_t is not None else 0
        self.dt_pose = (
            np.zeros(len(means)) if inp.pose_t is None else inp.pose_t - np.mean(inp.pose_t)
        )
        self.K, self.S = K, S = len(means), len(inp.segs)
        self.n_th = (
            18 + n_b + n_G + n_d
        )  # calibration parameters; then 2 per pose for its direction
        self.x_full0 = np.concatenate([theta_a0, theta_g0[:9], np.zeros(n_b + n_G + n_d + 2 * K)])
        self.free = np.ones(self.x_full0.size, dtype=bool)
        if inp.accel_free is not None:
            self.free[:9] = inp.accel_free
        # Each pose's direction u_i = normalise(u0_i + B_i delta_i), B_i (3, 2) an orthonormal tangent basis.
        h0 = _accel_h(theta_a0, means, cfg.sign)
        self.u0 = u0 = h0 / np.linalg.norm(h0, axis=1, keepdims=True)
        helper = np.where(
            np.abs(u0[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]])
        )
        e1 = np.cross(u0, helper)
        e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
        self.e1, self.e2 = e1, np.cross(u0, e1)
        self.n_gyro = 9 + n_b + n_G  # parameters whose columns need an integration
        kg = np.abs(theta_g0[6:9])
        scale = np.concatenate(
            [
                np.full(3, 1e-3),
                np.abs(theta_a0[3:6]),
                1e-2 / np.abs(theta_a0[3:6]),
                np.full(6, 1e-2),
                kg,
                np.full(3, 1e-3) / kg if n_b else np.zeros(0),
                np.full(n_G, 1e-4),
                1e-5 / np.abs(theta_a0[3:6]) if n_d else np.zeros(0),
                np.full(2 * K, 1e-3),
            ]
        )
        self.step = scale * 1e-5
        self.x0 = self.x_full0[self.free]
        self.P = self.x0.size
        self.extra_w = float(np.sqrt(max(cfg.norm_weight**2 - 1.0, 0.0)))
        self.n_rows = [3 * K, 3 * S, 3 * K if self.use_static else 0, K if self.extra_w > 0 else 0]
        self.weights = np.ones(4)
        wp = (
            np.ones((K, 1))
            if inp.pose_n is None
            else np.sqrt(inp.pose_n / np.mean(inp.pose_n))[:, None]
        )
        wd = np.ones((S, 1))
        wr = wp
        if inp.noise is not None:
            wp = 1.0 / np.asarray(inp.noise[0], dtype=np.float64).reshape(K, 1)
            wd = 1.0 / np.asarray(inp.noise[1], dtype=np.float64).reshape(S, 1)
            wr = 1.0 / np.asarray(inp.noise[2], dtype=np.float64).reshape(K, 1)
        self.wp, self.wd, self.wr = wp, wd, wr
        self.bounds = np.cumsum([0, *self.n_rows])
        self.dof = [3 * K, 2 * S, 3 * K]  # each direction residual has 2 dof (unit vectors)

    def full(self, z: FloatArray) -> FloatArray:
        """The whole parameter vector from its free entries ``z``."""
        x = self.x_full0.copy()
        x[self.free] = z
        return x

    def unpack(self, x: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """``theta_a`` (9,), ``theta_g`` (9,), ``db`` (3,), ``G`` (3, 3) of a parameter vector."""
        n_b = self.n_b
        db = x[18:21] if n_b else np.zeros(3)
        G = x[18 + n_b : 27 + n_b].reshape(3, 3) if self.n_G else np.zeros((3, 3))
        return x[:9], x[9:18], db, G

    def drift(self, x: FloatArray) -> FloatArray:
        """(K, 3) accelerometer bias drift at each pose, raw units."""
        if not self.n_d:
            return np.zeros_like(self.inp.means)
        return self.dt_pose[:, None] * x[18 + self.n_b + self.n_G : self.n_th][None, :]

    def pose_u(self, x: FloatArray) -> FloatArray:
        """(K, 3) the poses' gravity directions."""
        d = x[self.n_th :].reshape(self.K, 2)
        v = self.u0 + self.e1 * d[:, :1] + self.e2 * d[:, 1:]
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    def gyro_rot(self, xs: FloatArray) -> FloatArray:
        """Rotations (Q, S, 3, 3) for the gyro parts of parameter vectors xs (Q, P)."""
        inp = self.inp
        parts = [self.unpack(x) for x in xs]
        Ms = np.stack([_gyro_M(p[1]) for p in parts])
        offs = np.stack([p[2] for p in parts])
        if self.n_G:
            Gs = np.stack([p[3] for p in parts])
            return self.integrate(inp.w, inp.t_s, inp.segs, Ms, offs, Gs, inp.f)
        return self.integrate(inp.w, inp.t_s, inp.segs, Ms, offs)

    def raw_resid(
        self, x: FloatArray, R: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Unweighted residuals: accelerometer (K, 3), direction (S, 3), static rate (K, 3) or (0, 3),
        gravity norm (K,), for the rotations ``R`` (S, 3, 3) of ``x``."""
        inp, g, sign, pairs = self.inp, self.cfg.g, self.cfg.sign, self.inp.pairs
        th_a, th_g, db, G = self.unpack(x)
        h = _accel_h(th_a, inp.means + sign * self.drift(x), sign)
        u = self.pose_u(x)
        rn = (
            h - g * u
        )  # the accelerometer measures g along the pose's direction (norm and direction)
        rd = np.einsum("sji,sj->si", R, u[pairs[:, 0]]) - u[pairs[:, 1]]
        rw = (
            (inp.gyro_means - db) @ _gyro_M(th_g).T - h @ G.T
            if self.use_static
            else np.zeros((0, 3))
        )
        return rn, rd, rw, np.linalg.norm(h, axis=1) - g

    def stack(self, rn: FloatArray, rd: FloatArray, rw: FloatArray, rx: FloatArray) -> FloatArray:
        """The weighted residual vector."""
        weights, wp, extra_w = self.weights, self.wp, self.extra_w
        rw = rw * self.wr if rw.size else rw
        return np.concatenate(
            [
                (rn * wp).ravel() * weights[0],
                (rd * self.wd).ravel() * weights[1],
                rw.ravel() * weights[2],
                (rx * wp[:, 0]) * (extra_w * weights[0]) if extra_w > 0 else np.zeros(0),
            ]
        )

    def fun(self, z: FloatArray) -> FloatArray:
        """The weighted residuals at the free parameters ``z`` (LM's trial steps: one integration
        instead of 1 + n_gyro)."""
        x = self.full(z)
        return self.stack(*self.raw_resid(x, self.gyro_rot(x[None])[0]))

    def fun_jac(self, z: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The weighted residuals and their Jacobian (rows, free parameters) at ``z``."""
        x = self.full(z)
        n_gyro, step = self.n_gyro, self.step
        xs = np.repeat(x[None], 1 + n_gyro, axis=0)
        for j in range(n_gyro):
            xs[1 + j, 9 + j] += step[9 + j]
        Rs = self.gyro_rot(xs)
        r = self.stack(*self.raw_resid(x, Rs[0]))
        J = np.zeros((r.size, self.P))
        free_th = np.flatnonzero(self.free[: self.n_th])
        for col, j in enumerate(free_th.tolist()):
            xp = x.copy()
            xp[j] += step[j]
            # accelerometer columns need no integration; gyro column j uses rotation set j - 8
            R = Rs[j - 8] if 9 <= j < 9 + n_gyro else Rs[0]
            J[:, col] = (self.stack(*self.raw_resid(xp, R)) - r) / step[j]
        self._direction_columns(x, Rs[0], J, len(free_th))
        return r, J

    def _direction_columns(self, x: FloatArray, R0: FloatArray, J: FloatArray, c0: int) -> None:
        """Fill the direction columns of ``J`` from column ``c0`` on, analytic:
        du/d delta = (I - u u^T) B / |v| for v = u0 + B delta."""
        K, S, g, pairs, weights = self.K, self.S, self.cfg.g, self.inp.pairs, self.weights
        e1, e2 = self.e1, self.e2
        d = x[self.n_th :].reshape(K, 2)
        v = self.u0 + e1 * d[:, :1] + e2 * d[:, 1:]
        nv = np.linalg.norm(v, axis=1)
        u = v / nv[:, None]
        B = np.stack([e1, e2], axis=2)  # (K, 3, 2)
        dU = (B - u[:, :, None] * np.einsum("ki,kij->kj", u, B)[:, None, :]) / nv[:, None, None]
        rows_a = np.arange(K)[:, None] * 3 + np.arange(3)[None, :]  # (K, 3)
        for m in range(2):
            cols = c0 + 2 * np.arange(K) + m
            # accelerometer residual h_i - g u_i, weighted per pose
            J[rows_a, cols[:, None]] = -g * dU[:, :, m] * self.wp * weights[0]
            # direction residual R_s^T u_a - u_b
            base = 3 * K
            rs = base + np.arange(S)[:, None] * 3 + np.arange(3)[None, :]
            Ra = np.einsum("sji,sj->si", R0, dU[pairs[:, 0], :, m])
            np.add.at(
                J, (rs, np.repeat(cols[pairs[:, 0]][:, None], 3, axis=1)), Ra * self.wd * weights[1]
            )
            np.add.at(
                J,
                (rs, np.repeat(cols[pairs[:, 1]][:, None], 3, axis=1)),
                -dU[pairs[:, 1], :, m] * self.wd * weights[1],
            )

    def initial_weights(self) -> None:
        """First weights from the starting point's residuals (each group its own RMS)."""
        if self.inp.noise is not None:
            return
        K, S, wp, weights = self.K, self.S, self.wp, self.weights
        rn0, rd0, rw0, _ = self.raw_resid(self.x_full0, self.gyro_rot(self.x_full0[None])[0])
        weights[0] = 1.0 / max(float(np.sqrt(np.sum((rn0 * wp) ** 2) / K)), 1e-12)
        weights[1] = 1.0 / max(float(np.sqrt(np.sum(rd0**2) / (2 * S))), 1e-12)
        if self.use_static:
            weights[2] = 1.0 / max(float(np.sqrt(np.mean((rw0 * wp) ** 2))), 1e-12)

    def reweigh(self, r: FloatArray, J: FloatArray) -> tuple[FloatArray, FloatArray, float]:
        """Variance-component estimation: each group's redundancy from the hat matrix's diagonal; the
        residuals and Jacobian rescaled to the new weights, and the largest relative change."""
        weights, bounds = self.weights, self.bounds
        hat = _hat_diagonal(J)
        new = weights.copy()
        for k in range(0 if self.inp.noise is not None else 3 if self.use_static else 2):
            a, b = bounds[k], bounds[k + 1]
            rho = max(self.dof[k] - float(hat[a:b].sum()), 1.0)
            new[k] = weights[k] / np.sqrt(max(float(r[a:b] @ r[a:b]) / rho, 1e-300))
        w_changed = float(np.max(np.abs(new / weights - 1.0)))
        if w_changed > 0:
            ratio = np.repeat(new / weights, self.n_rows)
            ratio[bounds[3] :] = (
                new[0] / weights[0]
            )  # the extra norm rows follow the accelerometer's
            r, J = r * ratio, J * ratio[:, None]
            weights[:] = new
        return r, J, w_changed

    def solve(self) -> tuple[FloatArray, int]:
        """Levenberg-Marquardt (Marquardt 1963, diagonal scaling) with the variance components
        re-estimated after every accepted step, so weights and parameters converge together (one
        Jacobian per step). Returns the free parameters and the iterations done."""
        self.initial_weights()
        x = self.x0.copy()
        lam = 1e-3
        n_iter = 0
        r, J = self.fun_jac(x)
        for _ in range(self.cfg.max_iter):
            n_iter += 1
            r, J, w_changed = self.reweigh(r, J)
            N = J.T @ J
            gvec = J.T @ r
            d = np.maximum(np.diag(N), 1e-30)
            cost = float(r @ r)
            step_ok = False
            for _ in range(20):
                try:
                    dx = -np.linalg.solve(N + lam * np.diag(d), gvec)
                except np.linalg.LinAlgError:
                    lam *= 10.0
                    continue
                r_try = self.fun(x + dx)
                if np.all(np.isfinite(r_try)) and float(r_try @ r_try) < cost:
                    step_ok = True
                    break
                lam *= 10.0
            if not step_ok:
                break
            x = x + dx
            lam = max(lam / 10.0, 1e-12)
            r, J = self.fun_jac(x)
            # Converged when the step is far below the parameters' uncertainty and the weights settled.
            var_x = np.clip(np.diag(_inv_normal(J)), 0.0, None)  # pinv of a rank-deficient N: 0
            small = bool(np.all(np.abs(dx) <= 1e-3 * np.sqrt(var_x)))
            if small and w_changed < 1e-2:
                break
        return x, n_iter

    def covariance(
        self, r: FloatArray, J: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray | None]:
        """Covariance (n_th, n_th) of the calibration parameters (the directions marginalised out), the
        a-posteriori variance factors (3,) and the per-row factors ``c`` (None without measured noise).

        With measured noise, a significant factor means the group's misfit exceeds its measured noise
        (Koch 1999, sec. 3.6): sandwich covariance with that factor."""
        cov_free = _inv_normal(J)
        factors = np.ones(3)
        c = None
        if self.inp.noise is not None:
            bounds = self.bounds
            hat = _hat_diagonal(J)
            c = np.ones(r.size)
            for k in range(3 if self.use_static else 2):
                a, b = bounds[k], bounds[k + 1]
                rho = max(self.dof[k] - float(hat[a:b].sum()), 1.0)
                factors[k] = float(r[a:b] @ r[a:b]) / rho
                if factors[k] * rho > float(chdtri(rho, 1.0 - 0.997)):
                    c[a:b] = factors[k]
            nm = bounds[
                3
            ]  # the extra norm rows only re-weight: the noise enters through the others
            if np.any(c != 1.0) or self.extra_w > 0:
                Jm = J[:nm]
                cov_free = cov_free @ (Jm.T @ (Jm * c[:nm, None])) @ cov_free
        free = self.free
        cov_all = np.zeros((free.size, free.size))
        cov_all[np.ix_(free, free)] = cov_free
        return cov_all[: self.n_th, : self.n_th], factors, c

    def result(self, x: FloatArray, n_iter: int) -> JointFit:
        """The fit at the free parameters ``x``."""
        r, J = self.fun_jac(x)
        cov, factors, c = self.covariance(r, J)
        xf = self.full(x)
        _, rd, _, _ = self.raw_resid(xf, self.gyro_rot(xf[None])[0])
        th_a, th_g, db, G = self.unpack(xf)
        sign = self.cfg.sign
        rn = np.linalg.norm(_accel_h(th_a, self.inp.means + sign * self.drift(xf), sign), axis=1)
        rn = rn - self.cfg.g
        weights = self.weights
        sig = {"accel": 1.0 / weights[0], "direction": 1.0 / weights[1]}
        if self.use_static:
            sig["static_rate"] = 1.0 / weights[2]
        if c is not None:  # the a-posteriori factors of the measured noise instead
            sig = {"accel_factor": factors[0], "direction_factor": factors[1]}
            if self.use_static:
                sig["static_rate_factor"] = factors[2]
        return JointFit(
            theta_a=th_a.copy(),
            theta_g=th_g.copy(),
            db=db.copy(),
            G=G.copy(),
            cov=cov,
            sigmas=sig,
            drift=xf[18 + self.n_b + self.n_G : self.n_th].copy() if self.n_d else np.zeros(3),
            norm_residual=rn,
            dir_residual=rd,
            iterations=n_iter,
            accel_misfit=bool(c[0] != 1.0) if c is not None else False,
            cost=float(r @ r),
        )


def joint_refine(
    inputs: JointInputs, settings: JointSettings, integrate: Callable[..., FloatArray]
) -> JointFit:
    """Refine ``inputs.theta_a0`` (9,) and ``inputs.theta_g0`` (9,) jointly (see the module doc).

    integrate: ``imuslam.imu.rk4.integrate_segments`` (passed in to keep this module free of numba).
    """
    problem = JointProblem(inputs, settings, integrate)
    x, n_iter = problem.solve()
    return problem.result(x, n_iter)


def measured_noise(
    sigma_accel: FloatArray,
    sigma_gyro: FloatArray,
    pose_n: FloatArray,
    seg_duration_s: FloatArray,
    dt_s: float,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """1-sigma of each residual of :func:`joint_refine` from the sensors' white noise.

    sigma_accel, sigma_gyro: (3,) per-sample noise of each axis (calibrated units, from the still
    period); pose_n: (K,) samples averaged per pose; seg_duration_s: (S,) integration time of each
    rotation; dt_s: sample interval.
    - accelerometer residual of a pose (a mean of n samples): ``sigma_a / sqrt(n)`` per component;
    - direction residual: the angle random walk of the integrated rate, ``sigma_w sqrt(dt T)`` per
      component (trapezoidal sum of T / dt white samples, each weighted by dt); the pose directions are
      parameters of the fit, so their accelerometer noise is in the accelerometer residuals only;
    - static rate of a pose: ``sigma_w / sqrt(n)``.
    The axes are pooled (root mean square), the residuals being expressed in the body frame.
    """
    sa = float(np.sqrt(np.mean(np.square(sigma_accel))))
    sw = float(np.sqrt(np.mean(np.square(sigma_gyro))))
    n = np.maximum(np.asarray(pose_n, dtype=np.float64), 1.0)
    return (
        sa / np.sqrt(n),
        sw * np.sqrt(dt_s * np.asarray(seg_duration_s, np.float64)),
        sw / np.sqrt(n),
    )
