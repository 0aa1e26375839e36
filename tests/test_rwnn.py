"""The RWNN observer: its structure (Hurwitz observer, bounded learning) and what it estimates."""

import numpy as np

from imuslam.ins.rwnn import RwnnConfig, run_rwnn
from imuslam.ins.strapdown import NavState
from imuslam.sim.imu import ImuErrorSpec, simulate_imu
from imuslam.sim.imu_errors import TriadErrors
from imuslam.sim.trajectory import Static

G = 9.80665


def test_observer_gain_is_hurwitz() -> None:
    c = RwnnConfig()
    A = np.block([[np.zeros((3, 3)), np.eye(3)], [np.zeros((3, 3)), np.zeros((3, 3))]])
    C = np.hstack([np.eye(3), np.zeros((3, 3))])
    L = np.vstack([2 * c.zeta * c.omega * np.eye(3), c.omega**2 * np.eye(3)])
    assert np.all(np.linalg.eigvals(A - L @ C).real < 0)


def test_static_base_learning_is_bounded_and_moves_towards_the_vertical_error() -> None:
    """Still IMU with zero-velocity aiding, 120 s. Measured behaviour (not a design target): the learned
    vertical accelerometer error has the right sign and stays within twice the true 0.09 m/s^2, and every
    learned weight stays within its bound (no run-away). The horizontal accelerometer errors are
    indistinguishable from tilt on a still base, for any method, and are not checked."""
    ba, bg = np.array([0.06, -0.04, 0.09]), np.array([0.003, -0.002, 0.004])
    spec = ImuErrorSpec(TriadErrors(np.eye(3), np.ones(3), ba, "minus"), TriadErrors(np.eye(3), np.ones(3), bg, "minus"),
                        3e-3, 2e-4)  # fmt: skip
    for seed in range(3):
        log, tr = simulate_imu(
            Static(rpy=(0.05, -0.03, 0.4)), 120.0, np.random.default_rng(seed), spec, 200.0, g=G
        )
        ta = np.arange(0.1, 120.0, 0.1)
        init = NavState(tr.p_w[0], tr.vel_w[0], tr.R_w_i[0])
        r = run_rwnn(log.t_s, log.accel, log.gyro, ta, np.zeros((len(ta), 3)), "velocity", init.p_n, init.v_n,
                     init.R_n_b, G)  # fmt: skip
        assert 0.0 < r.accel_error[-1, 2] < 2 * ba[2]
        assert np.all(np.isfinite(r.accel_error)) and np.all(np.isfinite(r.gyro_error))
        # four weights per output, each within the bound: |output| <= 4 * max_weight * max |Pi|
        assert np.max(np.abs(r.accel_error)) < 4 * RwnnConfig().max_weight * 8
