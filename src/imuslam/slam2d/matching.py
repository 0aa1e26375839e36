"""Scan-to-grid matching: a real-time correlative search, Gauss-Newton refinement against the
interpolated probability grid, and branch-and-bound correlative search for loop closure.

- Correlative search: Olson, "Real-Time Correlative Scan Matching", ICRA 2009: score every pose of a
  window (translations on the grid's cells, rotations at the step that moves the farthest point by about
  one cell, ``acos(1 - r^2 / (2 d_max^2))``, Hess 2016 eq. 7), weighted by the distance to the prior
  (Cartographer's ``translation/rotation_delta_cost_weight``).
- Refinement: Hess 2016 eq. 4, ``argmin sum_k (1 - M_smooth(T p_k))^2`` plus the pull towards the prior
  pose, by Gauss-Newton; M_smooth is the bilinear interpolation of the probability grid.
- Branch and bound: Hess 2016 section V.C (algorithm 3): pre-computed grids of the maximum over
  2^h x 2^h blocks bound the score of every translation below a node; depth-first, best child first.

Point sets are (P, 2) in the body frame, m; poses are [x, y, theta] of the body in the grid's frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
F32 = NDArray[np.float32]
U8 = NDArray[np.uint8]
I64 = NDArray[np.int64]


def angular_step(resolution: float, max_range: float) -> float:
    """Rotation that moves a point at ``max_range`` by about one cell (Hess 2016, eq. 7)."""
    d = max(max_range, 2 * resolution)
    return float(np.arccos(1.0 - resolution**2 / (2.0 * d**2)))


@numba.njit(cache=True, nogil=True, inline="always")
def _cell_sum(
    prob: F32, cx: I64, cy: I64, dx: int, dy: int, p_unknown: float
) -> float:  # pragma: no cover - compiled
    """Sum of the grid's probabilities at the points' cells shifted by (dx, dy); off the grid counts as
    ``p_unknown``."""
    H, W = prob.shape
    acc = 0.0
    for k in range(cx.size):
        ix = cx[k] + dx
        iy = cy[k] + dy
        if 0 <= ix < W and 0 <= iy < H:
            acc += prob[iy, ix]
        else:
            acc += p_unknown
    return acc


@numba.njit(cache=True)
def correlative_search(
    prob: F32,
    x0: float,
    y0: float,
    res: float,
    pts_b: FloatArray,
    pose0: FloatArray,
    lin_cells: int,
    n_ang: int,
    ang_step: float,
    w_trans: float,
    w_rot: float,
    p_unknown: float,
) -> tuple[FloatArray, float]:  # pragma: no cover - compiled
    """Exhaustive search of ``pose0`` +- lin_cells cells and +- n_ang angle steps; returns the best pose
    and its score (mean probability times exp(-w_trans |dt|^2 - w_rot dtheta^2))."""
    P = pts_b.shape[0]
    best = -1.0
    bx, by, bt = pose0[0], pose0[1], pose0[2]
    cx = np.empty(P, np.int64)
    cy = np.empty(P, np.int64)
    for a in range(-n_ang, n_ang + 1):
        th = pose0[2] + a * ang_step
        c, s = np.cos(th), np.sin(th)
        for k in range(P):
            px = c * pts_b[k, 0] - s * pts_b[k, 1] + pose0[0]
            py = s * pts_b[k, 0] + c * pts_b[k, 1] + pose0[1]
            cx[k] = int(np.floor((px - x0) / res))
            cy[k] = int(np.floor((py - y0) / res))
        rot_pen = w_rot * (a * ang_step) ** 2
        for dy in range(-lin_cells, lin_cells + 1):
            for dx in range(-lin_cells, lin_cells + 1):
                acc = _cell_sum(prob, cx, cy, dx, dy, p_unknown)
                sc = acc / P * np.exp(-(w_trans * ((dx * res) ** 2 + (dy * res) ** 2) + rot_pen))
                if sc > best:
                    best = sc
                    bx = pose0[0] + dx * res
                    by = pose0[1] + dy * res
                    bt = th
    out = np.empty(3)
    out[0], out[1], out[2] = bx, by, bt
    return out, best


@numba.njit(cache=True, nogil=True)
def _bilinear(
    prob: F32, u: float, v: float, p_unknown: float
) -> tuple[float, float, float]:  # pragma: no cover
    """Value and gradient (d/du, d/dv) at continuous cell coordinates (cell centres at i + 0.5)."""
    H, W = prob.shape
    u -= 0.5
    v -= 0.5
    i0 = int(np.floor(u))
    j0 = int(np.floor(v))
    fu = u - i0
    fv = v - j0
    if i0 < 0 or j0 < 0 or i0 + 1 >= W or j0 + 1 >= H:
        return p_unknown, 0.0, 0.0
    a = prob[j0, i0]
    b = prob[j0, i0 + 1]
    c = prob[j0 + 1, i0]
    d = prob[j0 + 1, i0 + 1]
    val = a * (1 - fu) * (1 - fv) + b * fu * (1 - fv) + c * (1 - fu) * fv + d * fu * fv
    du = (b - a) * (1 - fv) + (d - c) * fv
    dv = (c - a) * (1 - fu) + (d - b) * fu
    return val, du, dv


@numba.njit(cache=True, nogil=True)
def _bicubic(
    prob: F32, u: float, v: float, p_unknown: float
) -> tuple[float, float, float]:  # pragma: no cover
    """Catmull-Rom bicubic value and gradient (d/du, d/dv) at continuous cell coordinates (cell centres
    at i + 0.5): the interpolation Cartographer's Ceres scan matcher uses (ceres::BiCubicInterpolator),
    continuous in its gradient where the bilinear one jumps at every cell border."""
    H, W = prob.shape
    u -= 0.5
    v -= 0.5
    i0 = int(np.floor(u))
    j0 = int(np.floor(v))
    if i0 < 1 or j0 < 1 or i0 + 2 >= W or j0 + 2 >= H:
        return p_unknown, 0.0, 0.0
    tu = u - i0
    tv = v - j0
    wu = np.empty(4)
    wv = np.empty(4)
    du = np.empty(4)
    dv = np.empty(4)
    for t, w, d in ((tu, wu, du), (tv, wv, dv)):
        t2 = t * t
        t3 = t2 * t
        w[0] = 0.5 * (-t3 + 2 * t2 - t)
        w[1] = 0.5 * (3 * t3 - 5 * t2 + 2)
        w[2] = 0.5 * (-3 * t3 + 4 * t2 + t)
        w[3] = 0.5 * (t3 - t2)
        d[0] = 0.5 * (-3 * t2 + 4 * t - 1)
        d[1] = 0.5 * (9 * t2 - 10 * t)
        d[2] = 0.5 * (-9 * t2 + 8 * t + 1)
        d[3] = 0.5 * (3 * t2 - 2 * t)
    val = 0.0
    gu = 0.0
    gv = 0.0
    for j in range(4):
        for i in range(4):
            p = prob[j0 - 1 + j, i0 - 1 + i]
            val += wv[j] * wu[i] * p
            gu += wv[j] * du[i] * p
            gv += dv[j] * wu[i] * p
    return val, gu, gv


@numba.njit(cache=True, nogil=True, inline="always")
def _interp(
    prob: F32, u: float, v: float, p_unknown: float, cubic: bool
) -> tuple[float, float, float]:  # pragma: no cover
    if cubic:
        return _bicubic(prob, u, v, p_unknown)
    return _bilinear(prob, u, v, p_unknown)


@numba.njit(cache=True, nogil=True)
def refine_pose(
    prob: F32,
    x0: float,
    y0: float,
    res: float,
    pts_b: FloatArray,
    pose_init: FloatArray,
    prior: FloatArray,
    w_occ: float,
    w_trans: float,
    w_rot: float,
    p_unknown: float,
    iters: int,
    cubic: bool = False,
) -> tuple[FloatArray, float]:  # pragma: no cover - compiled
    """Gauss-Newton (Levenberg-damped) on Hess 2016 eq. 4 plus the prior terms
    ``w_trans^2 |t - t_prior|^2 + w_rot^2 (theta - theta_prior)^2``; occupied residuals weighted
    ``w_occ / sqrt(P)`` as Cartographer's; the grid interpolated bilinearly, or bicubically with
    ``cubic``. Returns the pose and the mean probability at the points."""
    P = pts_b.shape[0]
    x = pose_init.copy()
    wo = w_occ / np.sqrt(P)
    lam = 1e-3

    def cost_of(xx: FloatArray) -> float:
        c, s = np.cos(xx[2]), np.sin(xx[2])
        tot = 0.0
        for k in range(P):
            px = c * pts_b[k, 0] - s * pts_b[k, 1] + xx[0]
            py = s * pts_b[k, 0] + c * pts_b[k, 1] + xx[1]
            val, _, _ = _interp(prob, (px - x0) / res, (py - y0) / res, p_unknown, cubic)
            tot += (wo * (1.0 - val)) ** 2
        tot += (w_trans * (xx[0] - prior[0])) ** 2 + (w_trans * (xx[1] - prior[1])) ** 2
        tot += (w_rot * (xx[2] - prior[2])) ** 2
        return tot

    cost = cost_of(x)
    for _ in range(iters):
        c, s = np.cos(x[2]), np.sin(x[2])
        A = np.zeros((3, 3))
        g = np.zeros(3)
        for k in range(P):
            bx, by = pts_b[k, 0], pts_b[k, 1]
            px = c * bx - s * by + x[0]
            py = s * bx + c * by + x[1]
            val, du, dv = _interp(prob, (px - x0) / res, (py - y0) / res, p_unknown, cubic)
            r = wo * (1.0 - val)
            jx = -wo * du / res
            jy = -wo * dv / res
            jt = jx * (-s * bx - c * by) + jy * (c * bx - s * by)
            J = (jx, jy, jt)
            for i in range(3):
                g[i] += J[i] * r
                for j in range(3):
                    A[i, j] += J[i] * J[j]
        r0 = w_trans * (x[0] - prior[0])
        r1 = w_trans * (x[1] - prior[1])
        r2 = w_rot * (x[2] - prior[2])
        A[0, 0] += w_trans**2
        A[1, 1] += w_trans**2
        A[2, 2] += w_rot**2
        g[0] += w_trans * r0
        g[1] += w_trans * r1
        g[2] += w_rot * r2
        improved = False
        for _t in range(6):
            Ad = A.copy()
            for i in range(3):
                Ad[i, i] += lam * (A[i, i] + 1e-9)
            step = np.linalg.solve(Ad, -g)
            xn = x + step
            cn = cost_of(xn)
            if cn < cost:
                x = xn
                lam = max(lam * 0.3, 1e-6)
                improved = cn > cost - 1e-10
                cost = cn
                improved = True
                break
            lam *= 10.0
        if not improved or (abs(step[0]) < 1e-5 and abs(step[1]) < 1e-5 and abs(step[2]) < 1e-6):
            break
    c, s = np.cos(x[2]), np.sin(x[2])
    acc = 0.0
    for k in range(P):
        px = c * pts_b[k, 0] - s * pts_b[k, 1] + x[0]
        py = s * pts_b[k, 0] + c * pts_b[k, 1] + x[1]
        val, _, _ = _interp(prob, (px - x0) / res, (py - y0) / res, p_unknown, cubic)
        acc += val
    return x, acc / P


@numba.njit(cache=True, nogil=True)
def match_information(
    prob: F32,
    x0: float,
    y0: float,
    res: float,
    pts_b: FloatArray,
    pose: FloatArray,
    w_occ: float,
    p_unknown: float,
) -> FloatArray:  # pragma: no cover - compiled
    """J^T J (3 x 3, [x, y, theta] in the grid's frame) of the refinement's occupied-space residuals at
    ``pose``: the scan's information about its pose (small along a corridor's axis, where every shift
    fits as well; Censi 2007's Hessian approximation of an ICP covariance, here of Hess 2016 eq. 4)."""
    P = pts_b.shape[0]
    wo = w_occ / np.sqrt(P)
    c, s = np.cos(pose[2]), np.sin(pose[2])
    A = np.zeros((3, 3))
    for k in range(P):
        bx, by = pts_b[k, 0], pts_b[k, 1]
        px = c * bx - s * by + pose[0]
        py = s * bx + c * by + pose[1]
        _, du, dv = _bilinear(prob, (px - x0) / res, (py - y0) / res, p_unknown)
        jx = -wo * du / res
        jy = -wo * dv / res
        jt = jx * (-s * bx - c * by) + jy * (c * bx - s * by)
        J = (jx, jy, jt)
        for i in range(3):
            for j in range(3):
                A[i, j] += J[i] * J[j]
    return A


def refine_pose_reference(
    prob: F32, x0: float, y0: float, res: float, pts_b: FloatArray, pose_init: FloatArray,
    prior: FloatArray, w_occ: float, w_trans: float, w_rot: float, p_unknown: float,
    cubic: bool = False,
) -> FloatArray:  # fmt: skip
    """Slow reference of :func:`refine_pose`: scipy's least squares on the same residuals (for tests);
    bilinear by scipy's grid interpolator, bicubic by the Catmull-Rom kernel written out in numpy."""
    from scipy.interpolate import RegularGridInterpolator
    from scipy.optimize import least_squares

    H, W = prob.shape
    yc = (np.arange(H) + 0.5) * res + y0
    xc = (np.arange(W) + 0.5) * res + x0
    f = RegularGridInterpolator(
        (yc, xc), prob.astype(float), bounds_error=False, fill_value=p_unknown
    )
    wo = w_occ / np.sqrt(len(pts_b))
    P64 = prob.astype(float)

    def catmull_rom(p: FloatArray) -> FloatArray:
        u, v = (p[:, 0] - x0) / res - 0.5, (p[:, 1] - y0) / res - 0.5
        i0, j0 = np.floor(u).astype(int), np.floor(v).astype(int)
        ok = (i0 >= 1) & (j0 >= 1) & (i0 + 2 < W) & (j0 + 2 < H)

        def weights(t: FloatArray) -> FloatArray:  # Keys' cubic convolution kernel, a = -0.5
            d = np.abs(t[:, None] - np.arange(-1, 3)[None, :])
            return np.where(d <= 1, 1.5 * d**3 - 2.5 * d**2 + 1,
                            np.where(d < 2, -0.5 * d**3 + 2.5 * d**2 - 4 * d + 2, 0.0))  # fmt: skip

        wu, wv = weights(u - i0), weights(v - j0)
        out = np.full(len(p), p_unknown)
        for n in np.flatnonzero(ok):
            patch = P64[j0[n] - 1 : j0[n] + 3, i0[n] - 1 : i0[n] + 3]
            out[n] = wv[n] @ patch @ wu[n]
        return out

    def resid(x: FloatArray) -> FloatArray:
        c, s = np.cos(x[2]), np.sin(x[2])
        p = pts_b @ np.array([[c, s], [-s, c]]) + x[:2]
        occ = wo * (1.0 - (catmull_rom(p) if cubic else f(p[:, ::-1])))
        return np.concatenate([occ, w_trans * (x[:2] - prior[:2]), [w_rot * (x[2] - prior[2])]])

    return np.asarray(least_squares(resid, pose_init, method="lm", xtol=1e-10).x)


# ----------------------------------------------------------------------------------------------
# Branch and bound (Hess 2016, section V)


@numba.njit(cache=True, nogil=True)
def precompute_max_grids(prob: F32, depth: int) -> U8:  # pragma: no cover - compiled
    """Levels 0..depth (depth + 1, H + 2 pad, W + 2 pad), pad = 2^depth - 1, uint8 (probability * 255):
    level h at padded (Y, X) is the maximum of level 0 over [Y, Y + 2^h) x [X, X + 2^h) (Hess 2016
    eq. 14), built by doubling: each level is the maximum of four shifted copies of the one below."""
    H, W = prob.shape
    pad = (1 << depth) - 1
    Hp, Wp = H + 2 * pad, W + 2 * pad
    out = np.zeros((depth + 1, Hp, Wp), np.uint8)
    for y in range(H):
        for x in range(W):
            out[0, y + pad, x + pad] = np.uint8(min(255.0, max(0.0, prob[y, x] * 255.0 + 0.5)))
    for h in range(1, depth + 1):
        s = 1 << (h - 1)
        for y in range(Hp):
            for x in range(Wp):
                m = out[h - 1, y, x]
                if x + s < Wp and out[h - 1, y, x + s] > m:
                    m = out[h - 1, y, x + s]
                if y + s < Hp:
                    if out[h - 1, y + s, x] > m:
                        m = out[h - 1, y + s, x]
                    if x + s < Wp and out[h - 1, y + s, x + s] > m:
                        m = out[h - 1, y + s, x + s]
                out[h, y, x] = m
    return out


@numba.njit(cache=True, nogil=True)
def _score(
    levels: U8, h: int, cells: NDArray[np.int64], a: int, ox: int, oy: int
) -> float:  # pragma: no cover
    _, Hp, Wp = levels.shape
    P = cells.shape[1]
    acc = 0
    for k in range(P):
        x = cells[a, k, 0] + ox
        y = cells[a, k, 1] + oy
        if 0 <= x < Wp and 0 <= y < Hp:
            acc += levels[h, y, x]
    return acc / (255.0 * P)


@numba.njit(cache=True, nogil=True, inline="always")
def _excluded(
    h: int, a: int, x: int, y: int, ex: NDArray[np.int64], ex_r: float, ex_ang: int
) -> bool:  # pragma: no cover - compiled
    """Whether every pose of the node (angle a, cells [x, x + 2^h) x [y, y + 2^h)) lies within ``ex_r``
    cells and ``ex_ang`` angle steps of one excluded peak (rows (angle, x, y) of ``ex``)."""
    e = (1 << h) - 1
    for q in range(ex.shape[0]):
        if abs(a - ex[q, 0]) > ex_ang:
            continue
        fx = max(abs(x - ex[q, 1]), abs(x + e - ex[q, 1]))
        fy = max(abs(y - ex[q, 2]), abs(y + e - ex[q, 2]))
        if fx * fx + fy * fy <= ex_r * ex_r:
            return True
    return False


@numba.njit(cache=True, nogil=True)
def branch_and_bound(
    levels: U8,
    cells: NDArray[np.int64],
    lin_cells: int,
    min_score: float,
    ex: NDArray[np.int64],
    ex_r: float,
    ex_ang: int,
) -> tuple[int, int, int, float]:  # pragma: no cover - compiled
    """Best (angle index, dx, dy) cells over the window [-lin_cells, lin_cells]^2 of every discretised
    rotation ``cells`` (A, P, 2) (padded level-0 cell indices at zero offset); returns score -1 if none
    reaches ``min_score``. The poses within ``ex_r`` cells and ``ex_ang`` angle steps of a row
    (angle, dx, dy) of ``ex`` (E, 3) are left out (E = 0: none): the best pose clearly away from peaks
    found before (nodes wholly inside one neighbourhood are pruned; their bounds stay valid for the
    others)."""
    depth = levels.shape[0] - 1
    A = cells.shape[0]
    step = 1 << depth
    cap = 1 << 20
    st_h = np.empty(cap, np.int64)
    st_a = np.empty(cap, np.int64)
    st_x = np.empty(cap, np.int64)
    st_y = np.empty(cap, np.int64)
    st_s = np.empty(cap, np.float64)
    # root candidates, pushed in ascending score so the best is popped first
    nroot = 0
    xs = np.arange(-lin_cells, lin_cells + 1, step)
    n1 = xs.shape[0]
    rs = np.empty(A * n1 * n1)
    ra = np.empty(A * n1 * n1, np.int64)
    rx = np.empty(A * n1 * n1, np.int64)
    ry = np.empty(A * n1 * n1, np.int64)
    for a in range(A):
        for i in range(n1):
            for j in range(n1):
                rs[nroot] = _score(levels, depth, cells, a, xs[i], xs[j])
                ra[nroot] = a
                rx[nroot] = xs[i]
                ry[nroot] = xs[j]
                nroot += 1
    order = np.argsort(rs[:nroot])
    top = 0
    for q in order:
        if _excluded(depth, ra[q], rx[q], ry[q], ex, ex_r, ex_ang):
            continue
        if rs[q] > min_score and top < cap:
            st_h[top] = depth
            st_a[top] = ra[q]
            st_x[top] = rx[q]
            st_y[top] = ry[q]
            st_s[top] = rs[q]
            top += 1
    best = min_score
    ba, bx, by = -1, 0, 0
    cs = np.empty(4)
    cx = np.empty(4, np.int64)
    cy = np.empty(4, np.int64)
    while top > 0:
        top -= 1
        h, a, x, y, sc = st_h[top], st_a[top], st_x[top], st_y[top], st_s[top]
        if sc <= best:
            continue
        if h == 0:
            best = sc
            ba, bx, by = a, x, y
            continue
        hh = h - 1
        s = 1 << hh
        n = 0
        for ddx in (0, s):
            for ddy in (0, s):
                nx, ny = x + ddx, y + ddy
                if nx > lin_cells or ny > lin_cells:
                    continue
                if _excluded(hh, a, nx, ny, ex, ex_r, ex_ang):
                    continue
                cs[n] = _score(levels, hh, cells, a, nx, ny)
                cx[n] = nx
                cy[n] = ny
                n += 1
        o = np.argsort(cs[:n])
        for q in o:
            if cs[q] > best and top < cap:
                st_h[top] = hh
                st_a[top] = a
                st_x[top] = cx[q]
                st_y[top] = cy[q]
                st_s[top] = cs[q]
                top += 1
    return ba, bx, by, best if ba >= 0 else -1.0


@dataclass
class SubmapIndex:
    """A finished submap prepared for loop closure: the max grids, its origin and resolution."""

    levels: U8
    x0: float
    y0: float
    res: float
    pad: int


NO_EX = np.zeros((0, 3), np.int64)  # branch and bound without excluded peaks


def make_index(prob: F32, x0: float, y0: float, res: float, depth: int) -> SubmapIndex:
    return SubmapIndex(precompute_max_grids(prob, depth), x0, y0, res, (1 << depth) - 1)


def _rotated_cells(
    index: SubmapIndex, pts_b: FloatArray, pose0: FloatArray, ang_window: float, step_range: float
) -> tuple[FloatArray, NDArray[np.int64]]:
    """The search's rotations around ``pose0`` and every point's padded level-0 cell under each."""
    res = index.res
    d_max = float(np.max(np.hypot(pts_b[:, 0], pts_b[:, 1]))) if len(pts_b) else 1.0
    d_max = min(d_max, step_range)
    step = angular_step(res, d_max)
    n_ang = int(np.ceil(ang_window / step))
    th = pose0[2] + np.arange(-n_ang, n_ang + 1) * step
    c, s = np.cos(th)[:, None], np.sin(th)[:, None]
    px = c * pts_b[None, :, 0] - s * pts_b[None, :, 1] + pose0[0]
    py = s * pts_b[None, :, 0] + c * pts_b[None, :, 1] + pose0[1]
    cells = np.empty((len(th), len(pts_b), 2), np.int64)
    cells[..., 0] = np.floor((px - index.x0) / res).astype(np.int64) + index.pad
    cells[..., 1] = np.floor((py - index.y0) / res).astype(np.int64) + index.pad
    return th, cells


def bnb_match(
    index: SubmapIndex,
    pts_b: FloatArray,
    pose0: FloatArray,
    lin_window: float,
    ang_window: float,
    min_score: float,
    step_range: float = np.inf,
) -> tuple[FloatArray, float]:
    """Branch-and-bound search around ``pose0`` (in the submap's frame): the best pose on the search
    lattice and its score (mean probability), or score -1 when nothing reaches ``min_score``. The angular
    step moves a point at ``min(step_range, farthest point)`` by one cell."""
    th, cells = _rotated_cells(index, pts_b, pose0, ang_window, step_range)
    lin_cells = int(np.ceil(lin_window / index.res))
    a, dx, dy, score = branch_and_bound(index.levels, cells, lin_cells, min_score, NO_EX, -1.0, 0)
    if a < 0:
        return pose0.copy(), -1.0
    return np.array([pose0[0] + dx * index.res, pose0[1] + dy * index.res, th[a]]), float(score)


def bnb_match_distinct(
    index: SubmapIndex,
    pts_b: FloatArray,
    pose0: FloatArray,
    lin_window: float,
    ang_window: float,
    min_score: float,
    step_range: float,
    peak_radius: float,
    peak_angle: float,
    margin: float,
) -> tuple[FloatArray, float, float]:
    """``bnb_match``, then a second branch and bound over the same window without the poses within
    ``peak_radius`` m and ``peak_angle`` rad of the best: the match is distinct when no pose clearly
    away from it scores within ``margin`` of it (a corridor or a repeated room gives several peaks of
    about the same score; Olson's "local uniqueness" test, E. Olson, "Recognizing places using spectrally
    clustered local matches", Robotics and Autonomous Systems 57(12), 2009). Returns the pose, its
    lattice score (-1 when nothing reaches ``min_score``) and the best score away from it (-1 when none
    reaches ``score - margin``: distinct; the score itself when the best pose is on the window's edge)."""
    th, cells = _rotated_cells(index, pts_b, pose0, ang_window, step_range)
    lin_cells = int(np.ceil(lin_window / index.res))
    a, dx, dy, score = branch_and_bound(index.levels, cells, lin_cells, min_score, NO_EX, -1.0, 0)
    if a < 0:
        return pose0.copy(), -1.0, -1.0
    pose = np.array([pose0[0] + dx * index.res, pose0[1] + dy * index.res, th[a]])
    if max(abs(dx), abs(dy)) >= lin_cells or (len(th) > 1 and a in (0, len(th) - 1)):
        # the best pose on the window's edge is no peak: the scan may fit better outside the window
        return pose, float(score), float(score)
    step = float(th[1] - th[0]) if len(th) > 1 else np.inf
    ex_ang = int(np.floor(peak_angle / step)) if np.isfinite(step) else 0
    a2, _, _, second = branch_and_bound(
        index.levels, cells, lin_cells, max(score - margin, 0.0), np.array([[a, dx, dy]], np.int64),
        peak_radius / index.res, ex_ang,
    )  # fmt: skip
    return pose, float(score), float(second) if a2 >= 0 else -1.0


def bnb_match_peaks(
    index: SubmapIndex,
    pts_b: FloatArray,
    pose0: FloatArray,
    lin_window: float,
    ang_window: float,
    min_score: float,
    step_range: float,
    peak_radius: float,
    peak_angle: float,
    n_peaks: int,
) -> list[tuple[FloatArray, float]]:
    """The best ``n_peaks`` peaks of the window reaching ``min_score``, best first: branch and bound, then
    again without the poses within ``peak_radius`` m and ``peak_angle`` rad of every peak found so far
    (each a lattice pose and its score). A peak on the window's edge is left out but still excluded (the
    scan may fit better outside the window). Where no single peak is distinct, the true one is often among
    the few best, and consecutive scans agree on it while wrong ones scatter (Olson 2009's consistency of
    several hypotheses, checked by the caller)."""
    th, cells = _rotated_cells(index, pts_b, pose0, ang_window, step_range)
    lin_cells = int(np.ceil(lin_window / index.res))
    step = float(th[1] - th[0]) if len(th) > 1 else np.inf
    ex_ang = int(np.floor(peak_angle / step)) if np.isfinite(step) else 0
    ex = np.zeros((0, 3), np.int64)
    out: list[tuple[FloatArray, float]] = []
    for _ in range(n_peaks + 2):  # up to two edge peaks skipped
        a, dx, dy, score = branch_and_bound(
            index.levels, cells, lin_cells, min_score, ex, peak_radius / index.res, ex_ang
        )
        if a < 0:
            break
        ex = np.vstack([ex, np.array([[a, dx, dy]], np.int64)])
        if max(abs(dx), abs(dy)) >= lin_cells or (len(th) > 1 and a in (0, len(th) - 1)):
            continue
        out.append((np.array([pose0[0] + dx * index.res, pose0[1] + dy * index.res, th[a]]), score))
        if len(out) == n_peaks:
            break
    return out


@numba.njit(cache=True, nogil=True)
def score_volume(
    prob: F32,
    x0: float,
    y0: float,
    res: float,
    pts_b: FloatArray,
    pose0: FloatArray,
    lin_cells: int,
    n_ang: int,
    ang_step: float,
    p_unknown: float,
) -> F32:  # pragma: no cover - compiled
    """The score (mean probability at the points, no prior weighting) of every pose of the window
    ``pose0`` +- lin_cells cells, +- n_ang angle steps: (2 n_ang + 1, 2 lin_cells + 1, 2 lin_cells + 1)
    indexed [angle, dy, dx]. Shows how distinct a match's peak is (the correlative search's lattice)."""
    P = pts_b.shape[0]
    n = 2 * lin_cells + 1
    out = np.zeros((2 * n_ang + 1, n, n), np.float32)
    cx = np.empty(P, np.int64)
    cy = np.empty(P, np.int64)
    for a in range(-n_ang, n_ang + 1):
        th = pose0[2] + a * ang_step
        c, s = np.cos(th), np.sin(th)
        for k in range(P):
            cx[k] = int(np.floor((c * pts_b[k, 0] - s * pts_b[k, 1] + pose0[0] - x0) / res))
            cy[k] = int(np.floor((s * pts_b[k, 0] + c * pts_b[k, 1] + pose0[1] - y0) / res))
        for dy in range(-lin_cells, lin_cells + 1):
            for dx in range(-lin_cells, lin_cells + 1):
                acc = _cell_sum(prob, cx, cy, dx, dy, p_unknown)
                out[a + n_ang, dy + lin_cells, dx + lin_cells] = acc / P
    return out
