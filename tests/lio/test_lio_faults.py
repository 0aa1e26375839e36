"""What real sensors do to a LiDAR-inertial drive (``sim.faults``), against the simulator's truth:
scans and IMU samples dropped, an IMU gap, a gyro clipped on a fast turn, an open field that
constrains only part of the pose, cars and pedestrians moving through the scans; and the guards'
kernels (``lio.guards``) against cases whose answer is known in closed form."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2

from imuslam.errors import FilterDivergence
from imuslam.eval.metrics import evaluate
from imuslam.imu.model import ImuCalibration, TriadModel
from imuslam.ins.core import ErrorLayout, Eskf, InsState, boxminus
from imuslam.interfaces import ImuLog, Trajectory
from imuslam.io.lidarsets import MemoryDataset
from imuslam.lio.config import ExtrinsicConfig, FilterConfig, FrontEndConfig, LioConfig
from imuslam.lio.guards import DegeneracyGuard, GuardedEskf, detect_range, repair_imu
from imuslam.lio.pipeline import LioPipeline, LioResult
from imuslam.sim import faults as F
from imuslam.sim.drive import LidarDrive, simulate_lidar_drive
from imuslam.sim.imu_errors import SEED000_ACCEL, SEED000_GYRO
from imuslam.sim.lidar import Lidar3dConfig

LIDAR = Lidar3dConfig(columns=900)  # half the bench's columns: the same geometry, half the cost


def _calibrated(log: ImuLog) -> ImuLog:
    a, g = SEED000_ACCEL, SEED000_GYRO
    cal = ImuCalibration(
        TriadModel(a.T, a.K, a.b, a.bias_sign), TriadModel(g.T, g.K, g.b, g.bias_sign)
    )
    return cal.correct(log)


def _run(d: LidarDrive, imu: ImuLog | None = None, **filt: object) -> LioResult:
    cfg = LioConfig(frontend=FrontEndConfig(mode="direct", scan_voxel=1.0),
                    extrinsic=ExtrinsicConfig(p_i_l=tuple(d.T_i_l[:3, 3])),  # type: ignore[arg-type]
                    filter=FilterConfig(**filt))  # type: ignore[arg-type]  # fmt: skip
    log = _calibrated(d.imu if imu is None else imu)
    return LioPipeline(MemoryDataset(d.scans, log, "sim"), cfg, progress=False).run()


def _assert_tracks(d: LidarDrive, res: LioResult) -> None:
    """The issue's accuracy bounds as on the clean drive (tests/lio/test_lio_sim.py): ATE within
    0.5 % of the path, rotation RMSE within 0.5 deg; every pose finite."""
    gt = Trajectory(d.gt_t_ns, d.gt_p_w, d.gt_R_w_b, "truth")
    assert np.all(np.isfinite(res.trajectory.p_w))
    ev = evaluate(gt, res.trajectory, "se3", 1.0, "frames", 0.02)
    assert ev.ape_trans.rmse < 0.005 * gt.path_length
    assert ev.ape_rot_deg.rmse < 0.5


# --- the guards' kernels ---------------------------------------------------------------------
def _hump(peak_dps: float = 337.0, T: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(0.0, 4.0, 0.005)
    _, ds = F._quintic(t - 1.0, T)
    w = np.zeros((len(t), 3))
    w[:, 2] = np.deg2rad(peak_dps) / 1.875 * T * ds
    return t, w


def test_a_clipped_turn_is_detected_and_bridged() -> None:
    """A whole turn in 2 s (337 deg/s peak) clipped at 250 deg/s loses 43 deg of the turn; the
    quadratic bridge through the 0.1 s flanks restores 87 % of it (a hump is flatter than a parabola
    near its base: the bridge falls short, never over), and the attitude 1-sigma it adds covers what is
    left (the LiDAR update takes it back).
    Without the range given, the clip level is found from the repeated samples."""
    t, w = _hump()
    clipped = np.clip(w, -np.deg2rad(250), np.deg2rad(250))
    log = ImuLog((t * 1e9).astype(np.int64), np.tile([0, 0, 9.81], (len(t), 1)), clipped)
    assert detect_range(clipped) == pytest.approx(np.deg2rad(250))
    assert detect_range(w) is None
    lost = np.rad2deg(np.sum(w[:-1, 2] - clipped[:-1, 2]) * 0.005)
    assert lost > 40.0
    for rng_dps in (250.0, None):
        rep = repair_imu(log, rng_dps, 0.03)
        left = np.rad2deg(np.sum(w[:-1, 2] - rep.imu.gyro[:-1, 2]) * 0.005)
        assert 0.0 < left < 0.15 * lost
        th, _, _ = rep.extra_covariance(0.0, 4.0)
        assert np.rad2deg(np.sqrt(th)) > abs(left)
        assert rep.n_clipped > 0 and rep.notes


def test_an_imu_gap_adds_covariance_over_the_gap_only() -> None:
    t = np.arange(0.0, 2.0, 0.005)
    keep = (t < 1.0) | (t >= 1.5)
    log = ImuLog(
        (t[keep] * 1e9).astype(np.int64),
        np.tile([0, 0, 9.81], (keep.sum(), 1)),
        np.zeros((keep.sum(), 3)),
    )
    rep = repair_imu(log, None, 0.03)
    assert len(rep.gaps) == 1 and rep.gaps[0][1] - rep.gaps[0][0] == pytest.approx(0.505)
    assert rep.extra_covariance(0.0, 0.9) == (0.0, 0.0, 0.0)
    th, vel, pos = rep.extra_covariance(0.9, 1.6)
    assert th == pytest.approx((0.1 * 0.505) ** 2) and vel == pytest.approx((0.5 * 0.505) ** 2)


def _plane_rows(
    rng: np.random.Generator, n: np.ndarray, centre: np.ndarray, m: int = 400
) -> np.ndarray:
    """Point-to-plane Jacobian rows [n, (p x n)] on [p, theta] of ``m`` points on a plane."""
    a, b = np.linalg.svd(n[None])[2][1:]
    p = centre + rng.uniform(-20, 20, (m, 1)) * a + rng.uniform(-20, 20, (m, 1)) * b
    return np.column_stack([np.tile(n, (m, 1)), np.cross(p, n)])


@pytest.mark.parametrize(("planes", "expected"), [
    ("ground", ["x", "y", "yaw"]), ("ground+wall", ["x"]), ("box", [])])  # fmt: skip
def test_degeneracy_names_the_directions_the_planes_leave_free(
    planes: str, expected: list[str]
) -> None:
    """The ground alone fixes z, roll and pitch; a wall along x adds y and yaw; walls facing x too fix
    everything: the free directions are the test's, and the remapped Jacobian has no component
    along them."""
    rng = np.random.default_rng(0)
    rows = [_plane_rows(rng, np.array([0.0, 0, 1]), np.array([0.0, 0, -1.8]))]
    if planes != "ground":
        rows.append(_plane_rows(rng, np.array([0.0, 1, 0]), np.array([0.0, -8, 0])))
    if planes == "box":
        rows.append(_plane_rows(rng, np.array([1.0, 0, 0]), np.array([15.0, 0, 0])))
    Hp = np.vstack(rows)
    lay = ErrorLayout.full(gravity=True)
    H = np.zeros((len(Hp), lay.dim))
    H[:, lay.P], H[:, lay.TH] = Hp[:, :3], Hp[:, 3:]
    R = np.full(len(H), 0.05**2 * len(H) / 30)
    guard = DegeneracyGuard(lay, 0.1, True)
    deg, proj = guard.test(H, R)
    assert deg.directions == expected
    if expected:
        assert proj is not None
        e = np.zeros(6)
        e[{"x": 0, "y": 1}[expected[0]]] = 1.0  # a pure translation along the first free axis
        assert np.allclose(Hp @ proj @ e, 0.0, atol=1e-9)
    else:
        assert proj is None


def _ground_and_a_far_wall(lay: ErrorLayout) -> tuple[np.ndarray, np.ndarray]:
    """H (M, dim) and R (M,): the ground within 20 m (z, roll, pitch) and two points of a wall 55 m
    ahead at 0.2 m noise, 1 m below and above the sensor (x known to 0.14 m from the scan, not tied
    to pitch: degenerate at 0.1 m along x itself; y, yaw unseen)."""
    rng = np.random.default_rng(2)
    Hp = np.vstack([_plane_rows(rng, np.array([0.0, 0, 1]), np.array([0.0, 0, -1.8])),
                    np.column_stack([np.tile([1.0, 0, 0], (2, 1)),
                                     np.cross([[55.0, 0, -1], [55.0, 0, 1]], [1.0, 0, 0])])])  # fmt: skip
    H = np.zeros((len(Hp), lay.dim))
    H[:, lay.P], H[:, lay.TH] = Hp[:, :3], Hp[:, 3:]
    R = np.r_[np.full(len(Hp) - 2, 0.05**2), 0.2**2, 0.2**2]
    return H, R


def test_the_guard_projects_through_the_filters_update_hook() -> None:
    """The degeneracy guard's projector applied by the iterated update's hook (``GuardedEskf``)
    gives the update of the same Jacobian projected inside the linearisation (the guard's former
    form) to rounding; with a prior that does not correlate the free directions with the others,
    x, y and yaw keep the prior's value and variance (the IMU's prediction) while the unguarded
    update moves x by the far wall's noise, and z, roll, pitch reach the truth (chi-square bound)."""
    lay = ErrorLayout.full(gravity=True)
    H, R = _ground_and_a_far_wall(lay)
    guard = DegeneracyGuard(lay, 0.1, True)
    T = guard.projector(H, R)
    assert T is not None and guard.last is not None and guard.last.directions == ["x", "y", "yaw"]
    rng = np.random.default_rng(3)
    x0 = InsState(np.zeros(3), np.zeros(3), np.eye(3))
    sd = np.sqrt(lay.diag(theta=0.01**2, p=0.3**2, v=0.1**2, ba=0.05**2, bg=0.001**2, g=0.01**2))
    dx_true = rng.normal(0.0, sd)
    r_meas = H @ dx_true + rng.normal(0.0, np.sqrt(R))

    def lin(x: InsState) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return r_meas - H @ boxminus(x, x0, lay), H, R

    cols = np.r_[np.arange(lay.P.start, lay.P.stop), np.arange(lay.TH.start, lay.TH.stop)]
    _, proj = guard.test(H, R)
    assert proj is not None

    def lin_projected(x: InsState) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        r, Hx, Rx = lin(x)
        Hx = Hx.copy()
        Hx[:, cols] = Hx[:, cols] @ proj
        return r, Hx, Rx

    A = rng.normal(size=(lay.dim, lay.dim))
    for P0 in (
        np.diag(sd**2),
        np.diag(sd) @ (np.eye(lay.dim) + 0.3 * np.tanh(A @ A.T / lay.dim)) @ np.diag(sd),
    ):
        hook = GuardedEskf(x0, P0, layout=lay)
        hook.projector = T
        res = hook.iterated_update(lin, 10, 1e-12)
        wrapped = Eskf(x0, P0, layout=lay)
        ref = wrapped.iterated_update(lin_projected, 10, 1e-12)
        assert np.allclose(res.dx, ref.dx, rtol=0, atol=1e-12)
        assert np.allclose(hook.P, wrapped.P, rtol=0, atol=1e-15)
    P0 = np.diag(sd**2)
    kf = GuardedEskf(x0, P0, layout=lay)
    kf.projector = T
    dx = kf.iterated_update(lin, 10, 1e-12).dx
    free = np.r_[lay.P.start, lay.P.start + 1, lay.TH.start + 2]
    assert np.all(np.abs(dx[free]) < 1e-12)
    assert np.allclose(kf.P[np.ix_(free, free)], P0[np.ix_(free, free)], rtol=1e-12, atol=0)
    seen = np.r_[lay.P.start + 2, lay.TH.start, lay.TH.start + 1]
    e = dx[seen] - dx_true[seen]  # its NEES within the chi-square(3) 99.9 % bound
    assert e @ np.linalg.solve(kf.P[np.ix_(seen, seen)], e) < chi2.ppf(0.999, 3)
    free_kf = Eskf(x0, P0, layout=lay)
    dx_free = free_kf.iterated_update(lin, 10, 1e-12).dx
    assert abs(dx_free[lay.P.start]) > 0.01  # the unguarded update follows the two far points


# --- on the simulator's drives ------------------------------------------------------------------
@pytest.fixture(scope="module")
def street() -> LidarDrive:
    return simulate_lidar_drive("street", 8.0, seed=21, lidar=LIDAR)


def test_dropped_scans_and_imu_samples(street: LidarDrive) -> None:
    rng = np.random.default_rng(4)
    d = replace(street, scans=F.drop_scans(street.scans, 0.05, rng))
    res = _run(d, F.drop_imu_samples(street.imu, 0.02, rng))
    assert len(res.trajectory) == len(d.scans) == len(street.scans) - 4
    _assert_tracks(d, res)


def test_an_imu_gap_of_half_a_second(street: LidarDrive) -> None:
    res = _run(street, F.imu_gap(street.imu, 4.0, 0.5))
    assert any("IMU gaps" in w for w in res.warnings)
    _assert_tracks(street, res)


@pytest.mark.slow
def test_a_clipped_gyro_on_a_fast_turn_is_bridged_or_reported() -> None:
    """A whole turn of the head in 2 s (337 deg/s) with a +-250 deg/s gyro: bridged, the filter keeps
    the accuracy bounds; without the guard its attitude ends 20-40 deg off and it says so (a
    FilterDivergence naming the scan: exit 3 in ``imuslam lio``) instead of going on."""
    d = F.simulate_fault_drive("spin", 8.0, seed=2, lidar=LIDAR)
    assert np.rad2deg(np.abs(d.imu.gyro[:, 2]).max()) > 300.0
    imu = F.saturate_gyro(d.imu, 250.0)
    res = _run(d, imu, gyro_range_dps=250.0)
    assert any("bridged" in w for w in res.warnings)
    _assert_tracks(d, res)
    with pytest.raises(FilterDivergence, match=r"^scan \d+ \(t = .*lost the map"):
        _run(d, imu, imu_guard=False)


@pytest.mark.slow
def test_an_open_field_is_reported_degenerate_and_crossed_on_the_imu() -> None:
    """The straight road from x = 90 m: the LiDAR sees only the ground while its x is within
    123-171 m (nearest building beyond its 60 m), from 4.1 s to 10.1 s. The filter reports the
    scans about that window degenerate in x, y and yaw (from a little before it: the last buildings'
    few points at 55-60 m carry little information; to up to 1.5 s after it: the next buildings must
    enter the map before they are matched) and keeps the accuracy bounds across it."""
    d = F.simulate_fault_drive("field", 12.0, seed=3, lidar=LIDAR, road_x0=90.0)
    est_res = _run(d)
    _assert_tracks(d, est_res)
    note = next(w for w in est_res.warnings if "degenerate scans" in w)
    assert note.endswith("x, y, yaw kept at the IMU's prediction")
    t = [float(v) for v in note.split("t = ")[1:3] for v in [v.split(" s")[0]]]
    assert 3.4 <= t[0] <= 4.6 and 10.1 <= t[1] <= 11.6


@pytest.mark.slow
def test_moving_cars_and_pedestrians() -> None:
    d = F.simulate_fault_drive("traffic", 8.0, seed=4, lidar=LIDAR)
    assert F.dynamic_fraction(d.scans) > 0.02
    _assert_tracks(d, _run(d))


@pytest.mark.slow
def test_the_command_on_a_clipped_gyro_bridges_it_or_exits_3_naming_the_scan(
    tmp_path: Path,
) -> None:
    """``imuslam lio`` on a bag whose raw gyro clips at +-250 deg/s on the fast turn, with the IMU
    calibration applied (``--calib``): with the range in the config, exit 0 and the bridged samples
    reported; with the guard off, exit 3 and one line naming the scan, never a traceback."""
    from typer.testing import CliRunner

    from imuslam.cli import app
    from imuslam.sim import export

    d = F.simulate_fault_drive("spin", 8.0, seed=2, lidar=LIDAR)
    pc = [(s.t_ns, "/points", export.pointcloud_message(s)[1]) for s in d.scans]
    export.write_bag(
        tmp_path / "bag", [export.imu_messages(F.saturate_gyro(d.imu, 250.0)), iter(pc)]
    )
    a, g = SEED000_ACCEL, SEED000_GYRO
    cal = ImuCalibration(
        TriadModel(a.T, a.K, a.b, a.bias_sign), TriadModel(g.T, g.K, g.b, g.bias_sign)
    )
    cal.save_yaml(tmp_path / "calibration.yaml")
    runner = CliRunner()
    out = {}
    for name, filt in (("guard", "gyro_range_dps: 250"), ("off", "imu_guard: false")):
        (tmp_path / f"{name}.yaml").write_text(
            f"extrinsic:\n  p_i_l: [0.0, 0.0, 0.2]\nfrontend:\n  mode: direct\nfilter:\n  {filt}\n"
        )
        out[name] = runner.invoke(app, ["lio", str(tmp_path / "bag"), "--imu-topic", "/imu/data", "--points-topic",
                                        "/points", "--config", str(tmp_path / f"{name}.yaml"), "--calib",
                                        str(tmp_path / "calibration.yaml"), "--out", str(tmp_path / name)])  # fmt: skip
    assert out["guard"].exit_code == 0, out["guard"].output
    assert "bridged" in out["guard"].output
    r = out["off"]
    assert r.exit_code == 3, r.output
    assert "Traceback" not in r.output and "lost the map" in r.output
    assert re.search(r"scan \d+ \(t = ", r.output)
    assert "set filter.gyro_range_dps" in " ".join(r.output.split())
    assert not (tmp_path / "off").exists()
