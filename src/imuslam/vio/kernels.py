"""The VIO filter: everything the EKF does between two VO frames in one numba call (the product path of
every VO model; :class:`imuslam.vio.filter.VioFilter` drives it).

:func:`frame_step` runs, for one VO frame: the non-holonomic pseudo-measurements due before it (predict
to each, gated update, record), the prediction, the gated VO updates (``vo_model: rate``: the VO rate
against the mean gyro and the body velocity at the pair's mid-time, the velocity conditioned on the
rate, optionally against a slowly varying VO error kept as three extra states; ``relative``: the pair's
rotation and translation against a clone of the pose at its start, six extra states), and the record.
The prediction is the inertial core's (:func:`imuslam.ins.core.propagate`: its strapdown step, its
transition matrix) with the covariance product taken block by block (:func:`propagate_sparse`); the
update (:func:`update_sparse`) works on the 3 to 12 error states a measurement touches, in the standard
form where the core's :func:`~imuslam.ins.core.kalman_update` uses the Joseph form (equal for the
optimal gain), with the core's attitude perturbation :func:`~imuslam.ins.core.boxplus_attitude`. The
measurement models' equations are derived in the docstrings of :func:`_vo_rate_velocity`,
:func:`relative_rotation`, :func:`relative_translation` and :func:`_nhc_until`; ``tests/vio`` holds a
Python reference filter (one core ``Eskf`` call per event, each measurement an object that linearises
itself) and compares the two on every model.

State arrays are updated in place: ``p, v (3,)``, ``R (3, 3)``, ``ba, bg, g_n (3,)``, ``P (m, m)``,
``clock = [t, next_nhc]`` (s since the filter's reference time), ``vo_scale = [rate, velocity]`` (the
online VO covariance scales, ones when ``const[C_ADAPT_N]`` is 0), ``xe`` (12,) the extra states'
nominal values (the VO error ``e`` (3,) m/s body frame, or the clone's ``R_c`` (9, row-major) and
``p_c`` (3,)). Records go to preallocated buffers with counters ``cnt = [track, marks, nhc,
vo_velocity, vo_rate]``; measurement kinds are rows 0 (nhc), 1 (vo_velocity), 2 (vo_rate) of ``nis``
and ``accepted``.

Compile time: numba compiles each kernel on its own and LLVM optimises a caller together with every
callee it links, so each level of calls optimises the code below it once more. The steps called from
one place (:func:`frame_step` from :func:`run_frames`; the NHC, VO-rate and relative updates from
:func:`frame_step`) are therefore inlined in numba's IR (``inline="always"``), each call site of the
prediction and the NHC is written once, and the measurement kind reaches the update chain as a run-time
integer: a first run after an install compiles for about 95 s of CPU instead of 147 s.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

from imuslam.geometry.so3_nb import exp_nb, hat_nb, log_nb, right_jacobian_nb
from imuslam.ins.core import boxplus_attitude, integrate_corrected, is_pd

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

# measurement kinds; a kernel passes them on as np.int64(KIND_...): a bare global is typed as a literal,
# which would compile the update chain once per kind
KIND_NHC, KIND_VEL, KIND_RATE = 0, 1, 2
# layout of frame_step's packed inputs (one array each: fewer arguments to type-check per call)
M_T, M_VEL, M_COV_V, M_OMEGA, M_COV_W, M_T0, M_T1, M_VEL_ON, M_RATE_ON, M_COV_WV, M_JOINT, M_LEN = (
    0, 1, 4, 13, 16, 25, 26, 27, 28, 29, 38, 39)  # fmt: skip
(C_NHC_ON, C_NHC_STD, C_NHC_DT, C_GYRO_Q, C_GATE_ON, C_THR2, C_THR3, C_NHC_STD_Z, C_ADAPT_N,
 C_ADAPT_UNTIL, C_MODE, C_X_OFF, C_ERR_TAU, C_ERR_VAR, C_LEN) = (
    0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 16)  # fmt: skip
# const[C_MODE]: how a frame pair's VO is read (VioConfig.vo_model and vo_error_std); the extra error
# states start at const[C_X_OFF], their nominal values are ``xe`` (12,)
MODE_RATE, MODE_VO_ERROR, MODE_RELATIVE = 0, 1, 2
# the online VO covariance scale stays within this factor of its start (VioConfig.vo_cov_adapt_n)
ADAPT_LIMIT = 20.0
# frame_step's verdicts
OK, DIVERGED, VEL_REJECTED = 0, 1, 2


@numba.njit(cache=True)
def sample_at_nb(
    t_imu: FloatArray, acc: FloatArray, gyr: FloatArray, t: float
) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - compiled
    """IMU (accel, gyro) linearly interpolated at time t (the end segments extrapolate)."""
    k = int(np.searchsorted(t_imu, t)) - 1
    k = min(max(k, 0), t_imu.shape[0] - 2)
    w = (t - t_imu[k]) / (t_imu[k + 1] - t_imu[k])
    return (1 - w) * acc[k] + w * acc[k + 1], (1 - w) * gyr[k] + w * gyr[k + 1]


@numba.njit(cache=True)
def gyro_mean_nb(
    t_imu: FloatArray, acc: FloatArray, gyr: FloatArray, t0: float, t1: float
) -> FloatArray:  # pragma: no cover - compiled
    """Mean raw gyro (3,) over [t0, t1]: trapezoid over the samples and the interpolated ends."""
    i0 = int(np.searchsorted(t_imu, t0, side="right"))
    i1 = int(np.searchsorted(t_imu, t1, side="right"))
    n = max(i1 - i0, 0)
    ts = np.empty(n + 2)
    gs = np.empty((n + 2, 3))
    ts[0] = t0
    gs[0] = sample_at_nb(t_imu, acc, gyr, t0)[1]
    for j in range(n):
        ts[j + 1] = t_imu[i0 + j]
        gs[j + 1] = gyr[i0 + j]
    ts[n + 1] = t1
    gs[n + 1] = sample_at_nb(t_imu, acc, gyr, t1)[1]
    s = np.zeros(3)
    for j in range(n + 1):
        s += 0.5 * (gs[j + 1] + gs[j]) * (ts[j + 1] - ts[j])
    return s / max(t1 - t0, 1e-12)


@numba.njit(cache=True)
def _blk_rows(
    dst: FloatArray, src: FloatArray, i: int, j: int, M: FloatArray
) -> None:  # pragma: no cover - compiled
    """dst[i:i+3, :] += M (3, 3) @ src[j:j+3, :]."""
    for a in range(3):
        for c in range(src.shape[1]):
            dst[i + a, c] += M[a, 0] * src[j, c] + M[a, 1] * src[j + 1, c] + M[a, 2] * src[j + 2, c]


@numba.njit(cache=True)
def _blk_cols(
    dst: FloatArray, src: FloatArray, i: int, j: int, M: FloatArray
) -> None:  # pragma: no cover - compiled
    """dst[:, i:i+3] += src[:, j:j+3] @ M^T (M (3, 3))."""
    for r in range(src.shape[0]):
        s0, s1, s2 = src[r, j], src[r, j + 1], src[r, j + 2]
        for a in range(3):
            dst[r, i + a] += s0 * M[a, 0] + s1 * M[a, 1] + s2 * M[a, 2]


@numba.njit(cache=True)
def propagate_sparse(
    accel: FloatArray, gyro: FloatArray, dt: FloatArray,
    p: FloatArray, v: FloatArray, R: FloatArray, ba: FloatArray, bg: FloatArray, g_n: FloatArray,
    P: FloatArray, q: FloatArray, off: IntArray,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:  # fmt: skip  # pragma: no cover - compiled
    """The core's prediction (:func:`imuslam.ins.core.propagate`: the same strapdown steps, the same
    transition matrix and process noise) with the covariance product ``Phi P Phi^T`` done block by
    block: ``Phi`` is the identity but for six 3x3 blocks, so the two dense (m, m) products per sample
    become a few (3, m) row and column operations, and the strong-tracking noise sum the core also
    keeps is not formed. Returns p (N, 3), v (N, 3), R_n_b (N, 3, 3) per sample and P; equal to the
    core's kernel to rounding (``tests/vio/test_vio_filter.py``)."""
    Ps, Vs, Rs, fn_sum = integrate_corrected(accel - ba, gyro - bg, dt, p, v, R, g_n, np.zeros(3))
    fn = fn_sum / max(dt.shape[0], 1)
    ith, ip, iv, iba, ibg, ig = off[0], off[1], off[2], off[3], off[4], off[5]
    Fx = hat_nb(fn)
    eye3 = np.eye(3)
    m = P.shape[0]
    P = P.copy()
    A = np.empty((m, m))
    B = np.empty((m, m))
    for k in range(dt.shape[0]):
        h = dt[k]
        E = exp_nb(-(0.5 * (gyro[k] + gyro[k + 1]) - bg) * h)
        C = -(Fx @ Rs[k]) * h
        Rh = -Rs[k] * h
        Ih = eye3 * h
        # A = Phi P (row blocks from P's rows)
        A[:, :] = P
        A[ith : ith + 3, :] = 0.0
        _blk_rows(A, P, ith, ith, E)
        if ibg >= 0:
            _blk_rows(A, P, ith, ibg, -Ih)
        _blk_rows(A, P, ip, iv, Ih)
        _blk_rows(A, P, iv, ith, C)
        if iba >= 0:
            _blk_rows(A, P, iv, iba, Rh)
        if ig >= 0:
            _blk_rows(A, P, iv, ig, Ih)
        # P = A Phi^T (column blocks from A's columns)
        B[:, :] = A
        B[:, ith : ith + 3] = 0.0
        _blk_cols(B, A, ith, ith, E)
        if ibg >= 0:
            _blk_cols(B, A, ith, ibg, -Ih)
        _blk_cols(B, A, ip, iv, Ih)
        _blk_cols(B, A, iv, ith, C)
        if iba >= 0:
            _blk_cols(B, A, iv, iba, Rh)
        if ig >= 0:
            _blk_cols(B, A, iv, ig, Ih)
        for i in range(3):
            B[iv + i, iv + i] += q[0] * h
            B[ith + i, ith + i] += q[1] * h
            if iba >= 0:
                B[iba + i, iba + i] += q[2] * h
            if ibg >= 0:
                B[ibg + i, ibg + i] += q[3] * h
        P[:, :] = B
    return Ps, Vs, Rs, P


@numba.njit(cache=True)
def _check(P: FloatArray, p: FloatArray, v: FloatArray, R: FloatArray) -> bool:  # pragma: no cover
    """The core filter's check: finite state, P symmetrised in place and positive definite."""
    if not (np.isfinite(P).all() and np.isfinite(p).all() and np.isfinite(v).all()
            and np.isfinite(R).all()):  # fmt: skip
        return False
    P[:, :] = 0.5 * (P + P.T)
    return is_pd(P + np.eye(P.shape[0]) * 1e-18)


@numba.njit(cache=True)
def _advance(
    t_imu: FloatArray, acc: FloatArray, gyr: FloatArray,
    p: FloatArray, v: FloatArray, R: FloatArray, ba: FloatArray, bg: FloatArray, g_n: FloatArray,
    P: FloatArray, clock: FloatArray, t: float, q: FloatArray, off: IntArray,
    tr_t: FloatArray, tr_p: FloatArray, tr_R: FloatArray, cnt: IntArray,
    xe: FloatArray, const: FloatArray,
) -> bool:  # fmt: skip  # pragma: no cover - compiled
    """Predict from clock[0] to t with the core's kernel (IMU interpolated at both ends), recording the
    interior samples; in MODE_VO_ERROR the VO error's own first-order Gauss-Markov transition over
    the block (the core carries extra states with an identity transition): ``phi = exp(-T / tau)`` on
    its rows and columns of P and on its nominal value, ``var (1 - phi^2)`` added. False when the
    filter diverged."""
    t_now = clock[0]
    if t <= t_now:
        return True
    i0 = int(np.searchsorted(t_imu, t_now, side="right"))
    i1 = int(np.searchsorted(t_imu, t, side="right"))
    n_in = max(i1 - i0, 0)
    ts_all = np.empty(n_in + 2)
    ts_all[0] = t_now
    ts_all[1 : n_in + 1] = t_imu[i0 : i0 + n_in]
    ts_all[n_in + 1] = t
    keep = np.empty(n_in + 2, np.bool_)
    keep[0] = True
    for j in range(1, n_in + 2):
        keep[j] = ts_all[j] - ts_all[j - 1] > 1e-9
    n = int(keep.sum())
    if n < 2:
        return True
    a0, w0 = sample_at_nb(t_imu, acc, gyr, t_now)
    a1, w1 = sample_at_nb(t_imu, acc, gyr, t)
    ts = np.empty(n)
    A = np.empty((n, 3))
    W = np.empty((n, 3))
    k = 0
    for j in range(n_in + 2):
        if not keep[j]:
            continue
        ts[k] = ts_all[j]
        if j == 0:
            A[k], W[k] = a0, w0
        elif j == n_in + 1:
            A[k], W[k] = a1, w1
        else:
            A[k], W[k] = acc[i0 + j - 1], gyr[i0 + j - 1]
        k += 1
    Ps, Vs, Rs, Pn = propagate_sparse(A, W, np.diff(ts), p, v, R, ba, bg, g_n, P, q, off)
    p[:] = Ps[n - 1]
    v[:] = Vs[n - 1]
    R[:, :] = Rs[n - 1]
    P[:, :] = Pn
    c = cnt[0]
    for j in range(1, n - 1):
        tr_t[c] = ts[j]
        tr_p[c] = Ps[j]
        tr_R[c] = Rs[j]
        c += 1
    cnt[0] = c
    clock[0] = t
    ok = _check(P, p, v, R)
    if int(const[C_MODE]) == MODE_VO_ERROR:
        o = int(const[C_X_OFF])
        phi = np.exp(-(ts[n - 1] - ts[0]) / const[C_ERR_TAU])
        P[o:, :] *= phi
        P[:, o:] *= phi
        for i in range(3):
            P[o + i, o + i] += const[C_ERR_VAR + i] * (1.0 - phi**2)
        xe[0:3] *= phi
    return ok


@numba.njit(cache=True)
def mark_state(
    t: float, p: FloatArray, R: FloatArray, ba: FloatArray, bg: FloatArray, P: FloatArray,
    off: IntArray, tr_t: FloatArray, tr_p: FloatArray, tr_R: FloatArray, bias_t: FloatArray,
    bias: FloatArray, bias_std: FloatArray, cnt: IntArray,
) -> None:  # fmt: skip  # pragma: no cover - compiled
    """Record the posterior state at t: the track, the biases and their 1-sigma."""
    c = cnt[0]
    tr_t[c] = t
    tr_p[c] = p
    tr_R[c] = R
    cnt[0] = c + 1
    b = cnt[1]
    bias_t[b] = t
    bias[b, :3] = ba
    bias[b, 3:] = bg
    for i in range(3):
        bias_std[b, i] = np.sqrt(P[off[3] + i, off[3] + i])
        bias_std[b, 3 + i] = np.sqrt(P[off[4] + i, off[4] + i])
    cnt[1] = b + 1


@numba.njit(cache=True)
def update_sparse(
    r: FloatArray, Hc: FloatArray, cols: IntArray, Rm: FloatArray,
    p: FloatArray, v: FloatArray, R: FloatArray, ba: FloatArray, bg: FloatArray, g_n: FloatArray,
    P: FloatArray, off: IntArray, gate_on: bool, threshold: float,
    kind: int | np.int64, nis_buf: FloatArray, acc_buf: NDArray[np.bool_], cnt: IntArray,
) -> tuple[int, FloatArray]:  # fmt: skip  # pragma: no cover - compiled
    """Chi-square gate (nis = r^T (H P H^T + R)^-1 r) and the Kalman update, the attitude by the core's
    :func:`~imuslam.ins.core.boxplus_attitude`, for a Jacobian whose nonzero columns are ``cols`` (nc,), given there as ``Hc``
    (k, nc): the VIO's measurements touch 3 (VO rate) or 9 (NHC, VO velocity) of the 15 error states.
    ``P H^T`` is formed from those columns only, ``S`` (k <= 3) inverted directly, and the covariance
    updated in the standard form ``P - K S K^T = P - P H^T S^-1 H P`` (a rank-k downdate instead of
    the Joseph form's two dense (m, m) products; equal for the optimal gain, Maybeck, *Stochastic
    Models, Estimation and Control* vol. 1, eq. 5-50 against 5-47; the symmetrised result is checked
    positive definite by :func:`_check`). Records the nis and the verdict of this kind; returns 1
    accepted, 0 rejected, -1 diverged, and the correction (m,) (meaningless unless accepted)."""
    m = P.shape[0]
    k = r.shape[0]
    nc = cols.shape[0]
    PHt = np.zeros((m, k))
    for i in range(m):
        for j in range(nc):
            pij = P[i, cols[j]]
            for a in range(k):
                PHt[i, a] += pij * Hc[a, j]
    S = Rm.copy()
    for a in range(k):
        for b in range(k):
            acc = 0.0
            for j in range(nc):
                acc += Hc[a, j] * PHt[cols[j], b]
            S[a, b] += acc
    S = 0.5 * (S + S.T)
    Si = np.linalg.inv(S)
    Si = 0.5 * (Si + Si.T)
    Sr = Si @ r
    nis = r @ Sr
    j = cnt[2 + kind]
    nis_buf[kind, j] = nis
    cnt[2 + kind] = j + 1
    if gate_on and not (nis <= threshold):
        acc_buf[kind, j] = False
        return 0, Sr
    acc_buf[kind, j] = True
    dx = PHt @ Sr
    K = PHt @ Si
    for i in range(m):
        for c in range(i, m):
            acc = 0.0
            for a in range(k):
                acc += K[i, a] * PHt[c, a]
            P[i, c] -= acc
            if c != i:
                P[c, i] = P[i, c]
    R[:, :] = boxplus_attitude(R, np.ascontiguousarray(dx[off[0] : off[0] + 3]))
    p += dx[off[1] : off[1] + 3]
    v += dx[off[2] : off[2] + 3]
    if off[3] >= 0:
        ba += dx[off[3] : off[3] + 3]
    if off[4] >= 0:
        bg += dx[off[4] : off[4] + 3]
    if off[5] >= 0:
        g_n += dx[off[5] : off[5] + 3]
    return (1 if _check(P, p, v, R) else -1), dx


@numba.njit(cache=True)
def adapt_scale(scale: float, nis: float, dof: float, n: float) -> float:  # pragma: no cover
    """One step of the online covariance scale: ``scale * exp((nis / dof - 1) / n)``, a Robbins-Monro
    stochastic approximation (Robbins and Monro 1951) whose fixed point is E[NIS] = dof, clipped to
    [1 / ADAPT_LIMIT, ADAPT_LIMIT]."""
    s = scale * np.exp((nis / dof - 1.0) / n)
    return min(max(s, 1.0 / ADAPT_LIMIT), ADAPT_LIMIT)


@numba.njit(cache=True)
def clone_pose(P: FloatArray, R: FloatArray, p: FloatArray, xe: FloatArray, off: IntArray,
               o: int) -> None:  # fmt: skip  # pragma: no cover - compiled
    """Stochastic cloning (Roumeliotis and Burdick, ICRA 2002): the attitude and position error rows
    and columns of ``P`` copied into the extra states at ``o`` (replacing the former clone), their
    nominal values ``R`` and ``p`` into ``xe = [R_c (9, row-major), p_c (3)]``."""
    for i in range(6):
        P[o + i, :] = P[(off[0] if i < 3 else off[1] - 3) + i, :]
    for i in range(6):
        P[:, o + i] = P[:, (off[0] if i < 3 else off[1] - 3) + i]
    for i in range(3):
        for j in range(3):
            xe[3 * i + j] = R[i, j]
        xe[9 + i] = p[i]


@numba.njit(cache=True)
def _update(
    r: FloatArray, Hc: FloatArray, cols: IntArray, Rm: FloatArray,
    p: FloatArray, v: FloatArray, R: FloatArray, ba: FloatArray, bg: FloatArray, g_n: FloatArray,
    P: FloatArray, xe: FloatArray, const: FloatArray, off: IntArray, threshold: float,
    kind: int | np.int64, nis_buf: FloatArray, acc_buf: NDArray[np.bool_], cnt: IntArray,
) -> int:  # fmt: skip  # pragma: no cover - compiled
    """:func:`update_sparse`, then the extra states' share of an accepted correction: the VO velocity
    error adds it, the clone's attitude is perturbed on the right and its position adds it."""
    st, dx = update_sparse(r, Hc, cols, Rm, p, v, R, ba, bg, g_n, P, off, const[C_GATE_ON] != 0.0,
                           threshold, kind, nis_buf, acc_buf, cnt)  # fmt: skip
    if st != 1:
        return st
    mode = int(const[C_MODE])
    o = int(const[C_X_OFF])
    if mode == MODE_VO_ERROR:
        xe[0:3] += dx[o : o + 3]
    elif mode == MODE_RELATIVE:
        Rc = np.ascontiguousarray(xe[0:9]).reshape((3, 3)) @ exp_nb(
            np.ascontiguousarray(dx[o : o + 3])
        )
        xe[0:9] = Rc.reshape(9)
        xe[9:12] += dx[o + 3 : o + 6]
    return st


@numba.njit(cache=True)
def _vo_update(
    r: FloatArray, Hc: FloatArray, cols: IntArray, Rm: FloatArray,
    p: FloatArray, v: FloatArray, R: FloatArray, ba: FloatArray, bg: FloatArray, g_n: FloatArray,
    P: FloatArray, xe: FloatArray, const: FloatArray, off: IntArray, kind: int | np.int64,
    vo_scale: FloatArray, adapt_n: float, nis_buf: FloatArray, acc_buf: NDArray[np.bool_],
    cnt: IntArray,
) -> int:  # fmt: skip  # pragma: no cover - compiled
    """A VO update (3 dof, KIND_RATE or KIND_VEL) through :func:`_update`; when accepted and
    ``adapt_n`` > 0, its online covariance scale (``vo_scale`` row 0 rate, 1 velocity) steps on its
    NIS (:func:`adapt_scale`)."""
    st = _update(r, Hc, cols, Rm, p, v, R, ba, bg, g_n, P, xe, const, off, const[C_THR3], kind,
                 nis_buf, acc_buf, cnt)  # fmt: skip
    if st == 1 and adapt_n > 0:
        row = 0 if kind == KIND_RATE else 1
        vo_scale[row] = adapt_scale(vo_scale[row], nis_buf[kind, cnt[2 + kind] - 1], 3.0, adapt_n)
    return st


@numba.njit(cache=True)
def vehicle_velocity(
    R: FloatArray, v: FloatArray, w: FloatArray, R_b_v: FloatArray, p_b_v: FloatArray
) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - compiled
    """The vehicle frame's velocity ``v_v = R_b_v^T (R^T v + w x p_b_v)`` (3,) (``w`` the
    bias-corrected gyro rate (3,) rad/s, the vehicle frame given in the body by ``R_b_v`` and its
    origin ``p_b_v``) and its Jacobian (3, 9) on ``[dtheta, dv, db_g]``: with the right perturbation
    ``R^T v ~ R_hat^T v + [R_hat^T v]x dtheta``, so ``R_b_v^T [R^T v]x``, ``R_b_v^T R^T`` and, as
    ``w = gyro - b_g``, ``R_b_v^T [p_b_v]x``. The non-holonomic constraint reads rows 1-2 (lateral,
    vertical: zero), the wheel speed row 0 (:mod:`imuslam.vio.measurements` uses it too)."""
    R_v_b = np.ascontiguousarray(R_b_v.T)
    vb = R.T @ v
    vv = R_v_b @ (vb + np.cross(w, p_b_v))
    Hc = np.empty((3, 9))
    Hc[:, 0:3] = R_v_b @ hat_nb(vb)
    Hc[:, 3:6] = R_v_b @ R.T
    Hc[:, 6:9] = R_v_b @ hat_nb(p_b_v)
    return vv, Hc


@numba.njit(cache=True, inline="always")
def _nhc_until(
    t_until: float, t_imu: FloatArray, acc: FloatArray, gyr: FloatArray,
    p: FloatArray, v: FloatArray, R: FloatArray, ba: FloatArray, bg: FloatArray, g_n: FloatArray,
    P: FloatArray, clock: FloatArray, xe: FloatArray, const: FloatArray,
    R_b_v: FloatArray, p_b_v: FloatArray, q: FloatArray, off: IntArray,
    tr_t: FloatArray, tr_p: FloatArray, tr_R: FloatArray,
    bias_t: FloatArray, bias: FloatArray, bias_std: FloatArray,
    nis_buf: FloatArray, acc_buf: NDArray[np.bool_], cnt: IntArray,
) -> bool:  # fmt: skip  # pragma: no cover - compiled
    """The non-holonomic updates due before ``t_until`` (when on): predict to each, the gated update of
    the vehicle-frame lateral and vertical velocity (:func:`vehicle_velocity`), a record.
    False when the filter diverged."""
    if const[C_NHC_ON] == 0.0:
        return True
    cols = np.empty(9, np.int64)  # [dtheta, dv, db_g]
    for i in range(3):
        cols[i] = off[0] + i
        cols[3 + i] = off[2] + i
        cols[6 + i] = off[4] + i
    Rm = np.zeros((2, 2))
    Rm[0, 0] = const[C_NHC_STD] ** 2
    Rm[1, 1] = const[C_NHC_STD_Z] ** 2
    while clock[1] < t_until:
        tn = clock[1]
        if not _advance(t_imu, acc, gyr, p, v, R, ba, bg, g_n, P, clock, tn, q, off,
                        tr_t, tr_p, tr_R, cnt, xe, const):  # fmt: skip
            return False
        w = sample_at_nb(t_imu, acc, gyr, tn)[1] - bg
        vv, Hv = vehicle_velocity(R, v, w, R_b_v, p_b_v)
        Hc = np.ascontiguousarray(Hv[1:])
        if _update(-vv[1:], Hc, cols, Rm, p, v, R, ba, bg, g_n, P, xe, const, off,
                   const[C_THR2], np.int64(KIND_NHC), nis_buf, acc_buf, cnt) < 0:  # fmt: skip
            return False
        mark_state(clock[0], p, R, ba, bg, P, off, tr_t, tr_p, tr_R, bias_t, bias, bias_std, cnt)
        clock[1] = tn + const[C_NHC_DT]
    return True


@numba.njit(cache=True, inline="always")
def _vo_rate_velocity(
    meas: FloatArray, t_imu: FloatArray, acc: FloatArray, gyr: FloatArray,
    p: FloatArray, v: FloatArray, R: FloatArray, ba: FloatArray, bg: FloatArray, g_n: FloatArray,
    P: FloatArray, clock: FloatArray, vo_scale: FloatArray, xe: FloatArray, const: FloatArray,
    off: IntArray, nis_buf: FloatArray, acc_buf: NDArray[np.bool_], cnt: IntArray,
) -> int:  # fmt: skip  # pragma: no cover - compiled
    """``vo_model: rate``: the VO rate against the mean gyro over the pair (it observes the gyro bias),
    then the VO body velocity (``H_v = R^T``, ``H_theta = [R^T v]x``), conditioned on the rate when
    the joint flag is set and the rate was accepted (with ``G = C_vw C_ww^-1``: residual ``r_v - G
    r_w``, Jacobian ``H_v - G H_w``, covariance ``C_vv - G C_wv``; the rate update followed by this
    one equals the joint 6-dof update), against ``v_b + e`` with the slowly varying VO error ``e`` in
    MODE_VO_ERROR. (The tests' reference, ``tests/vio/vio_reference.py``, writes them as ``VoRate``,
    ``VoVelocity``, ``VoVelocityGivenRate`` and ``WithVoError``.) Returns OK, VEL_REJECTED or
    DIVERGED."""
    rate_ok = False
    r_w = np.zeros(3)
    Rm_w = np.eye(3)
    adapt_n = const[C_ADAPT_N] if clock[0] < const[C_ADAPT_UNTIL] else 0.0
    s_w = vo_scale[0]  # the online scales in force for this frame (ones when off)
    s_v = vo_scale[1]
    gm = int(const[C_MODE]) == MODE_VO_ERROR
    nc = 12 if gm else 9
    cols = np.empty(nc, np.int64)  # [dtheta, dv, db_g] (and e)
    for i in range(3):
        cols[i] = off[0] + i
        cols[3 + i] = off[2] + i
        cols[6 + i] = off[4] + i
        if gm:
            cols[9 + i] = int(const[C_X_OFF]) + i
    if meas[M_RATE_ON] != 0.0:
        omega_b = meas[M_OMEGA : M_OMEGA + 3]
        cov_w = np.ascontiguousarray(meas[M_COV_W : M_COV_W + 9]).reshape((3, 3))
        t0 = meas[M_T0]
        t1 = meas[M_T1]
        g_mean = gyro_mean_nb(t_imu, acc, gyr, t0, t1)
        r = omega_b - (g_mean - bg)
        Rm_w = cov_w * s_w + np.eye(3) * (const[C_GYRO_Q] / (t1 - t0))
        st = _vo_update(r, -np.eye(3), cols[6:9], Rm_w, p, v, R, ba, bg, g_n, P, xe, const, off,
                        np.int64(KIND_RATE), vo_scale, adapt_n, nis_buf, acc_buf, cnt)  # fmt: skip
        if st < 0:
            return DIVERGED
        rate_ok = st == 1
        r_w = omega_b - (g_mean - bg)  # at the updated gyro bias
    if meas[M_VEL_ON] == 0.0:
        return OK
    vel_b = meas[M_VEL : M_VEL + 3]
    cov_v = np.ascontiguousarray(meas[M_COV_V : M_COV_V + 9]).reshape((3, 3)) * s_v
    vb = R.T @ v
    Hc = np.zeros((3, nc))
    Hc[:, 0:3] = hat_nb(vb)
    Hc[:, 3:6] = R.T
    r = vel_b - vb
    if rate_ok and meas[M_JOINT] != 0.0:  # conditioned on the rate (VoVelocityGivenRate)
        C_wv = np.ascontiguousarray(meas[M_COV_WV : M_COV_WV + 9]).reshape((3, 3)) * np.sqrt(
            s_w * s_v
        )
        G = np.linalg.solve(Rm_w, C_wv).T
        r = r - G @ r_w
        Hc[:, 6:9] += G
        cov_v = cov_v - G @ C_wv
        cov_v = 0.5 * (cov_v + cov_v.T)
    if gm:  # the residual against v_b + e
        r = r - xe[0:3]
        for i in range(3):
            Hc[i, 9 + i] = 1.0
    st = _vo_update(r, Hc, cols, cov_v, p, v, R, ba, bg, g_n, P, xe, const, off, np.int64(KIND_VEL),
                    vo_scale, adapt_n, nis_buf, acc_buf, cnt)  # fmt: skip
    return DIVERGED if st < 0 else OK if st == 1 else VEL_REJECTED


@numba.njit(cache=True)
def relative_rotation(
    omega_b: FloatArray, dt: float, R_c: FloatArray, R: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:  # pragma: no cover - compiled
    """The VO rotation ``z = omega_b dt`` against the attitude change since the clone: residual
    ``Log(dR^T Exp(z)) / dt`` (3,) with ``dR = R_c^T R``, its Jacobians on the attitude error (``I /
    dt``) and on the clone's (``-dR^T / dt``), and the right Jacobian ``J_r(z)`` that carries the VO
    noise (``Exp(z + e) ~ Exp(z) Exp(J_r e)``). With the right perturbation ``R = R_hat Exp(dtheta)``,
    ``R_c^T R ~ dR Exp(dtheta - dR^T dtheta_c)``."""
    dR = R_c.T @ R
    z = omega_b * dt
    r = log_nb(dR.T @ exp_nb(z)) / dt
    return r, np.eye(3) / dt, -dR.T / dt, right_jacobian_nb(z)


@numba.njit(cache=True)
def relative_translation(
    vel_b: FloatArray,
    omega_b: FloatArray,
    dt: float,
    R_c: FloatArray,
    p_c: FloatArray,
    p: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray]:  # pragma: no cover - compiled
    """The VO mean velocity over the pair (body frame at mid-interval) against ``Exp(-z / 2) R_c^T
    (p - p_c) / dt``, ``z = omega_b dt``: residual (3,), the Jacobian on the position error ``A / dt``
    (``A = Exp(-z / 2) R_c^T``; on the clone's position its negative) and on the clone's attitude
    ``Exp(-z / 2) [R_c^T (p - p_c)]x / dt`` (``Exp(-dtheta_c) R_c^T d ~ R_c^T d + [R_c^T d]x
    dtheta_c``)."""
    d = p - p_c
    half = exp_nb(-0.5 * omega_b * dt)
    A = half @ R_c.T
    return vel_b - A @ d / dt, A / dt, half @ hat_nb(R_c.T @ d) / dt


@numba.njit(cache=True, inline="always")
def _vo_relative(
    meas: FloatArray, p: FloatArray, v: FloatArray, R: FloatArray, ba: FloatArray, bg: FloatArray,
    g_n: FloatArray, P: FloatArray, clock: FloatArray, vo_scale: FloatArray, xe: FloatArray,
    const: FloatArray, off: IntArray, nis_buf: FloatArray, acc_buf: NDArray[np.bool_],
    cnt: IntArray,
) -> int:  # fmt: skip  # pragma: no cover - compiled
    """``vo_model: relative``, at the pair's end with the clone taken at its start: the VO rotation
    (:func:`relative_rotation`), then the translation (:func:`relative_translation`), conditioned on
    the rotation when the joint flag is set and the rotation was accepted: with the joint noise of
    ``[J_r e_w, e_v]`` and ``G = C_vw J_r^T (J_r C_ww J_r^T)^-1``, residual ``r_v - G r_w``,
    Jacobian ``H_v - G H_w``, covariance ``C_vv - G J_r C_wv``, both residuals at the current state.
    Returns OK, VEL_REJECTED or DIVERGED."""
    o = int(const[C_X_OFF])
    dt = meas[M_T1] - meas[M_T0]
    adapt_n = const[C_ADAPT_N] if clock[0] < const[C_ADAPT_UNTIL] else 0.0
    s_w = vo_scale[0]
    s_v = vo_scale[1]
    has_w = meas[M_RATE_ON] != 0.0
    omega_b = np.zeros(3)
    cov_w = np.zeros((3, 3))
    if has_w:
        omega_b = np.ascontiguousarray(meas[M_OMEGA : M_OMEGA + 3])
        cov_w = np.ascontiguousarray(meas[M_COV_W : M_COV_W + 9]).reshape((3, 3)) * s_w
    # columns [dtheta, dp, dtheta_c, dp_c]
    cols = np.empty(12, np.int64)
    for i in range(3):
        cols[i] = off[0] + i
        cols[3 + i] = off[1] + i
        cols[6 + i] = o + i
        cols[9 + i] = o + 3 + i
    cols_w = np.concatenate((cols[0:3], cols[6:9]))
    rate_ok = False
    if has_w:
        R_c = np.ascontiguousarray(xe[0:9]).reshape((3, 3))
        r, H_th, H_cth, Jr = relative_rotation(omega_b, dt, R_c, R)
        Hc = np.concatenate((H_th, H_cth), axis=1)
        st = _vo_update(r, Hc, cols_w, Jr @ cov_w @ Jr.T, p, v, R, ba, bg, g_n, P, xe, const, off,
                        np.int64(KIND_RATE), vo_scale, adapt_n, nis_buf, acc_buf, cnt)  # fmt: skip
        if st < 0:
            return DIVERGED
        rate_ok = st == 1
    if meas[M_VEL_ON] == 0.0:
        return OK
    vel_b = np.ascontiguousarray(meas[M_VEL : M_VEL + 3])
    cov_v = np.ascontiguousarray(meas[M_COV_V : M_COV_V + 9]).reshape((3, 3)) * s_v
    R_c = np.ascontiguousarray(xe[0:9]).reshape((3, 3))
    p_c = np.ascontiguousarray(xe[9:12])
    r, H_p, H_cth = relative_translation(vel_b, omega_b, dt, R_c, p_c, p)
    Hc = np.zeros((3, 12))
    Hc[:, 3:6] = H_p
    Hc[:, 6:9] = H_cth
    Hc[:, 9:12] = -H_p
    if rate_ok and meas[M_JOINT] != 0.0:
        C_wv = np.ascontiguousarray(meas[M_COV_WV : M_COV_WV + 9]).reshape((3, 3)) * np.sqrt(
            s_w * s_v
        )
        r_w, Hw_th, Hw_cth, Jr = relative_rotation(omega_b, dt, R_c, R)
        c_wv = Jr @ C_wv
        G = np.linalg.solve(Jr @ cov_w @ Jr.T, c_wv).T
        r = r - G @ r_w
        Hc[:, 0:3] -= G @ Hw_th
        Hc[:, 6:9] -= G @ Hw_cth
        cov_v = cov_v - G @ c_wv
        cov_v = 0.5 * (cov_v + cov_v.T)
    st = _vo_update(r, Hc, cols, cov_v, p, v, R, ba, bg, g_n, P, xe, const, off, np.int64(KIND_VEL),
                    vo_scale, adapt_n, nis_buf, acc_buf, cnt)  # fmt: skip
    return DIVERGED if st < 0 else OK if st == 1 else VEL_REJECTED


@numba.njit(cache=True, inline="always")
def frame_step(
    t_imu: FloatArray, acc: FloatArray, gyr: FloatArray,
    p: FloatArray, v: FloatArray, R: FloatArray, ba: FloatArray, bg: FloatArray, g_n: FloatArray,
    P: FloatArray, clock: FloatArray, vo_scale: FloatArray, xe: FloatArray, meas: FloatArray,
    const: FloatArray, R_b_v: FloatArray, p_b_v: FloatArray, q: FloatArray, off: IntArray,
    tr_t: FloatArray, tr_p: FloatArray, tr_R: FloatArray,
    bias_t: FloatArray, bias: FloatArray, bias_std: FloatArray,
    nis_buf: FloatArray, acc_buf: NDArray[np.bool_], cnt: IntArray,
) -> int:  # fmt: skip  # pragma: no cover - compiled
    """One VO frame (see the module docstring). ``meas`` (M_LEN,): mid-time, velocity (3,) m/s, its
    covariance (9,), rate (3,) rad/s, its covariance (9,), the pair's interval [t0, t1] s, the two
    flags, the rate-velocity cross-covariance (9,), the joint flag; ``const`` (C_LEN,): NHC on, its
    lateral sigma m/s and period s, gyro density^2, gate on, chi-square thresholds for 2 and 3 dof,
    its vertical sigma m/s, the online scales' n (0: off; ``vo_scale`` is then left at ones) and the
    time after which they are held, the mode, the extra states' offset, the VO error's time constant
    s and variances (3,) (m/s)^2.

    MODE_RATE and MODE_VO_ERROR: NHC updates due before the mid-time, prediction to it, the VO rate
    and velocity (:func:`_vo_rate_velocity`), a record. MODE_RELATIVE: a frame without a measurement
    moves to its mid-time; else, when the pair starts at or after the filter's time, NHC updates and
    prediction to its start and a clone there, then NHC updates and prediction to its end and the
    VO updates against the clone (:func:`_vo_relative`); a pair that starts earlier (the first) only
    moves the filter to its end. Then a record. Returns OK, VEL_REJECTED or DIVERGED (the time is
    in clock[0])."""
    relative = int(const[C_MODE]) == MODE_RELATIVE
    has_meas = meas[M_RATE_ON] != 0.0 or meas[M_VEL_ON] != 0.0
    usable = False
    t_target = meas[M_T]
    if relative and has_meas:
        t_target = meas[M_T1]
        usable = clock[0] <= meas[M_T0] + 1e-9
    # one leg to the target, or two (to the pair's start, where the pose is cloned, then to its end):
    # one call site each for the NHC updates and the prediction keeps the compiled kernel small
    legs = 2 if usable else 1
    for leg in range(legs):
        t_leg = meas[M_T0] if leg < legs - 1 else t_target
        if not _nhc_until(t_leg, t_imu, acc, gyr, p, v, R, ba, bg, g_n, P, clock, xe, const,
                          R_b_v, p_b_v, q, off, tr_t, tr_p, tr_R, bias_t, bias, bias_std,
                          nis_buf, acc_buf, cnt):  # fmt: skip
            return DIVERGED
        if not _advance(t_imu, acc, gyr, p, v, R, ba, bg, g_n, P, clock, t_leg, q, off,
                        tr_t, tr_p, tr_R, cnt, xe, const):  # fmt: skip
            return DIVERGED
        if leg < legs - 1:
            clone_pose(P, R, p, xe, off, int(const[C_X_OFF]))
    st = OK
    if not relative:
        st = _vo_rate_velocity(meas, t_imu, acc, gyr, p, v, R, ba, bg, g_n, P, clock, vo_scale, xe,
                               const, off, nis_buf, acc_buf, cnt)  # fmt: skip
    elif usable:
        st = _vo_relative(meas, p, v, R, ba, bg, g_n, P, clock, vo_scale, xe, const, off, nis_buf,
                          acc_buf, cnt)  # fmt: skip
    if st == DIVERGED:
        return DIVERGED
    mark_state(clock[0], p, R, ba, bg, P, off, tr_t, tr_p, tr_R, bias_t, bias, bias_std, cnt)
    return st


@numba.njit(cache=True)
def run_frames(
    t_imu: FloatArray, acc: FloatArray, gyr: FloatArray,
    p: FloatArray, v: FloatArray, R: FloatArray, ba: FloatArray, bg: FloatArray, g_n: FloatArray,
    P: FloatArray, clock: FloatArray, vo_scale: FloatArray, xe: FloatArray, meas: FloatArray,
    const: FloatArray, R_b_v: FloatArray, p_b_v: FloatArray, q: FloatArray, off: IntArray,
    tr_t: FloatArray, tr_p: FloatArray, tr_R: FloatArray,
    bias_t: FloatArray, bias: FloatArray, bias_std: FloatArray,
    nis_buf: FloatArray, acc_buf: NDArray[np.bool_], cnt: IntArray, vel_ok: NDArray[np.bool_],
) -> int:  # fmt: skip  # pragma: no cover - compiled
    """:func:`frame_step` over the frames' packed measurements ``meas`` (n, M_LEN) in one call (no
    Python between frames); ``vel_ok`` (n,) receives whether each frame's velocity update was accepted
    (True without one). The buffers must hold the whole batch. Returns -1, or the index of the frame at
    which the filter diverged."""
    for i in range(meas.shape[0]):
        st = frame_step(t_imu, acc, gyr, p, v, R, ba, bg, g_n, P, clock, vo_scale, xe, meas[i], const,
                        R_b_v, p_b_v, q, off, tr_t, tr_p, tr_R, bias_t, bias, bias_std, nis_buf,
                        acc_buf, cnt)  # fmt: skip
        if st == DIVERGED:
            return i
        vel_ok[i] = st != VEL_REJECTED
    return -1
