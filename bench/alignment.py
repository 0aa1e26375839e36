"""Alignment methods compared on simulated BWT901CL-class IMUs (after calibration: biases left).

Scenarios (20 seeded runs each): fixed base (still: zero velocity and zero rate at 10 Hz), moving base (the
figure-eight robot with 2 cm position fixes at 10 Hz), rotating platform (still base, IMU turning at 10 Hz
about z, zero-velocity aiding 50 Hz), and warm-up (the moving base while the IMU warms up: temperature
rising 15 degC with a 20 s time constant, the biases following at 4 mg and 0.011 deg/s per degC in seeded
directions; errors are against the biases at each time). Methods: none, KF, STKF, the RWNN observer and
the same observer without its network (bias weights only: what the network adds). Each run: 60 s of alignment, then 30 s of free inertial navigation
from the aligned state with the estimated biases removed. Printed per method: accelerometer and gyro bias
error after 10 s, 30 s and at the end of alignment, attitude error, the time after which the accelerometer bias error stays
below 0.02 m/s^2, the free-navigation position error after 30 s, and throughput.

Run: .venv/bin/python bench/alignment.py [runs]
"""

from __future__ import annotations

import sys
import time

import numpy as np
from rich.console import Console
from rich.table import Table

from imuslam.geometry import exp as exp_so3
from imuslam.geometry import log as so3_log
from imuslam.ins.align import Aiding, run_alignment
from imuslam.ins.kf import KfNoise
from imuslam.ins.rwnn import RwnnConfig
from imuslam.ins.strapdown import integrate
from imuslam.interfaces.imu import ImuLog
from imuslam.interfaces.nav import NavState
from imuslam.sim.imu import ImuErrorSpec, simulate_imu
from imuslam.sim.imu_errors import BWT901CL_ACCEL_DENSITY, BWT901CL_GYRO_DENSITY, TriadErrors
from imuslam.sim.trajectory import DiffDriveFigureEight, Static
from imuslam.threads import configure_process

G = 9.80665
T_ALIGN, T_FREE = 60.0, 30.0


def case(scenario: str, seed: int):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(seed)
    ba0 = rng.normal(size=3) * 0.05
    bg0 = rng.normal(size=3) * np.deg2rad(0.3)
    ua, ug = rng.normal(size=3), rng.normal(size=3)
    ua, ug = ua / np.linalg.norm(ua), ug / np.linalg.norm(ug)

    def ba(t: np.ndarray) -> np.ndarray:  # true accelerometer bias at times t, (N, 3)
        if scenario != "warm-up":
            return np.tile(ba0, (len(t), 1))
        return ba0 + 0.004 * 15.0 * (1.0 - np.exp(-t / 20.0))[:, None] * ua

    def bg(t: np.ndarray) -> np.ndarray:
        if scenario != "warm-up":
            return np.tile(bg0, (len(t), 1))
        return bg0 + 2e-4 * 15.0 * (1.0 - np.exp(-t / 20.0))[:, None] * ug

    spec = ImuErrorSpec(TriadErrors(np.eye(3), np.ones(3), ba0, "minus"), TriadErrors(np.eye(3), np.ones(3), bg0, "minus"),
                        BWT901CL_ACCEL_DENSITY, BWT901CL_GYRO_DENSITY, 1e-5, 1e-6)  # fmt: skip
    rate, rot = 200.0, 0.0
    moving = scenario in ("moving", "warm-up")
    if moving:
        traj = DiffDriveFigureEight()
    else:
        traj = Static(rpy=(rng.normal() * 0.05, rng.normal() * 0.05, rng.uniform(-np.pi, np.pi)))
    if scenario == "rotating":
        rate, rot = 400.0, 10.0
    log, tr = simulate_imu(traj, T_ALIGN + T_FREE, rng, spec, rate, g=G, rotating_platform_hz=rot)
    if scenario == "warm-up":  # measured = true + bias: add the bias's change
        t = log.t_s
        log = ImuLog(log.t_ns, log.accel + ba(t) - ba0, log.gyro + bg(t) - bg0)
    aid_rate = 50.0 if scenario == "rotating" else 10.0
    ta = np.arange(1.0 / aid_rate, T_ALIGN, 1.0 / aid_rate)
    if moving:
        aid = Aiding(
            ta, "position", traj.state(ta).p_w + rng.normal(size=(len(ta), 3)) * 0.02, 0.02
        )
    elif scenario == "fixed":
        aid = Aiding(ta, "zupt", np.zeros((len(ta), 3)), 0.01)
    else:  # the turning IMU is not still in rate: zero velocity only
        aid = Aiding(ta, "velocity", np.zeros((len(ta), 3)), 0.01)
    # the same initial state for every method: the truth with an attitude error of 0.5 deg (level) and
    # 2 deg (heading) 1-sigma, what a coarse alignment and a rough heading give
    err = np.deg2rad(np.array([0.5, 0.5, 2.0])) * rng.normal(size=3)
    init = NavState(tr.p_w[0], tr.vel_w[0], exp_so3(err) @ tr.R_w_i[0])
    return log, tr, aid, ba, bg, init


def run(method: str, log, tr, aid, ba_fn, bg_fn, init):  # type: ignore[no-untyped-def]
    t = log.t_s
    k_end = int(np.searchsorted(t, T_ALIGN))
    part = log.slice(0, k_end + 1)
    t0 = time.perf_counter()
    res = run_alignment(
        part,
        aid,
        init,
        "rwnn" if method == "rwnn-nonet" else method,
        KfNoise(BWT901CL_ACCEL_DENSITY, BWT901CL_GYRO_DENSITY, 1e-4, 1e-5),
        g=G,
        rwnn_config=RwnnConfig(network=method != "rwnn-nonet"),
    )  # type: ignore[arg-type]
    hist_a, t_hist = res.accel_bias, res.t_s
    est_a, est_g = res.accel_bias[-1], res.gyro_bias[-1]
    ba, bg = ba_fn(t_hist[-1:])[0], bg_fn(t_hist[-1:])[0]
    state = res.final
    k_end = int(np.searchsorted(t, res.t_s[-1]))  # the state is at the last aiding time
    dt = time.perf_counter() - t0
    err_hist = np.linalg.norm(hist_a - ba_fn(t_hist), axis=1)
    bad = np.flatnonzero(err_hist >= 0.02)
    conv = (
        float(t_hist[bad[-1] + 1])
        if bad.size and bad[-1] + 1 < len(t_hist)
        else (0.0 if not bad.size else np.inf)
    )
    att = float(np.rad2deg(np.linalg.norm(so3_log(tr.R_w_i[k_end].T @ state.R_n_b))))
    P, _, _ = integrate(t[k_end:], log.accel[k_end:] - est_a, log.gyro[k_end:] - est_g, state, G)
    drift = float(np.linalg.norm(P[-1] - tr.p_w[-1]))
    return (
        np.linalg.norm(est_a - ba),
        np.linalg.norm(est_g - bg),
        att,
        conv,
        drift,
        (k_end + 1) / dt,
        err_hist[min(np.searchsorted(t_hist, 10.0), len(t_hist) - 1)],
        err_hist[min(np.searchsorted(t_hist, 30.0), len(t_hist) - 1)],
    )


def main() -> None:
    runs = int(sys.argv[1]) if len(sys.argv) > 1 else 20
    table = Table(
        title=f"Alignment, {runs} seeded runs per cell: mean (std); BWT901CL-class noise, biases 0.05 m/s^2 and 0.3 deg/s"
    )
    for c in ("scenario", "method", "|accel bias err| 10 s", "30 s", "60 s [m/s^2]", "|gyro bias err| [deg/s]", "attitude err [deg]",
              "converged [s]", "free INS 30 s [m]", "samples/s"):  # fmt: skip
        table.add_column(c, justify="right")
    for scen in ("fixed", "moving", "rotating", "warm-up"):
        cases = [case(scen, s) for s in range(runs)]
        for method in ("none", "kf", "stkf", "rwnn", "rwnn-nonet"):
            if method == "none":
                rows = []
                for log, tr, _aid, ba_fn, bg_fn, init in cases:
                    t = log.t_s
                    ba = ba_fn(t[-1:])[0]
                    bg = bg_fn(t[-1:])[0]
                    k_end = int(np.searchsorted(t, T_ALIGN))
                    P, _, R = integrate(t, log.accel, log.gyro, init, G)
                    att = float(np.rad2deg(np.linalg.norm(so3_log(tr.R_w_i[k_end].T @ R[k_end]))))
                    P2, _, _ = integrate(
                        t[k_end:],
                        log.accel[k_end:],
                        log.gyro[k_end:],
                        NavState(tr.p_w[k_end], tr.vel_w[k_end], R[k_end]),
                        G,
                    )
                    rows.append(
                        (
                            np.linalg.norm(ba),
                            np.linalg.norm(bg),
                            att,
                            np.inf,
                            float(np.linalg.norm(P2[-1] - tr.p_w[-1])),
                            np.nan,
                            np.linalg.norm(ba),
                            np.linalg.norm(ba),
                        )
                    )
            else:
                rows = [run(method, *c) for c in cases]
            a = np.array(rows)

            def ms(col: int, scale: float = 1.0, fmt: str = "{:.3g}", a: np.ndarray = a) -> str:
                x = a[:, col] * scale
                fin = np.isfinite(x)
                if not fin.any():
                    return "never"
                s = f"{fmt.format(np.mean(x[fin]))} ({fmt.format(np.std(x[fin]))})"
                return s + (f" [{(~fin).sum()} never]" if (~fin).any() else "")

            table.add_row(scen, method, ms(6), ms(7), ms(0), ms(1, np.rad2deg(1.0)), ms(2), ms(3), ms(4),
                          "-" if method == "none" else f"{np.nanmean(a[:, 5]):,.0f}")  # fmt: skip
    Console(width=200).print(table)


if __name__ == "__main__":
    configure_process()  # the command line's thread defaults, before numba's first parallel kernel
    main()
