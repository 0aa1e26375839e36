"""Noise floor of the held-out gravity-norm score on the real logs: is the held-out figure at the floor
that the score's own noise and the refit's parameter noise set, or above it (model error)?

Per static pose of the score (``imu/score.py``'s detector) and the default calibration:
- the standard error of the pose's calibrated gravity norm, from its own samples: the sample variance of
  the calibrated norm times the integrated autocorrelation time over n (Sokal 1997, "Monte Carlo methods
  in statistical mechanics", sec. 3: tau = 1 + 2 sum rho_k, window M the smallest with M >= 5 tau(M)),
  next to the white-noise figure sigma_still / sqrt(n) the fit weighs with;
- the parameter noise of the prediction: j_i^T C_f j_i, with j_i the gradient of the pose's norm over the
  9 accelerometer parameters and C_f the covariance reported by the fold's refit that held the pose out;
- the leverage h_ii of the pose in a fit of the 9 parameters to the poses' norms weighted by 1 / se_i^2
  (the hat matrix's diagonal; the joint fit adds the rotations, so its leverages are lower) and the leave-one-out inflation 1 / (1 - h_ii) of the
  residual's variance (a held-out residual of a linear fit has variance se_i^2 / (1 - h_ii) where the
  in-sample one has se_i^2 (1 - h_ii); Cook & Weisberg 1982, sec. 2.2).
If the model holds, E[held-out norm error^2] = se_i^2 + j_i^T C_f j_i: the floor (C_f is the reported
covariance, widened where the fit's misfit exceeds the measured noise, so it holds the model error too).
Then a model-free bound: the poses repeated in the same direction (within 3 deg). A calibration without a
time term predicts the same norm error for all of them, so its held-out error on them cannot be below
that of the mean of the same cluster's poses the fold kept ("5-fold cluster-mean predictor"). The bench prints the
RMS of each part, the measured held-out RMS and their ratio, and imu_tk's in-sample figure beside.

Run: OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python bench/calibrate_floor.py  (about 1 minute of CPU)
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from rich.console import Console
from rich.markup import escape
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parent))

from calibrate_cv import IMUTK, LOGS  # noqa: E402
from imuslam.imu.calibrate import CalibrationConfig, calibrate  # noqa: E402
from imuslam.imu.crossval import cross_validate  # noqa: E402
from imuslam.imu.model import ImuCalibration, misalignment_angles, misalignment_matrix  # noqa: E402
from imuslam.imu.score import detect_poses, pose_errors, rms  # noqa: E402
from imuslam.io.load import load_imu  # noqa: E402
from imuslam.threads import configure_process  # noqa: E402

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
FloatArray = NDArray[np.float64]


def iat(x: FloatArray, c: float = 5.0) -> float:
    """Integrated autocorrelation time of the series x (Sokal 1997, automatic window)."""
    x = x - x.mean()
    n = len(x)
    f = np.fft.rfft(x, 2 * n)
    acf = np.fft.irfft(f * np.conj(f))[:n]
    acf /= acf[0]
    taus = 2.0 * np.cumsum(acf) - 1.0
    m = np.arange(n)
    ok = m >= c * taus
    return float(taus[np.argmax(ok)] if np.any(ok) else taus[-1])


def theta_of(cal: ImuCalibration) -> tuple[FloatArray, float]:
    a = cal.accel
    th = np.concatenate([misalignment_angles(a.T)[:3], a.K, a.b])
    return th, 1.0 if a.bias_sign == "plus" else -1.0


def norm_of(th: FloatArray, sign: float, m: FloatArray) -> FloatArray:
    T = misalignment_matrix(th[0], th[1], th[2])
    return np.asarray(np.linalg.norm(((m + sign * th[6:9]) * th[3:6]) @ T.T, axis=1))


def gradients(cal: ImuCalibration, means: FloatArray) -> FloatArray:
    """(K, 9) gradient of each pose's calibrated norm over the accelerometer parameters."""
    th, sign = theta_of(cal)
    assert cal.cov_accel is not None
    h = np.maximum(np.sqrt(np.clip(np.diag(cal.cov_accel), 0, None)), 1e-9) * 1e-2
    base = norm_of(th, sign, means)
    return np.stack(
        [(norm_of(th + h[j] * np.eye(9)[j], sign, means) - base) / h[j] for j in range(9)], axis=1
    )


def clusters(u: FloatArray, max_deg: float = 3.0) -> NDArray[np.int64]:
    """(K,) cluster label of each pose: poses whose gravity directions lie within max_deg of the
    cluster's first pose (greedy, in pose order)."""
    lab = np.full(len(u), -1, dtype=np.int64)
    cos = np.cos(np.radians(max_deg))
    for i in range(len(u)):
        if lab[i] < 0:
            lab[(lab < 0) & (u @ u[i] > cos)] = i
    return lab


def repeat_bound(err: FloatArray, lab: NDArray[np.int64]) -> tuple[float, float, int]:
    """Spread of the norm error over repeated poses (same direction within 3 deg, 2 or more poses).

    A calibration without a time term predicts (nearly) the same norm error for poses of the same
    direction, so on those poses its RMS cannot be below the within-cluster RMS about each cluster's
    mean, in-sample; and a held-out pose, predicted at best by the mean of its cluster's other poses,
    has the leave-one-out error n / (n - 1) (e_i - mean). Returns (in-sample bound, leave-one-out
    RMS of the cluster-mean predictor, number of poses in such clusters).
    """
    ss, loo, n_all = 0.0, 0.0, 0
    for c in np.unique(lab):
        e = err[lab == c]
        if len(e) < 2:
            continue
        d = e - e.mean()
        ss += float(d @ d)
        loo += float(d @ d) * (len(e) / (len(e) - 1)) ** 2
        n_all += len(e)
    return float(np.sqrt(ss / n_all)), float(np.sqrt(loo / n_all)), n_all


def fold_cluster_mean(
    err: FloatArray, lab: NDArray[np.int64], fold: NDArray[np.int64]
) -> FloatArray:
    """(K,) error of predicting each pose's norm error by the mean over the poses of its cluster that
    its fold kept (NaN where the fold kept none): the cross-validated counterpart of the bound."""
    out = np.full(len(err), np.nan)
    for i in range(len(err)):
        keep = (lab == lab[i]) & (fold != fold[i])
        if np.any(keep):
            out[i] = err[i] - err[keep].mean()
    return out


TERMS = {
    "none (imu_tk's model)": lambda x, e: x,
    "per-axis quadratic x + e x^2 / g": lambda x, e: x + e * x**2 / 9.81,
    "scale asymmetry +g / -g: x + e |x|": lambda x, e: x + e * np.abs(x),
    "per-axis cubic x + e x^3 / g^2": lambda x, e: x + e * x**3 / 9.81**2,
}


def term_cv(
    cal: ImuCalibration, raw: FloatArray, g: float, fold: NDArray[np.int64]
) -> list[tuple[str, float, float, FloatArray, float]]:
    """Norm-only fits of imu_tk's accelerometer model with each extra per-axis term (3 parameters,
    applied to the scaled, bias-corrected reading before the misalignment; MEMS datasheets give the
    nonlinearity and the +-g scale asymmetry), on the score's poses: in-sample and 5-fold CV RMS."""
    from scipy.optimize import least_squares

    th0, sign = theta_of(cal)
    sc = np.concatenate(
        [np.full(3, 1e-3), np.abs(th0[3:6]), 1e-2 / np.abs(th0[3:6]), np.full(3, 1e-3)]
    )
    out = []
    for label, term in TERMS.items():
        n = 9 if label.startswith("none") else 12
        x0 = np.concatenate([th0, np.zeros(3)])[:n]

        def norms(th: FloatArray, m: FloatArray, term=term, n=n) -> FloatArray:  # type: ignore[no-untyped-def]
            T = misalignment_matrix(th[0], th[1], th[2])
            x = term((m + sign * th[6:9]) * th[3:6], th[9:12] if n > 9 else 0.0)
            return np.asarray(np.linalg.norm(x @ T.T, axis=1))

        def fit(idx: NDArray[np.int64], x0=x0, n=n, norms=norms) -> FloatArray:  # type: ignore[no-untyped-def]
            r = least_squares(
                lambda z: norms(x0 + z * sc[:n], raw[idx]) - g, np.zeros(n), method="lm"
            )
            return np.asarray(x0 + r.x * sc[:n])

        th = fit(np.arange(len(raw)))
        cv = np.zeros(len(raw))
        for f in np.unique(fold):
            cv[fold == f] = norms(fit(np.flatnonzero(fold != f)), raw[fold == f]) - g
        # response of the calibrated norm to a change of the specific force along gravity, relative to
        # a linear model's (1): a term that flattens the response at 1 g can fit any drift away
        b = -sign * th[6:9]
        gain = (norms(th, b + (raw - b) * (1 + 1e-4)) / norms(th, raw) - 1) / 1e-4
        out.append((label, rms(norms(th, raw) - g), rms(cv), th[9:], float(np.median(gain))))
    return out


def main() -> None:
    table = Table(
        title="Noise floor of the held-out gravity-norm score (default method, 5-fold CV)"
    )
    cols = ("poses", "tau (median)", "score SE white [m/s^2]", "score SE autocorr [m/s^2]",
            "parameter noise held out (reported covariance, widened by the misfit) [m/s^2]",
            "floor held out with it [m/s^2]", "LOO floor 1/(1-h) [m/s^2]",
            "leverage h (mean)", "measured held out [m/s^2]", "measured / floor",
            "in-sample floor [m/s^2]", "measured in-sample [m/s^2]", "imu_tk in-sample [m/s^2]",
            "repeated poses", "repeat spread in-sample bound [m/s^2]",
            "repeat spread held-out (LOO cluster mean) [m/s^2]", "same, imu_tk's norms [m/s^2]",
            "measured held out on the repeated poses [m/s^2]",
            "5-fold cluster-mean predictor [m/s^2]", "measured held out, same poses [m/s^2]",
            "measured held out per fold [m/s^2]",
            "Wald statistics of the nuisance terms (G and drift 12 dof / G 9 / drift 3)", "CPU [s]", "wall [s]")  # fmt: skip
    vals: dict[str, list[str]] = {}
    terms = Table(
        title="Extra accelerometer terms, norm-only fit on the score's poses (same 5 folds)"
    )
    for c in (
        "log",
        "model",
        "in-sample norm RMS [m/s^2]",
        "5-fold CV norm RMS [m/s^2]",
        "fitted e",
        "response at 1 g (1 = linear)",
    ):
        terms.add_column(
            escape(c), justify="left" if c in ("log", "model", "fitted e") else "right"
        )
    repeats = Table(
        title="Norm error of the repeated poses in time (default calibration, in-sample), mm/s^2"
    )
    for c in ("log", "nearest axis", "poses", "time (s): error"):
        repeats.add_column(c)
    for name, (fa, fg) in LOGS.items():
        t0, c0 = time.perf_counter(), time.process_time()
        log = load_imu(DATA / fa, DATA / fg)
        g = IMUTK[name].g
        cfg = CalibrationConfig(g=g, bias_sign="minus")
        res = calibrate(log, cfg)
        cal = res.calibration
        poses = detect_poses(log)
        cv = cross_validate(log, cfg, res.intervals)
        raw = np.stack([log.accel[s:e].mean(axis=0) for s, e in poses])
        n_init = int(np.searchsorted(log.t_s, cfg.t_init_s, side="right"))
        sig_still = np.std(np.linalg.norm(cal.correct_accel(log.accel[:n_init]), axis=1), ddof=1)
        se_w, se_a, taus = [], [], []
        for s, e in poses:
            x = np.linalg.norm(cal.correct_accel(log.accel[s:e]), axis=1)
            tau = max(iat(x), 1.0)
            taus.append(tau)
            se_w.append(sig_still / np.sqrt(e - s))
            se_a.append(np.std(x, ddof=1) * np.sqrt(tau / (e - s)))
        se = np.asarray(se_a)
        par = np.zeros(len(poses))
        for f, fc in enumerate(cv.fold_calibrations):
            held = cv.fold == f
            j = gradients(fc, raw[held])
            par[held] = np.einsum("ki,ij,kj->k", j, np.asarray(fc.cov_accel), j)
        # leverage of each pose in a fit of the 9 accelerometer parameters to the poses' norms weighted by
        # 1 / se^2 (the norm-only fit; the joint fit adds the rotations' information, so its leverages
        # are lower): h = diag(J (J^T W J)^-1 J^T W)
        j_all = gradients(cal, raw) / se[:, None]
        lev = np.einsum("ki,ij,kj->k", j_all, np.linalg.inv(j_all.T @ j_all), j_all)
        floor = np.sqrt(np.mean(se**2 + par))
        pe = pose_errors(log, cal, poses, g)
        fit = rms(pe.norm_error)
        pe_ref = pose_errors(log, IMUTK[name], poses, g)
        ref = rms(pe_ref.norm_error)
        h = cal.correct_accel(raw)
        lab = clusters(h / np.linalg.norm(h, axis=1, keepdims=True))
        b_in, b_loo, n_rep = repeat_bound(pe.norm_error, lab)
        _, b_loo_ref, _ = repeat_bound(pe_ref.norm_error, lab)
        fcm = fold_cluster_mean(pe.norm_error, lab, cv.fold)
        ok = np.isfinite(fcm)
        rep = np.isin(lab, [c for c in np.unique(lab) if np.sum(lab == c) >= 2])
        t_pose = log.t_s[(poses[:, 0] + poses[:, 1]) // 2]
        for c in np.unique(lab):
            members = np.flatnonzero(lab == c)
            if len(members) >= 2:
                axis = int(np.argmax(np.abs(h[c])))
                d = f"{'+' if h[c, axis] > 0 else '-'}{'xyz'[axis]}"
                repeats.add_row(
                    name,
                    d,
                    f"{len(members)}",
                    "  ".join(f"{t_pose[i]:.0f}: {1e3 * pe.norm_error[i]:+.1f}" for i in members),
                )
        for label, ins, cvr, e, gain in term_cv(cal, raw, g, cv.fold):
            terms.add_row(
                name,
                label,
                f"{ins:.5f}",
                f"{cvr:.5f}",
                np.array2string(e, precision=5),
                f"{gain:.3f}",
            )
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        vals[name] = [
            f"{len(poses)}", f"{np.median(taus):.1f}", f"{rms(np.asarray(se_w)):.5f}",
            f"{rms(se):.5f}", f"{np.sqrt(np.mean(par)):.5f}", f"{floor:.5f}",
            f"{np.sqrt(np.mean(se**2 / (1 - lev))):.5f}", f"{np.mean(lev):.3f}", f"{cv.norm_rms:.5f}",
            f"{cv.norm_rms / floor:.2f}", f"{np.sqrt(np.mean(se**2 * (1 - lev))):.5f}", f"{fit:.5f}",
            f"{ref:.5f}", f"{n_rep}", f"{b_in:.5f}", f"{b_loo:.5f}", f"{b_loo_ref:.5f}",
            f"{rms(cv.norm_error[rep]):.5f}", f"{rms(fcm[ok]):.5f}",
            f"{rms(cv.norm_error[ok]):.5f}",
            " ".join(f"{rms(cv.norm_error[cv.fold == f]):.4f}" for f in range(cv.k_folds)),
            " / ".join(f"{v:.1f}" for v in cal.notes.get("wald_statistics", {}).values()), f"{dc:.0f}", f"{dt:.0f}",
        ]  # fmt: skip
    table.add_column("quantity")
    for name in vals:
        table.add_column(name, justify="right")
    for k, c in enumerate(cols):
        table.add_row(escape(c), *(vals[name][k] for name in vals))
    Console(width=200).print(table)
    Console(width=200).print(terms)
    Console(width=200).print(repeats)


if __name__ == "__main__":
    configure_process()  # the command line's thread defaults, before numba's first parallel kernel
    main()
