"""A small Levenberg-Marquardt solver for the calibration's few-parameter least squares.

``scipy.optimize.least_squares(method="lm")`` solves the same problems to the same minimum; importing
``scipy.optimize`` alone costs about half a second of a whole ``imuslam calibrate`` run, which here
solves problems of 9 to 12 parameters. The iteration is Moré's scaled Levenberg-Marquardt (Moré 1978,
"The Levenberg-Marquardt algorithm: implementation and theory") with Nielsen's damping update
(Nielsen 1999, IMM-REP-1999-05, eq. 3.2); each step solves the damped normal equations
``(J_s^T J_s + mu I) dz = -J_s^T r`` in the scaled variables ``z = x / x_scale`` (with the scaling the
calibration's normal matrices are well conditioned; a QR of the tall Jacobian costs 10x more here).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class LmResult:
    """The solution ``x``, its residual ``fun`` and Jacobian ``jac``, and how the iteration ended."""

    x: FloatArray
    fun: FloatArray
    jac: FloatArray
    success: bool
    message: str
    nfev: int


def levenberg_marquardt(
    fun: Callable[[FloatArray], FloatArray],
    x0: FloatArray,
    jac: Callable[[FloatArray], FloatArray],
    x_scale: FloatArray | None = None,
    xtol: float = 1e-12,
    ftol: float = 1e-12,
    gtol: float = 1e-12,
    max_nfev: int | None = None,
    tau: float = 1e-6,
) -> LmResult:
    """Minimise ``0.5 |fun(x)|^2`` from ``x0``.

    ``x_scale``: the typical size of each variable (the solver works in ``x / x_scale``, as
    scipy's ``x_scale``); tolerances as scipy's: ``ftol`` on the relative cost reduction (actual and
    predicted), ``xtol`` on the relative step size, ``gtol`` on the scaled gradient's largest entry.
    ``tau``: the first damping relative to the largest diagonal entry of ``J^T J`` (small: the start
    is trusted, as the calibration's closed-form first guesses are). ``success`` is False when the evaluations run out or a residual stops being finite.
    """
    x = np.array(x0, dtype=np.float64)
    n = x.size
    d = np.ones(n) if x_scale is None else 1.0 / np.asarray(x_scale, dtype=np.float64)
    budget = 100 * n if max_nfev is None else max_nfev
    r = np.asarray(fun(x), dtype=np.float64)
    nfev = 1
    if not np.all(np.isfinite(r)):
        return LmResult(x, r, np.full((r.size, n), np.nan), False, "residual not finite at x0", 1)
    J = np.asarray(jac(x), dtype=np.float64)
    cost = 0.5 * float(r @ r)
    # in scaled variables z = D x the Jacobian is J D^-1
    Js = J / d
    A = Js.T @ Js
    mu = tau * float(np.diag(A).max()) if np.diag(A).max() > 0 else tau
    nu = 2.0
    message = "the function evaluations ran out"
    success = False
    while nfev < budget:
        g = Js.T @ r
        if float(np.max(np.abs(g))) <= gtol * max(cost, np.finfo(float).tiny):
            message, success = "the gradient is below gtol", True
            break
        try:
            dz = np.linalg.solve(A + mu * np.eye(n), -g)
        except np.linalg.LinAlgError:
            dz = np.linalg.lstsq(A + mu * np.eye(n), -g, rcond=None)[0]
        z_norm = float(np.linalg.norm(d * x))
        if float(np.linalg.norm(dz)) <= xtol * (z_norm + xtol):
            message, success = "the step is below xtol", True
            break
        x_new = x + dz / d
        r_new = np.asarray(fun(x_new), dtype=np.float64)
        nfev += 1
        cost_new = 0.5 * float(r_new @ r_new) if np.all(np.isfinite(r_new)) else np.inf
        # predicted reduction of the local linear model (Moré 1978, eq. 4.4)
        Jdz = Js @ dz
        predicted = -(float(g @ dz) + 0.5 * float(Jdz @ Jdz))
        actual = cost - cost_new
        rho = actual / predicted if predicted > 0 else -1.0
        if predicted <= ftol * cost:
            # the local model promises no measurable reduction: converged (keep a step that helped)
            if rho > 0:
                x, r, cost = x_new, r_new, cost_new
                J = np.asarray(jac(x), dtype=np.float64)
            message, success = "the predicted cost reduction is below ftol", True
            break
        if rho > 0:
            small = actual <= ftol * cost
            x, r, cost = x_new, r_new, cost_new
            J = np.asarray(jac(x), dtype=np.float64)
            Js = J / d
            A = Js.T @ Js
            mu *= max(0.1, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            if small:
                message, success = "the cost reduction is below ftol", True
                break
        else:
            mu *= nu
            nu *= 2.0
            if not np.isfinite(mu) or mu > 1e300:
                message = "the damping grew without bound (no descent step)"
                break
    return LmResult(x, r, J, success, message, nfev)
