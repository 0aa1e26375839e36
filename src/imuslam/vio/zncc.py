"""Compiled zero-mean normalised cross-correlation (ZNCC) matching: stereo search along rectified rows and
temporal tracking on a two-level pyramid.

ZNCC of patches a, b of n pixels: ``(sum ab - sum a sum b / n) / sqrt(var_a var_b)`` with
``var_a = sum a^2 - (sum a)^2 / n`` (e.g. Szeliski, "Computer Vision", 2nd ed., eq. 9.11); it is
invariant to gain and offset of the intensities. Peaks are refined to sub-pixel by a parabola through
the best score and its two neighbours. Images are float32 (H, W); pixel (u, v) is column u, row v.
Slow pure-numpy references for the tests are :func:`zncc_ref` and :func:`stereo_match_ref`.
"""

from __future__ import annotations

from typing import Any

import numba as nb
import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
F32Array = NDArray[np.float32]


@nb.njit(cache=True, inline="always")
def _bilinear(img: F32Array, u: float, v: float) -> float:  # pragma: no cover - compiled
    u0 = int(np.floor(u))
    v0 = int(np.floor(v))
    a = u - u0
    b = v - v0
    return (
        (1 - a) * (1 - b) * img[v0, u0]
        + a * (1 - b) * img[v0, u0 + 1]
        + (1 - a) * b * img[v0 + 1, u0]
        + a * b * img[v0 + 1, u0 + 1]
    )


@nb.njit(cache=True, inline="always")
def _normalise(out: FloatArray, s: float, k: int) -> bool:  # pragma: no cover - compiled
    """Make the first ``k`` samples of ``out`` (their sum ``s``) zero-mean and unit-norm; False if flat."""
    m = s / k
    ss = 0.0
    for i in range(k):
        out[i] -= m
        ss += out[i] * out[i]
    if ss < 1e-6 * k:
        return False
    nrm = np.sqrt(ss)
    for i in range(k):
        out[i] /= nrm
    return True


@nb.njit(cache=True, inline="always")
def _zncc_sums(
    sa: float, sb: float, saa: float, sbb: float, sab: float, n: int
) -> float:  # pragma: no cover - compiled
    """ZNCC from the sums of two patches of ``n`` samples (-1 if either is flat)."""
    va_ = saa - sa * sa / n
    vb_ = sbb - sb * sb / n
    if va_ < 1e-6 * n or vb_ < 1e-6 * n:
        return -1.0
    return (sab - sa * sb / n) / np.sqrt(va_ * vb_)


@nb.njit(cache=True)
def _template(
    img: F32Array, u: float, v: float, h: int, out: FloatArray
) -> bool:  # pragma: no cover
    """Bilinear patch (2h+1)^2 centred at (u, v), zero mean, unit norm; False if outside or flat."""
    H, W = img.shape
    if u - h < 0 or v - h < 0 or u + h + 1 >= W - 1 or v + h + 1 >= H - 1:
        return False
    s = 0.0
    k = 0
    for dv in range(-h, h + 1):
        for du in range(-h, h + 1):
            x = _bilinear(img, u + du, v + dv)
            out[k] = x
            s += x
            k += 1
    return _normalise(out, s, k)


@nb.njit(cache=True)
def _template_warp(
    img: F32Array, u: float, v: float, h: int, ainv: FloatArray, out: FloatArray
) -> bool:  # pragma: no cover - compiled
    """Like :func:`_template`, sampled at ``(u, v) + ainv @ (du, dv)``: the previous image's patch in the
    geometry of the current one (``ainv`` the inverse of the local affine map from previous to current
    pixels)."""
    H, W = img.shape
    eu = h * (abs(ainv[0, 0]) + abs(ainv[0, 1]))
    ev = h * (abs(ainv[1, 0]) + abs(ainv[1, 1]))
    if u - eu < 0 or v - ev < 0 or u + eu + 1 >= W - 1 or v + ev + 1 >= H - 1:
        return False
    s = 0.0
    k = 0
    for dv in range(-h, h + 1):
        for du in range(-h, h + 1):
            x = _bilinear(
                img, u + ainv[0, 0] * du + ainv[0, 1] * dv, v + ainv[1, 0] * du + ainv[1, 1] * dv
            )
            out[k] = x
            s += x
            k += 1
    return _normalise(out, s, k)


@nb.njit(cache=True, fastmath=True)
def _score(img: F32Array, U: int, V: int, h: int, tpl: FloatArray) -> float:  # pragma: no cover
    """ZNCC of a normalised template with the integer-centred patch of ``img`` at (U, V)."""
    n = (2 * h + 1) * (2 * h + 1)
    s = 0.0
    ss = 0.0
    st = 0.0
    k = 0
    for dv in range(-h, h + 1):
        row = V + dv
        for du in range(-h, h + 1):
            x = img[row, U + du]
            s += x
            ss += x * x
            st += x * tpl[k]
            k += 1
    var = ss - s * s / n
    if var < 1e-6 * n:
        return -1.0
    # the template has zero mean, so sum (x - mean) t = sum x t
    return st / np.sqrt(var)


@nb.njit(cache=True, fastmath=True)
def _zncc_pair(
    a: F32Array, ua: float, va: float, b: F32Array, ub: float, vb: float, h: int
) -> float:  # pragma: no cover - compiled
    """ZNCC of the bilinear patches of ``a`` at (ua, va) and ``b`` at (ub, vb)."""
    Ha, Wa = a.shape
    Hb, Wb = b.shape
    if ua - h < 0 or va - h < 0 or ua + h + 1 >= Wa - 1 or va + h + 1 >= Ha - 1:
        return -2.0
    if ub - h < 0 or vb - h < 0 or ub + h + 1 >= Wb - 1 or vb + h + 1 >= Hb - 1:
        return -2.0
    n = (2 * h + 1) * (2 * h + 1)
    sa = 0.0
    sb = 0.0
    saa = 0.0
    sbb = 0.0
    sab = 0.0
    # every pixel of a patch has the same bilinear weights: compute them once per patch
    ia = int(np.floor(ua))
    ja = int(np.floor(va))
    xa = ua - ia
    ya = va - ja
    ib = int(np.floor(ub))
    jb = int(np.floor(vb))
    xb = ub - ib
    yb = vb - jb
    a00, a01, a10, a11 = (1 - xa) * (1 - ya), xa * (1 - ya), (1 - xa) * ya, xa * ya
    b00, b01, b10, b11 = (1 - xb) * (1 - yb), xb * (1 - yb), (1 - xb) * yb, xb * yb
    for dv in range(-h, h + 1):
        ra = ja + dv
        rb = jb + dv
        for du in range(-h, h + 1):
            ca = ia + du
            cb = ib + du
            x = (a00 * a[ra, ca] + a01 * a[ra, ca + 1] + a10 * a[ra + 1, ca]
                 + a11 * a[ra + 1, ca + 1])  # fmt: skip
            y = (b00 * b[rb, cb] + b01 * b[rb, cb + 1] + b10 * b[rb + 1, cb]
                 + b11 * b[rb + 1, cb + 1])  # fmt: skip
            sa += x
            sb += y
            saa += x * x
            sbb += y * y
            sab += x * y
    return _zncc_sums(sa, sb, saa, sbb, sab, n)


@nb.njit(cache=True, fastmath=True)
def _zncc_pair_warp(
    a: F32Array, ua: float, va: float, ainv: FloatArray, b: F32Array, ub: float, vb: float, h: int
) -> float:  # pragma: no cover - compiled
    """ZNCC of ``a`` sampled at ``(ua, va) + ainv @ (du, dv)`` with ``b``'s bilinear patch at (ub, vb)."""
    Ha, Wa = a.shape
    Hb, Wb = b.shape
    eu = h * (abs(ainv[0, 0]) + abs(ainv[0, 1]))
    ev = h * (abs(ainv[1, 0]) + abs(ainv[1, 1]))
    if ua - eu < 0 or va - ev < 0 or ua + eu + 1 >= Wa - 1 or va + ev + 1 >= Ha - 1:
        return -2.0
    if ub - h < 0 or vb - h < 0 or ub + h + 1 >= Wb - 1 or vb + h + 1 >= Hb - 1:
        return -2.0
    n = (2 * h + 1) * (2 * h + 1)
    sa = 0.0
    sb = 0.0
    saa = 0.0
    sbb = 0.0
    sab = 0.0
    ib = int(np.floor(ub))
    jb = int(np.floor(vb))
    xb = ub - ib
    yb = vb - jb
    b00, b01, b10, b11 = (1 - xb) * (1 - yb), xb * (1 - yb), (1 - xb) * yb, xb * yb
    for dv in range(-h, h + 1):
        rb = jb + dv
        for du in range(-h, h + 1):
            cb = ib + du
            x = _bilinear(
                a, ua + ainv[0, 0] * du + ainv[0, 1] * dv, va + ainv[1, 0] * du + ainv[1, 1] * dv
            )
            y = (b00 * b[rb, cb] + b01 * b[rb, cb + 1] + b10 * b[rb + 1, cb]
                 + b11 * b[rb + 1, cb + 1])  # fmt: skip
            sa += x
            sb += y
            saa += x * x
            sbb += y * y
            sab += x * y
    return _zncc_sums(sa, sb, saa, sbb, sab, n)


@nb.njit(cache=True)
def _refine_axis_warp(
    a: F32Array,
    ua: float,
    va: float,
    ainv: FloatArray,
    b: F32Array,
    ub: float,
    vb: float,
    h: int,
    axis: int,
) -> tuple[float, float]:  # pragma: no cover - compiled
    """:func:`_refine_axis` with ``a`` warped by ``ainv``: an offset o in ``b`` is o/2 there and
    ``ainv @ (-o/2)`` in ``a``, so the two patches still move symmetrically about the match."""
    best = -3.0
    bj = 0
    sc = np.empty(11)
    for j in range(11):
        o = -0.5 + 0.1 * j
        if axis == 0:
            sc[j] = _zncc_pair_warp(a, ua - 0.5 * o * ainv[0, 0], va - 0.5 * o * ainv[1, 0], ainv,
                                    b, ub + 0.5 * o, vb, h)  # fmt: skip
        else:
            sc[j] = _zncc_pair_warp(a, ua - 0.5 * o * ainv[0, 1], va - 0.5 * o * ainv[1, 1], ainv,
                                    b, ub, vb + 0.5 * o, h)  # fmt: skip
        if sc[j] > best:
            best = sc[j]
            bj = j
    off = -0.5 + 0.1 * bj
    if 0 < bj < 10 and sc[bj - 1] > -2 and sc[bj + 1] > -2:
        off += 0.1 * _parabola(sc[bj - 1], best, sc[bj + 1])
    return (ub if axis == 0 else vb) + off, best


@nb.njit(cache=True)
def _refine_axis(
    a: F32Array, ua: float, va: float, b: F32Array, ub: float, vb: float, h: int, axis: int
) -> tuple[float, float]:  # pragma: no cover - compiled
    """Sub-pixel position in ``b`` of the point (ua, va) of ``a``, along one axis, near (ub, vb).

    Offsets o in 0.1 px steps within +-0.5 px, each evaluated symmetrically: ``a`` sampled at -o/2 and
    ``b`` at +o/2, so both patches are interpolated (and their noise smoothed) alike; then a parabola
    through the best step and its neighbours. A parabola on whole-pixel scores is biased toward whole
    pixels, and interpolating only one patch biases the peak toward half pixels (interpolation averages
    the noise, which raises the ZNCC): both by up to ~0.1-0.2 px, a systematic depth (scale) error.
    Returns the refined coordinate along ``axis`` in ``b`` and its score."""
    best = -3.0
    bj = 0
    sc = np.empty(11)
    for j in range(11):
        o = -0.5 + 0.1 * j
        if axis == 0:
            sc[j] = _zncc_pair(a, ua - 0.5 * o, va, b, ub + 0.5 * o, vb, h)
        else:
            sc[j] = _zncc_pair(a, ua, va - 0.5 * o, b, ub, vb + 0.5 * o, h)
        if sc[j] > best:
            best = sc[j]
            bj = j
    off = -0.5 + 0.1 * bj
    if 0 < bj < 10 and sc[bj - 1] > -2 and sc[bj + 1] > -2:
        off += 0.1 * _parabola(sc[bj - 1], best, sc[bj + 1])
    return (ub if axis == 0 else vb) + off, best


@nb.njit(cache=True)
def _parabola(sm: float, s0: float, sp: float) -> float:  # pragma: no cover - compiled
    den = sm - 2 * s0 + sp
    if den >= 0:
        return 0.0
    off = 0.5 * (sm - sp) / den
    return min(0.5, max(-0.5, off))


@nb.njit(cache=True, parallel=True)
def stereo_match(
    left: F32Array,
    right: F32Array,
    uv: FloatArray,
    h: int,
    d_lo: FloatArray,
    d_hi: FloatArray,
    min_score: float,
    uniqueness: float,
) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - compiled
    """Disparity (N,) of left points ``uv`` (N, 2) along the same row of the rectified right image,
    searched over integer steps from ``d_lo`` to ``d_hi`` (N,) px.

    The right image is sampled at the same sub-pixel row and column fraction as the left point (one
    interpolated strip per point), so that integer disparity steps are exact; window sums slide along
    the strip. The best disparity needs ZNCC >= ``min_score`` and a second peak (more than 2 px away)
    below ``uniqueness`` times the best. Returns disparity (NaN: no match) and score.
    """
    n = uv.shape[0]
    H, W = right.shape
    disp = np.full(n, np.nan)
    best_s = np.full(n, -1.0)
    m = (2 * h + 1) * (2 * h + 1)
    w = 2 * h + 1
    for i in nb.prange(n):
        tpl = np.empty(m)
        u = uv[i, 0]
        v = uv[i, 1]
        if not _template(left, u, v, h, tpl):
            continue
        fu = u - np.floor(u)
        ui = int(np.floor(u))
        d0 = max(int(np.floor(d_lo[i])), 0)
        d1 = int(np.ceil(d_hi[i]))
        d1 = min(d1, ui - h - 1)  # the right patch must stay inside the image
        if d1 < d0:
            continue
        nd = d1 - d0 + 1
        # strip columns c = 0..L-1 hold right-image columns (ui - d1 - h + c) + fu
        L = nd + 2 * h
        c0 = ui - d1 - h
        if c0 + L + 1 >= W:
            continue
        strip = np.empty((w, L))
        cs = np.zeros(L)
        cs2 = np.zeros(L)
        for r in range(w):
            for c in range(L):
                x = _bilinear(right, c0 + c + fu, v - h + r)
                strip[r, c] = x
                cs[c] += x
                cs2[c] += x * x
        scores = np.empty(nd)
        best = -2.0
        bi = -1
        for j in range(nd):  # j indexes disparity d1 - j, i.e. strip columns j .. j + 2h
            s = 0.0
            ss = 0.0
            for c in range(j, j + w):
                s += cs[c]
                ss += cs2[c]
            st = 0.0
            k = 0
            for r in range(w):
                for c in range(j, j + w):
                    st += strip[r, c] * tpl[k]
                    k += 1
            var = ss - s * s / m
            sc = st / np.sqrt(var) if var > 1e-6 * m else -1.0
            scores[j] = sc
            if sc > best:
                best = sc
                bi = j
        if bi < 0 or best < min_score:
            continue
        second = -2.0
        for j in range(nd):
            if abs(j - bi) > 2 and scores[j] > second:
                second = scores[j]
        if second > uniqueness * best:
            continue
        # right column of the best integer step, then a sub-pixel refinement along the row
        ur, sr = _refine_axis(left, u, v, right, u - (d1 - bi), v, h, 0)
        disp[i] = u - ur
        best_s[i] = max(best, sr)
    return disp, best_s


@nb.njit(cache=True, fastmath=True)
def _zncc_slanted(
    left: F32Array, ul: float, v: float, right: F32Array, ur: float, su: float, sv: float, h: int
) -> float:  # pragma: no cover - compiled
    """ZNCC of the left patch at (ul, v) with the right one whose column for the left pixel offset
    (du, dv) is ``ur + du - (su du + sv dv)``: a window slanted with the disparity's slopes."""
    H, W = right.shape
    e = h * (1.0 + abs(su) + abs(sv))
    if ul - h < 0 or v - h < 0 or ul + h + 1 >= W - 1 or v + h + 1 >= H - 1:
        return -2.0
    if ur - e < 0 or ur + e + 1 >= W - 1:
        return -2.0
    n = (2 * h + 1) * (2 * h + 1)
    sa = 0.0
    sb = 0.0
    saa = 0.0
    sbb = 0.0
    sab = 0.0
    for dv in range(-h, h + 1):
        for du in range(-h, h + 1):
            x = _bilinear(left, ul + du, v + dv)
            y = _bilinear(right, ur + du - su * du - sv * dv, v + dv)
            sa += x
            sb += y
            saa += x * x
            sbb += y * y
            sab += x * y
    return _zncc_sums(sa, sb, saa, sbb, sab, n)


@nb.njit(cache=True, parallel=True)
def slanted_disparity(
    left: F32Array, right: F32Array, uv: FloatArray, d: FloatArray, slopes: FloatArray, h: int
) -> FloatArray:  # pragma: no cover - compiled
    """Disparity (N,) at left points ``uv`` refined within +-1 px of ``d`` with the window slanted by the
    disparity's ``slopes`` (N, 2): on a surface not facing the camera (the floor ahead of a ground
    robot) the disparity changes across a straight window, by about 0.2 px per row on the rendered
    floor, and a straight window matches it about 0.3 px off (median, noise-free). Offsets o in 0.1 px
    steps, sampled symmetrically (left at -o/2, right at +o/2, as :func:`_refine_axis`), then a
    parabola. Where the slopes are NaN or shear the window by less than 0.05 px at its edge, ``d`` is
    returned as it is; NaN where no peak is inside."""
    n = uv.shape[0]
    out = np.full(n, np.nan)
    for i in nb.prange(n):
        if not np.isfinite(d[i]):
            continue
        su = slopes[i, 0]
        sv = slopes[i, 1]
        if not (np.isfinite(su) and np.isfinite(sv)) or h * (abs(su) + abs(sv)) < 0.05:
            # a window the slopes shear by less than 0.05 px at its edge: the straight match stands
            out[i] = d[i]
            continue
        u = uv[i, 0]
        v = uv[i, 1]
        sc = np.empty(21)
        best = -3.0
        bj = -1
        for j in range(21):
            o = -1.0 + 0.1 * j
            sc[j] = _zncc_slanted(left, u - 0.5 * o, v, right, u - d[i] + 0.5 * o, su, sv, h)
            if sc[j] > best:
                best = sc[j]
                bj = j
        if bj <= 0 or bj >= 20 or best <= -1.0:
            continue
        off = -1.0 + 0.1 * bj + 0.1 * _parabola(sc[bj - 1], best, sc[bj + 1])
        out[i] = d[i] - off
    return out


@nb.njit(cache=True, parallel=True)
def disparity_slopes(
    left: F32Array, right: F32Array, uv: FloatArray, d: FloatArray, h: int, step: int
) -> FloatArray:  # pragma: no cover - compiled
    """Slopes (N, 2) of the disparity across the image, ``[dd/du, dd/dv]``, at left points ``uv`` of
    disparity ``d``: the disparity ``step`` px to either side along each axis, by ZNCC over whole-pixel
    steps within +-2 px of ``d`` refined by a parabola, differenced. NaN where a side has no clear
    peak."""
    n = uv.shape[0]
    out = np.full((n, 2), np.nan)
    for i in nb.prange(n):
        if not np.isfinite(d[i]):
            continue
        dd = np.empty(4)
        sc = np.empty(5)
        for k in range(4):
            du = step if k == 0 else (-step if k == 1 else 0)
            dv = step if k == 2 else (-step if k == 3 else 0)
            u = uv[i, 0] + du
            v = uv[i, 1] + dv
            best = -3.0
            bj = -1
            for j in range(5):
                sc[j] = _zncc_pair(left, u, v, right, u - d[i] - (j - 2), v, h)
                if sc[j] > best:
                    best = sc[j]
                    bj = j
            if bj <= 0 or bj >= 4 or best < 0.5:
                dd[k] = np.nan
            else:
                dd[k] = d[i] + (bj - 2) + _parabola(sc[bj - 1], best, sc[bj + 1])
        out[i, 0] = (dd[0] - dd[1]) / (2 * step)
        out[i, 1] = (dd[2] - dd[3]) / (2 * step)
    return out


@nb.njit(cache=True)
def _search(
    img: F32Array, tpl: FloatArray, h: int, U: int, V: int, r: int
) -> tuple[float, float, float]:  # pragma: no cover - compiled
    """Best integer ZNCC position within +-r of (U, V), refined by parabolas; (u, v, score)."""
    H, W = img.shape
    best = -2.0
    bu = 0
    bv = 0
    w = 2 * r + 1
    sc = np.full((w, w), -2.0)
    for jv in range(w):
        vv = V - r + jv
        if vv - h < 0 or vv + h >= H:
            continue
        for ju in range(w):
            uu = U - r + ju
            if uu - h < 0 or uu + h >= W:
                continue
            s = _score(img, uu, vv, h, tpl)
            sc[jv, ju] = s
            if s > best:
                best = s
                bu = ju
                bv = jv
    if best <= -2.0:
        return np.nan, np.nan, -2.0
    ou = 0.0
    ov = 0.0
    if 0 < bu < w - 1 and sc[bv, bu - 1] > -2 and sc[bv, bu + 1] > -2:
        ou = _parabola(sc[bv, bu - 1], best, sc[bv, bu + 1])
    if 0 < bv < w - 1 and sc[bv - 1, bu] > -2 and sc[bv + 1, bu] > -2:
        ov = _parabola(sc[bv - 1, bu], best, sc[bv + 1, bu])
    return U - r + bu + ou, V - r + bv + ov, best


def track(
    prev0: F32Array,
    prev1: F32Array,
    cur0: F32Array,
    cur1: F32Array,
    uv: FloatArray,
    pred: FloatArray,
    h0: int,
    h1: int,
    r1: int,
    r0: int,
    min_score: float,
    affine: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Track points ``uv`` (N, 2) of the previous image into the current one by ZNCC.

    Level 1 (half resolution, ``prev1``/``cur1`` from ``cv2.pyrDown``) searches +-``r1`` px around the
    prediction ``pred`` (N, 2); level 0 refines +-``r0`` px around twice the level-1 peak. ``affine``
    (N, 2, 2), optional: the predicted local map from previous to current pixel offsets per point (the
    patch's scale change and shear under the motion); at full resolution the previous patch is sampled
    through its inverse, so it is compared in the current image's geometry. Returns the new positions
    (N, 2) (NaN where lost) and the final scores (N,).
    """
    n = len(uv)
    if affine is None:
        ainv = np.broadcast_to(np.eye(2), (n, 2, 2)).copy()
    else:
        ainv = np.linalg.inv(np.asarray(affine, float).reshape(n, 2, 2))
        bad = ~np.isfinite(ainv).all(axis=(1, 2)) | (np.abs(ainv).max(axis=(1, 2)) > 4.0)
        ainv[bad] = np.eye(2)
    return _track(prev0, prev1, cur0, cur1, np.ascontiguousarray(uv, dtype=float),
                  np.ascontiguousarray(pred, dtype=float), h0, h1, r1, r0, min_score, ainv)  # fmt: skip


@nb.njit(cache=True, parallel=True)
def _track(
    prev0: F32Array,
    prev1: F32Array,
    cur0: F32Array,
    cur1: F32Array,
    uv: FloatArray,
    pred: FloatArray,
    h0: int,
    h1: int,
    r1: int,
    r0: int,
    min_score: float,
    ainv: FloatArray,
) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - compiled
    """:func:`track` with the inverse affine maps ``ainv`` (N, 2, 2) given."""
    n = uv.shape[0]
    out = np.full((n, 2), np.nan)
    score = np.full(n, -2.0)
    for i in nb.prange(n):
        t1 = np.empty((2 * h1 + 1) ** 2)
        t0 = np.empty((2 * h0 + 1) ** 2)
        if not _template(prev1, 0.5 * uv[i, 0], 0.5 * uv[i, 1], h1, t1):
            continue
        ai = ainv[i]
        warp = max(abs(ai[0, 0] - 1), abs(ai[0, 1]), abs(ai[1, 0]), abs(ai[1, 1] - 1)) * h0 > 0.02
        if warp:
            if not _template_warp(prev0, uv[i, 0], uv[i, 1], h0, ai, t0):
                continue
        elif not _template(prev0, uv[i, 0], uv[i, 1], h0, t0):
            continue
        pu = pred[i, 0]
        pv = pred[i, 1]
        if not (np.isfinite(pu) and np.isfinite(pv)):
            continue
        u1, v1, s1 = _search(cur1, t1, h1, int(np.rint(0.5 * pu)), int(np.rint(0.5 * pv)), r1)
        if s1 < min_score - 0.2:
            continue
        u0, v0, s0 = _search(cur0, t0, h0, int(np.rint(2 * u1)), int(np.rint(2 * v1)), r0)
        if s0 < min_score:
            continue
        pu0 = uv[i, 0]
        pv0 = uv[i, 1]
        if warp:
            u0, _ = _refine_axis_warp(prev0, pu0, pv0, ai, cur0, np.rint(u0), np.rint(v0), h0, 0)
            v0, _ = _refine_axis_warp(prev0, pu0, pv0, ai, cur0, u0, np.rint(v0), h0, 1)
            u0, s0 = _refine_axis_warp(prev0, pu0, pv0, ai, cur0, u0, v0, h0, 0)
        else:
            u0, _ = _refine_axis(prev0, pu0, pv0, cur0, np.rint(u0), np.rint(v0), h0, 0)
            v0, _ = _refine_axis(prev0, pu0, pv0, cur0, u0, np.rint(v0), h0, 1)
            u0, s0 = _refine_axis(prev0, pu0, pv0, cur0, u0, v0, h0, 0)
        out[i, 0] = u0
        out[i, 1] = v0
        score[i] = s0
    return out, score


def zncc_ref(a: NDArray[Any], b: NDArray[Any]) -> float:
    """Reference ZNCC of two equal-shape patches (numpy)."""
    a = a.astype(float).ravel() - a.mean()
    b = b.astype(float).ravel() - b.mean()
    return float(a @ b / np.sqrt((a @ a) * (b @ b)))


def stereo_match_ref(
    left: F32Array, right: F32Array, u: int, v: int, h: int, d_min: int, d_max: int
) -> tuple[int, float]:
    """Reference integer-disparity search at integer (u, v): best disparity and score (numpy)."""
    a = left[v - h : v + h + 1, u - h : u + h + 1]
    best, bd = -2.0, -1
    for d in range(d_min, d_max + 1):
        ur = u - d
        if ur - h < 0:
            break
        s = zncc_ref(a, right[v - h : v + h + 1, ur - h : ur + h + 1])
        if s > best:
            best, bd = s, d
    return bd, best
