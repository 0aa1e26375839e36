"""RK4 integration of corrected gyro rates over the rotations between static poses.

``integrate_segments`` returns the rotations ``R_start_end`` (P, S, 3, 3) of the rates
``Ms[p] @ (w - offsets[p]) - Gs[p] @ f`` over each segment (S, 2) of samples, for P parameter sets at
once: RK4 on the quaternion with the rate at the step midpoint taken as the mean of its ends (Tedaldi
2014, eq. 14; the slow reference is ``tests/imu/rk4_reference.py``). Two implementations:

- ``integrate_segments`` (the default): the compiled kernel of ``imu.rk4_compiled``, for callers that
  integrate thousands of times (the joint fit, cross-validation, the pose planner);
- ``integrate_segments_numpy``: the same integration in numpy, for one tedaldi fit, where importing
  numba and loading the kernel would cost more than the whole fit.

The numpy form rests on the ODE being linear in the quaternion: ``q' = 0.5 q (x) [0, w(t)]``, so one
RK4 step from any ``q`` is ``q (x) dq`` with ``dq`` the step taken from the identity, and the segment's
rotation is the ordered product of the ``dq`` (the per-step renormalisation only rescales, so it moves
to the end). The products are taken as a balanced tree (associativity), vectorised over the steps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imuslam.geometry import quat_to_matrix

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

_BLOCK = 16  # steps multiplied (or scanned) together inside a chunk (a power of two)
_CHUNK = 4096  # steps per vectorised chunk: 32 kB arrays stay in cache and off the mmap allocator
Quat = tuple[FloatArray, FloatArray, FloatArray, FloatArray]


def _qmul(a: Quat, b: Quat) -> Quat:
    """Hamilton product ``a (x) b`` of quaternions stored as four component arrays."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def _halve(q: Quat) -> Quat:
    """Products of neighbouring pairs along the last axis (even (x) odd)."""
    return _qmul(
        (q[0][..., 0::2], q[1][..., 0::2], q[2][..., 0::2], q[3][..., 0::2]),
        (q[0][..., 1::2], q[1][..., 1::2], q[2][..., 1::2], q[3][..., 1::2]),
    )


def _times_pure(
    s: FloatArray | float, bx: FloatArray, by: FloatArray, bz: FloatArray, x: FloatArray
) -> Quat:
    """``0.5 (s, b) (x) (0, x)`` with ``x`` (3, n)."""
    xx, xy, xz = x[0], x[1], x[2]
    return (
        -0.5 * (bx * xx + by * xy + bz * xz),
        0.5 * (s * xx + by * xz - bz * xy),
        0.5 * (s * xy - bx * xz + bz * xx),
        0.5 * (s * xz + bx * xy - by * xx),
    )


def _step_quats(x0: FloatArray, x1: FloatArray, h: FloatArray) -> Quat:
    """RK4 step ``dq`` from the identity for rates ``x0`` -> ``x1`` (3, n) over ``h`` (n,) seconds.

    The four stages of ``q' = 0.5 q (x) [0, w]`` with ``q = 1`` (the rate at the midpoint is the mean of
    the ends); a zero ``h`` gives the identity exactly (padding).
    """
    xm = 0.5 * (x0 + x1)
    hh = 0.5 * h
    k1x, k1y, k1z = 0.5 * x0[0], 0.5 * x0[1], 0.5 * x0[2]
    k2 = _times_pure(1.0, hh * k1x, hh * k1y, hh * k1z, xm)
    k3 = _times_pure(1.0 + hh * k2[0], hh * k2[1], hh * k2[2], hh * k2[3], xm)
    k4 = _times_pure(1.0 + h * k3[0], h * k3[1], h * k3[2], h * k3[3], x1)
    c = h / 6.0
    return (
        1.0 + c * (2.0 * (k2[0] + k3[0]) + k4[0]),
        c * (k1x + 2.0 * (k2[1] + k3[1]) + k4[1]),
        c * (k1y + 2.0 * (k2[2] + k3[2]) + k4[2]),
        c * (k1z + 2.0 * (k2[3] + k3[3]) + k4[3]),
    )


@dataclass(frozen=True)
class _Layout:
    """Each segment's steps laid flat and padded (h = 0, the identity) to whole blocks, so that no
    block and no chunk (a whole number of blocks) straddles two segments."""

    i0: IntArray  # (n,) first sample of each step
    i1: IntArray  # (n,) second sample (== i0 on padding)
    h: FloatArray  # (n,) step length, s; 0 on padding
    first: IntArray  # (S,) flat index of each segment's first step
    last: IntArray  # (S,) flat index of each segment's last real step (its first if it has none)
    block_seg: IntArray  # (B,) segment of each block
    block_pos: IntArray  # (B,) position of each block within its segment
    n_grid: int  # power of two >= the most blocks of a segment


def _layout(t_s: FloatArray, segs: IntArray) -> _Layout:
    S = segs.shape[0]
    n_steps = np.maximum(segs[:, 1] - segs[:, 0], 0)
    n_blocks = np.maximum(-(-n_steps // _BLOCK), 1)
    padded = n_blocks * _BLOCK
    first = np.concatenate([[0], np.cumsum(padded)[:-1]])
    seg_of = np.repeat(np.arange(S), padded)
    k = np.arange(int(padded.sum())) - first[seg_of]
    valid = k < n_steps[seg_of]
    i0 = np.where(valid, segs[seg_of, 0] + k, segs[seg_of, 0])
    i1 = np.where(valid, i0 + 1, i0)
    h = np.where(valid, t_s[i1] - t_s[i0], 0.0)
    block_first = np.concatenate([[0], np.cumsum(n_blocks)[:-1]])
    block_seg = np.repeat(np.arange(S), n_blocks)
    block_pos = np.arange(int(n_blocks.sum())) - block_first[block_seg]
    n_grid = 1 << int(np.ceil(np.log2(int(n_blocks.max()))))
    last = first + np.maximum(n_steps - 1, 0)
    return _Layout(i0, i1, h, first, last, block_seg, block_pos, n_grid)


def integrate_segments_numpy(
    w: FloatArray,
    t_s: FloatArray,
    segs: IntArray,
    Ms: FloatArray,
    offsets: FloatArray | None = None,
    Gs: FloatArray | None = None,
    f: FloatArray | None = None,
) -> FloatArray:
    """``integrate_segments`` in numpy (equal to the compiled kernel to rounding, ~1e-14)."""
    w = np.asarray(w, dtype=np.float64)
    t_s = np.asarray(t_s, dtype=np.float64)
    segs = np.asarray(segs, dtype=np.int64).reshape(-1, 2)
    Ms = np.asarray(Ms, dtype=np.float64).reshape(-1, 3, 3)
    P, S = Ms.shape[0], segs.shape[0]
    offs = np.zeros((P, 3)) if offsets is None else np.asarray(offsets, dtype=np.float64)
    offs = offs.reshape(P, 3)
    lay = _layout(t_s, segs)
    total = lay.h.size
    v0, v1 = np.ascontiguousarray(w[lay.i0].T), np.ascontiguousarray(w[lay.i1].T)  # (3, n)
    g_sens = Gs is not None and f is not None
    if g_sens:
        f_arr = np.asarray(f, dtype=np.float64)
        f0, f1 = np.ascontiguousarray(f_arr[lay.i0].T), np.ascontiguousarray(f_arr[lay.i1].T)
        G_all = np.asarray(Gs, dtype=np.float64).reshape(P, 3, 3)
    out = np.empty((P, S, 4))
    blocks = np.empty((4, lay.block_seg.size))
    for p in range(P):
        M = Ms[p]
        Mo = (M @ offs[p])[:, None]
        for c0 in range(0, total, _CHUNK):
            c1 = min(c0 + _CHUNK, total)
            x0 = M @ v0[:, c0:c1] - Mo
            x1 = M @ v1[:, c0:c1] - Mo
            if g_sens:
                x0 -= G_all[p] @ f0[:, c0:c1]
                x1 -= G_all[p] @ f1[:, c0:c1]
            q = _step_quats(x0, x1, lay.h[c0:c1])
            for _ in range(_BLOCK.bit_length() - 1):
                q = _halve(q)
            b0 = c0 // _BLOCK
            for j in range(4):
                blocks[j, b0 : b0 + q[j].size] = q[j]
        grid = np.zeros((4, S, lay.n_grid))
        grid[0] = 1.0
        grid[:, lay.block_seg, lay.block_pos] = blocks
        gq: Quat = (grid[0], grid[1], grid[2], grid[3])
        while gq[0].shape[-1] > 1:
            gq = _halve(gq)
        out[p] = np.stack([c[:, 0] for c in gq], axis=-1)
    return quat_to_matrix(out)


def _scan(q: Quat, axis_len: int) -> Quat:
    """Inclusive prefix products along the last axis (Hillis & Steele 1986): ``y_j = q_0 ... q_j``."""
    y = tuple(np.array(c) for c in q)
    d = 1
    while d < axis_len:
        prod = _qmul(
            (y[0][..., :-d], y[1][..., :-d], y[2][..., :-d], y[3][..., :-d]),
            (y[0][..., d:], y[1][..., d:], y[2][..., d:], y[3][..., d:]),
        )
        for j in range(4):
            y[j][..., d:] = prod[j]
        d *= 2
    return (y[0], y[1], y[2], y[3])


def integrate_segments_sensitivity(
    w: FloatArray,
    t_s: FloatArray,
    segs: IntArray,
    M: FloatArray,
    offset: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The rotations of ``integrate_segments`` for one parameter set, with their first derivatives.

    Returns ``R`` (S, 3, 3), ``Z`` (S, 3, 3, 3) and ``Y`` (S, 3, 3): a change ``dM`` of the rate matrix
    and ``dw`` of a constant rate added to every corrected sample turn each segment's rotation into
    ``R Exp(dtheta)`` with ``dtheta = sum_ab Z[:, :, a, b] dM[a, b] + Y dw`` (to first order).

    Each step is ``Exp(phi_k)`` with ``phi_k = h_k M v_k`` (``v_k`` the mean raw rate of the step, less
    the offset); a change of ``phi_k`` moves the segment's end by ``R^T R_incl,k J_r(phi_k) dphi_k``
    (``R_incl,k`` the rotation after step k, ``J_r`` the right Jacobian of SO(3), Sola et al. 2018,
    eq. 143; to first order ``J_r = I - [phi]x / 2``). The rotation itself is the RK4 product of
    ``integrate_segments_numpy``; the derivative treats each step as a rotation about its mean rate,
    which is accurate to O(|phi|^2) (1e-4 at 100 Hz and 1 rad/s), ample for a Gauss-Newton step and
    a covariance. The prefix products come from a scan inside each block and one over the blocks.
    """
    w = np.asarray(w, dtype=np.float64)
    t_s = np.asarray(t_s, dtype=np.float64)
    segs = np.asarray(segs, dtype=np.int64).reshape(-1, 2)
    M = np.asarray(M, dtype=np.float64).reshape(3, 3)
    o = np.zeros(3) if offset is None else np.asarray(offset, dtype=np.float64).reshape(3)
    S = segs.shape[0]
    lay = _layout(t_s, segs)
    total = lay.h.size
    nb = lay.block_seg.size
    v0 = np.ascontiguousarray(w[lay.i0].T) - o[:, None]
    v1 = np.ascontiguousarray(w[lay.i1].T) - o[:, None]
    inblock = np.empty((4, total))  # prefix products inside each block
    for c0 in range(0, total, _CHUNK):
        c1 = min(c0 + _CHUNK, total)
        q = _step_quats(M @ v0[:, c0:c1], M @ v1[:, c0:c1], lay.h[c0:c1])
        m = (c1 - c0) // _BLOCK
        qs = _scan((q[0].reshape(m, _BLOCK), q[1].reshape(m, _BLOCK), q[2].reshape(m, _BLOCK),
                    q[3].reshape(m, _BLOCK)), _BLOCK)  # fmt: skip
        for j in range(4):
            inblock[j, c0:c1] = qs[j].ravel()
    # each block's exclusive prefix within its segment
    grid = np.zeros((4, S, lay.n_grid))
    grid[0] = 1.0
    grid[:, lay.block_seg, lay.block_pos] = inblock[:, _BLOCK - 1 :: _BLOCK]
    incl = _scan((grid[0], grid[1], grid[2], grid[3]), lay.n_grid)
    excl = np.zeros((4, S, lay.n_grid))
    excl[0, :, 0] = 1.0
    excl[:, :, 1:] = np.stack(incl)[:, :, :-1]
    front = excl[:, lay.block_seg, lay.block_pos]  # (4, nb)
    ends = np.empty((4, S))
    sums_z = np.empty((nb, 9, 3))  # per block: sum_k h_k C_k[i, a] v_k[b]
    sums_y = np.empty((nb, 9))  # per block: sum_k h_k C_k[i, a]
    for c0 in range(0, total, _CHUNK):
        c1 = min(c0 + _CHUNK, total)
        b0, b1 = c0 // _BLOCK, c1 // _BLOCK
        m = b1 - b0
        fq = tuple(np.repeat(front[j, b0:b1], _BLOCK) for j in range(4))
        pref = _qmul(fq, tuple(inblock[j, c0:c1] for j in range(4)))  # type: ignore[arg-type]
        r = quat_to_matrix(np.stack(pref, axis=-1)).reshape(-1, 9).T  # rows r00, r01, ..., r22
        h = lay.h[c0:c1]
        vm0, vm1 = 0.5 * (v0[:, c0:c1] + v1[:, c0:c1]), None
        phi = (M @ vm0) * h  # (3, n)
        del vm1
        # C = R (I - [phi]x / 2), columns: C[:, 0] = R0 - (R1 phi_z - R2 phi_y) / 2, ...
        px, py, pz = 0.5 * phi[0], 0.5 * phi[1], 0.5 * phi[2]
        C = np.empty((9, c1 - c0))
        for i in range(3):
            r0, r1, r2 = r[3 * i], r[3 * i + 1], r[3 * i + 2]
            C[3 * i] = (r0 - (r1 * pz - r2 * py)) * h
            C[3 * i + 1] = (r1 - (r2 * px - r0 * pz)) * h
            C[3 * i + 2] = (r2 - (r0 * py - r1 * px)) * h
        Cb = C.reshape(9, m, _BLOCK)
        sums_z[b0:b1] = np.einsum("imk,bmk->mib", Cb, vm0.reshape(3, m, _BLOCK))
        sums_y[b0:b1] = Cb.sum(axis=2).T
    for j in range(4):
        ends[j] = _qmul(
            tuple(front[jj, lay.last // _BLOCK] for jj in range(4)),  # type: ignore[arg-type]
            tuple(inblock[jj, lay.last] for jj in range(4)),  # type: ignore[arg-type]
        )[j]
    R = quat_to_matrix(ends.T)
    block_first = np.flatnonzero(lay.block_pos == 0)
    Zs = np.add.reduceat(sums_z, block_first, axis=0).reshape(S, 3, 3, 3)  # [i, a, b]
    Ys = np.add.reduceat(sums_y, block_first, axis=0).reshape(S, 3, 3)
    RT = np.swapaxes(R, 1, 2)
    Z = np.einsum("sij,sjab->siab", RT, Zs)
    Y = np.einsum("sij,sja->sia", RT, Ys)
    return R, Z, Y


def integrate_segments(
    w: FloatArray,
    t_s: FloatArray,
    segs: IntArray,
    Ms: FloatArray,
    offsets: FloatArray | None = None,
    Gs: FloatArray | None = None,
    f: FloatArray | None = None,
) -> FloatArray:
    """Rotations R_start_end (P, S, 3, 3) of the rates ``Ms[p] @ (w - offsets[p]) - Gs[p] @ f`` over the
    segments (S, 2) of samples; ``offsets`` (P, 3) default to zero, ``Gs`` (P, 3, 3) with the specific
    force ``f`` (N, 3) to none (the g-sensitivity term). Compiled (numba)."""
    from imuslam.imu.rk4_compiled import rk4_segments

    P = Ms.shape[0]
    offs = np.zeros((P, 3)) if offsets is None else offsets
    if Gs is None or f is None:
        Gs, f = np.zeros((P, 3, 3)), np.zeros_like(np.asarray(w, dtype=np.float64))
    return np.asarray(
        rk4_segments(
            np.ascontiguousarray(w, dtype=np.float64),
            np.ascontiguousarray(t_s, dtype=np.float64),
            np.ascontiguousarray(segs, dtype=np.int64),
            np.ascontiguousarray(Ms, dtype=np.float64),
            np.ascontiguousarray(offs, dtype=np.float64).reshape(P, 3),
            np.ascontiguousarray(Gs, dtype=np.float64).reshape(P, 3, 3),
            np.ascontiguousarray(f, dtype=np.float64),
        )
    )
