"""The joint default against ``--method tedaldi`` on seeded simulated 40-pose logs (seed 000's errors,
BWT901CL-class noise; the logs of ``tests/imu/test_calibrate_sim.py``), with how sure each figure is.

Per method and triad: the mean NEES (9 parameters; 99.7 % band of the mean over R runs 9 +- 3 sqrt(18 / R))
and the mean squared error against the truth, as the ratio joint / tedaldi (mean over the 9 parameters
of the ratio of mean squared errors, the test's figure). A few plans turn little about some axis and
their gyro errors are 20x the median, so that ratio is decided by two or three runs: the table gives its
95 % interval by a bootstrap over the runs (2000 resamples, paired: both methods on the same resampled
runs) and the ratio the methods' own covariances predict (mean reported variance, same formula), which
holds when the NEES does and is far less noisy.
Run: OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python bench/calibrate_montecarlo.py --runs 100
(about 1 s of CPU per run; --start moves the first seed)

One plan, many noise draws: ``--plan-seed 16 --runs 60`` keeps the pose plan of seed 16's log and draws
the sensor noise anew for each run (generators seeded 1000, 1001, ...), so the ratio is that plan's
expected one rather than one draw's; the last table gives, per gyro parameter, each method's mean error
over the runs divided by its standard error (|t| > 3: a bias of the estimator on that plan).
``--variants "no G, no drift" "no drift" "no G"`` adds joint-fit variants without the nuisance terms beside
the default; the "G kept" and "drift kept" columns count the runs whose final calibration keeps the gyro
g-sensitivity and the accelerometer bias drift (with the first seeds that do).
The last table asks whether the runs that decide the gyro ratio are draws or faults: Hausman's statistic
of each run's gyro difference joint - tedaldi against ``P_tedaldi - P_joint``.
``--gyro-ends first_quiet`` runs the joint fit with the gyro segment ends it had before (see
``CalibrationConfig.gyro_ends``).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from rich.console import Console
from rich.table import Table

from imuslam.imu.calibrate import CalibrationConfig, calibrate
from imuslam.imu.model import GYRO_PARAM_NAMES, ImuCalibration, TriadModel
from imuslam.sim.imu_errors import SEED000_ACCEL, SEED000_GYRO
from imuslam.sim.multipose import simulate_multipose, sphere_plan_deg
from imuslam.threads import configure_process

TRUTH = ImuCalibration(
    TriadModel(SEED000_ACCEL.T, SEED000_ACCEL.K, SEED000_ACCEL.b),
    TriadModel(SEED000_GYRO.T, SEED000_GYRO.K, SEED000_GYRO.b),
)
METHODS = ("tedaldi", "joint")
# joint-fit variants that ``--variants`` adds beside the default (each a CalibrationConfig update)
VARIANTS: dict[str, dict[str, object]] = {
    # without G the gyro bias is still estimated from the static poses' rates (estimate_gyro_bias)
    "no G, no drift": {
        "gyro_g_sensitivity": False,
        "estimate_gyro_bias": True,
        "accel_bias_drift": False,
    },
    "no drift": {"accel_bias_drift": False},
    "no G": {"gyro_g_sensitivity": False, "estimate_gyro_bias": True},
}


def mse_ratio(err_j: np.ndarray, err_t: np.ndarray) -> float:
    """Mean over parameters of the ratio of mean squared errors; err_*: (R, 9)."""
    return float(np.mean(np.mean(err_j**2, axis=0) / np.mean(err_t**2, axis=0)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--start", type=int, default=0, help="first seed")
    ap.add_argument("--plan-seed", type=int, default=None, help="one plan, noise drawn per run")
    ap.add_argument("--gyro-ends", choices=("rest", "first_quiet"), default="rest")
    ap.add_argument(
        "--variants", nargs="*", default=[], choices=list(VARIANTS), help="joint variants beside"
    )
    args = ap.parse_args()
    methods = (*METHODS, *args.variants)
    t0, c0 = time.perf_counter(), time.process_time()
    err = {(m, t): [] for m in methods for t in "ag"}  # type: dict[tuple[str, str], list[np.ndarray]]
    var = {(m, t): [] for m in methods for t in "ag"}  # type: dict[tuple[str, str], list[np.ndarray]]
    nees = {(m, t): [] for m in methods for t in "ag"}  # type: dict[tuple[str, str], list[float]]
    cov_g = {m: [] for m in methods}  # type: dict[str, list[np.ndarray]]
    kept = {m: {"G": [], "drift": []} for m in methods}  # type: dict[str, dict[str, list[int]]]
    for seed in range(args.start, args.start + args.runs):
        if args.plan_seed is None:
            rng = np.random.default_rng(seed)
            sim = simulate_multipose(sphere_plan_deg(40, rng), rng)
        else:
            plan = sphere_plan_deg(40, np.random.default_rng(args.plan_seed))
            sim = simulate_multipose(plan, np.random.default_rng(1000 + seed - args.start))
        for m in methods:
            if m in METHODS:
                cfg = CalibrationConfig(g=sim.truth.g, method=m, gyro_ends=args.gyro_ends)
            else:
                cfg = CalibrationConfig(g=sim.truth.g, gyro_ends=args.gyro_ends, **VARIANTS[m])  # type: ignore[arg-type]
            c = calibrate(sim.log, cfg).calibration
            if c.gyro_g_sensitivity is not None:
                kept[m]["G"].append(seed)
            if "accel_bias_drift_per_s" in c.notes:
                kept[m]["drift"].append(seed)
            assert c.cov_accel is not None and c.cov_gyro is not None
            cov_g[m].append(c.cov_gyro)
            for t, e, P in (
                ("a", c.accel_params - TRUTH.accel_params, c.cov_accel),
                ("g", c.gyro_params - TRUTH.gyro_params, c.cov_gyro),
            ):
                err[m, t].append(e)
                var[m, t].append(np.diag(P))
                nees[m, t].append(float(e @ np.linalg.solve(P, e)))
    R = args.runs
    band = 3 * np.sqrt(18 / R)
    rng = np.random.default_rng(0)
    what = (
        f"seeds {args.start}-{args.start + R - 1}"
        if args.plan_seed is None
        else f"plan of seed {args.plan_seed}, noise seeds 1000-{1000 + R - 1}"
    )
    table = Table(title=f"joint (gyro ends: {args.gyro_ends}) vs tedaldi, {what} ({R} runs)")
    for col in ("method", "triad", "NEES tedaldi", "NEES joint", f"band 9 +- {band:.2f}",
                "MSE ratio joint / tedaldi", "95 % bootstrap interval", "predicted by the covariances",
                "ratio without the 2 worst runs", "G kept", "drift kept"):  # fmt: skip
        table.add_column(col, justify="right")
    for m in methods[1:]:
        for t, name in (("a", "accelerometer"), ("g", "gyroscope")):
            ej, et = np.asarray(err[m, t]), np.asarray(err["tedaldi", t])
            boots = []
            for _ in range(2000):
                i = rng.integers(0, R, R)
                boots.append(mse_ratio(ej[i], et[i]))
            lo, hi = np.percentile(boots, [2.5, 97.5])
            pred = mse_ratio(np.sqrt(np.asarray(var[m, t])), np.sqrt(np.asarray(var["tedaldi", t])))
            worst = np.argsort(-(np.sum(ej**2, axis=1) + np.sum(et**2, axis=1)))[:2]
            keep = np.setdiff1d(np.arange(R), worst)
            ok_t = abs(np.mean(nees["tedaldi", t]) - 9) < band
            ok_j = abs(np.mean(nees[m, t]) - 9) < band
            seeds = ", ".join(str(args.start + w) for w in worst)
            table.add_row(
                m,
                name,
                f"{np.mean(nees['tedaldi', t]):.2f}",
                f"{np.mean(nees[m, t]):.2f}",
                f"{'in' if ok_t else 'OUT'} / {'in' if ok_j else 'OUT'}",
                f"{mse_ratio(ej, et):.3f}",
                f"[{lo:.2f}, {hi:.2f}]",
                f"{pred:.3f}",
                f"{mse_ratio(ej[keep], et[keep]):.3f} (seeds {seeds})",
                f"{len(kept[m]['G'])} {kept[m]['G'][:8]}" if t == "a" else "",
                f"{len(kept[m]['drift'])} {kept[m]['drift'][:8]}" if t == "a" else "",
            )
    Console(width=260).print(table)
    bias = Table(title="gyro: mean error over the runs / its standard error (t)")
    bias.add_column("method")
    for name in GYRO_PARAM_NAMES:
        bias.add_column(name, justify="right")
    for m in methods:
        e = np.asarray(err[m, "g"])
        t = e.mean(axis=0) / (e.std(axis=0, ddof=1) / np.sqrt(R))
        bias.add_row(m, *(f"{v:+.1f}" for v in t))
    Console(width=200).print(bias)
    hausman_table(methods, err, nees, cov_g, args.start if args.plan_seed is None else 1000)
    print(f"CPU {time.process_time() - c0:.0f} s, wall {time.perf_counter() - t0:.0f} s")


def hausman(d: np.ndarray, P_t: np.ndarray, P_j: np.ndarray) -> tuple[float, int]:
    """Hausman's statistic d^T (P_t - P_j)^+ d and its degrees of freedom (Hausman 1978, Econometrica 46).

    If both estimators are consistent and the joint one is efficient, the covariance of their difference
    d = joint - tedaldi is P_t - P_j; the statistic is then chi-square with its rank. Directions in which
    the joint fit is not the more precise (non-positive eigenvalues) are left out.
    """
    w, U = np.linalg.eigh(P_t - P_j)
    keep = w > 1e-9 * max(float(w.max()), 1e-300)
    z = U[:, keep].T @ d
    return float(np.sum(z**2 / w[keep])), int(keep.sum())


def hausman_table(
    methods: tuple[str, ...],
    err: dict[tuple[str, str], list[np.ndarray]],
    nees: dict[tuple[str, str], list[float]],
    cov_g: dict[str, list[np.ndarray]],
    first: int,
) -> None:
    """Is the gap between the methods on the runs that decide the ratio a draw or a fault?

    Per joint variant: Hausman's statistic of the gyro difference joint - tedaldi on every run (its mean
    over the runs against the mean of its degrees of freedom, and how many runs exceed the 99 % point),
    and on the two runs that contribute most to the gyro mean squared errors, with both methods' NEES.
    Where the two covariances nearly agree, a small error in either inflates the statistic, so a large
    value asks for a look at that run and a typical one says the gap is a draw both covariances cover.
    """
    from scipy.special import chdtri  # chi-square quantile

    table = Table(title="gyro: joint - tedaldi against the covariance of the difference (Hausman)")
    for col in ("method", "mean statistic", "mean dof", "runs above 99 %", "two worst runs: "
                "seed, statistic / dof, NEES joint / tedaldi"):  # fmt: skip
        table.add_column(col, justify="right")
    et = np.asarray(err["tedaldi", "g"])
    for m in methods[1:]:
        ej = np.asarray(err[m, "g"])
        hs = [
            hausman(a - b, Pt, Pj)
            for a, b, Pt, Pj in zip(ej, et, cov_g["tedaldi"], cov_g[m], strict=True)
        ]
        stat = np.array([h[0] for h in hs])
        dof = np.array([h[1] for h in hs])
        above = int(sum(s > chdtri(k, 0.01) for s, k in zip(stat, dof, strict=True) if k > 0))
        # each run's share of the joint's mean squared error, summed over the parameters
        share = np.sum(ej**2 / np.sum(ej**2, axis=0), axis=1)
        worst = np.argsort(-share)[:2]
        table.add_row(
            m,
            f"{stat.mean():.2f}",
            f"{dof.mean():.2f}",
            f"{above} of {len(stat)}",
            "; ".join(
                f"{first + i}: {stat[i]:.1f} / {dof[i]}, {nees[m, 'g'][i]:.1f} / "
                f"{nees['tedaldi', 'g'][i]:.1f}"
                for i in worst
            ),
        )
    Console(width=200).print(table)


if __name__ == "__main__":
    configure_process()  # the command line's thread defaults, before numba's first parallel kernel
    main()
