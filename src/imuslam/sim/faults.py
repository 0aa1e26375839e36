"""What real sensors do to a LiDAR-inertial drive, injected into the simulator's drives with the truth kept.

Record faults (applied to a drive's records): scans and IMU samples dropped at random, an IMU gap, a
gyro that clips at its range. Scene faults (new drives): a fast turn of the sensor head on the street
loop (a whole turn about z in 2 s, 337 deg/s at its peak, beyond a +-250 deg/s gyro), cars and
pedestrians moving through the street drive's scans, and a straight road whose middle crosses an open
field where the LiDAR sees the flat ground only (degenerate for scan matching in x, y and yaw).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from imuslam.interfaces.imu import ImuLog
from imuslam.interfaces.lidar import Scan3d
from imuslam.sim.drive import T0_NS, LidarDrive, car_loop_period_s
from imuslam.sim.imu import ImuErrorSpec, simulate_imu
from imuslam.sim.lidar import Lidar3dConfig, MoversFn, simulate_lidar3d_scan
from imuslam.sim.trajectory import CarLoop, EulerTrajectory, TrajectoryState
from imuslam.sim.world import World, WorldBuilder, urban_block

FloatArray = NDArray[np.float64]


# --- record faults ---------------------------------------------------------------------------
def drop_scans(scans: list[Scan3d], fraction: float, rng: np.random.Generator) -> list[Scan3d]:
    """The scans with ``fraction`` of them (never the first three: the start) dropped at random."""
    n = len(scans)
    k = int(round(fraction * n))
    gone = set((3 + rng.choice(n - 3, size=k, replace=False)).tolist()) if k else set()
    return [s for j, s in enumerate(scans) if j not in gone]


def drop_imu_samples(imu: ImuLog, fraction: float, rng: np.random.Generator) -> ImuLog:
    """The log with ``fraction`` of its samples (not the first or last) dropped at random."""
    n = len(imu)
    keep = np.ones(n, bool)
    keep[1 + rng.choice(n - 2, size=int(round(fraction * n)), replace=False)] = False
    return replace(imu, t_ns=imu.t_ns[keep], accel=imu.accel[keep], gyro=imu.gyro[keep])


def imu_gap(imu: ImuLog, start_s: float, length_s: float) -> ImuLog:
    """The log without its samples in [start_s, start_s + length_s) s after its first sample."""
    t = (imu.t_ns - imu.t_ns[0]) * 1e-9
    keep = (t < start_s) | (t >= start_s + length_s)
    return replace(imu, t_ns=imu.t_ns[keep], accel=imu.accel[keep], gyro=imu.gyro[keep])


def saturate_gyro(imu: ImuLog, range_dps: float) -> ImuLog:
    """The gyro clipped at +-``range_dps`` on each axis, as a MEMS gyro's output saturates."""
    lim = np.deg2rad(range_dps) if imu.gyro_unit == "rad/s" else range_dps
    return replace(imu, gyro=np.clip(imu.gyro, -lim, lim))


# --- scene faults ----------------------------------------------------------------------------
def _quintic(t: FloatArray, T: float) -> tuple[FloatArray, FloatArray]:
    """Quintic smoothstep from 0 to 1 over [0, T] and its derivative (zero rate and acceleration at
    both ends)."""
    x = np.clip(t / T, 0.0, 1.0)
    inside = (t > 0) & (t < T)
    return 10 * x**3 - 15 * x**4 + 6 * x**5, np.where(inside, 30 * x**2 * (1 - x) ** 2 / T, 0.0)


class SpinTurn(EulerTrajectory):
    """``base`` with the sensor head turned ``turns`` times about its z axis over [t0, t0 + T] s
    (a quintic profile: peak rate 1.875 * 2 pi turns / T). The path is the base's."""

    def __init__(self, base: EulerTrajectory, t0: float, T: float, turns: float = 1.0) -> None:
        self.base, self.t0, self.T, self.turns = base, t0, T, turns

    @property
    def peak_rate_dps(self) -> float:
        return float(np.rad2deg(2 * np.pi * self.turns * 1.875 / self.T))

    def position(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        return self.base.position(t)

    def euler(self, t: FloatArray) -> tuple[FloatArray, FloatArray]:
        ang, rate = self.base.euler(t)
        s, ds = _quintic(np.asarray(t, float) - self.t0, self.T)
        ang, rate = ang.copy(), rate.copy()
        ang[:, 2] += 2 * np.pi * self.turns * s
        rate[:, 2] += 2 * np.pi * self.turns * ds
        return ang, rate


class StraightRoad(EulerTrajectory):
    """A car along +x at ``speed`` m/s from x = ``x0``, weaving ``weave`` m across the road, the LiDAR
    ``height`` m above the ground; yaw along the velocity, a few mrad of roll and pitch."""

    def __init__(self, speed: float = 8.0, weave: float = 1.0, x0: float = 0.0,
                 height: float = 1.8) -> None:  # fmt: skip
        self.v, self.a, self.x0, self.h = speed, weave, x0, height

    def position(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        w, z = 0.35, np.zeros_like(t)
        p = np.stack([self.x0 + self.v * t, self.a * np.sin(w * t), z + self.h], axis=1)
        v = np.stack([z + self.v, self.a * w * np.cos(w * t), z], axis=1)
        a = np.stack([z, -self.a * w**2 * np.sin(w * t), z], axis=1)
        return p, v, a

    def euler(self, t: FloatArray) -> tuple[FloatArray, FloatArray]:
        _, v, a = self.position(t)
        yaw = np.arctan2(v[:, 1], v[:, 0])
        dyaw = (v[:, 0] * a[:, 1] - v[:, 1] * a[:, 0]) / (v[:, 0] ** 2 + v[:, 1] ** 2)
        roll, droll = 0.005 * np.sin(1.1 * t), 0.0055 * np.cos(1.1 * t)
        pitch, dpitch = 0.005 * np.sin(0.8 * t + 1.0), 0.004 * np.cos(0.8 * t + 1.0)
        return np.stack([roll, pitch, yaw], axis=1), np.stack([droll, dpitch, dyaw], axis=1)


def open_field_road(field_from: float = 60.0, field_to: float = 230.0) -> World:
    """A straight road along x through a town for x < ``field_from`` and x > ``field_to`` (buildings,
    poles and parked cars on both sides) and an open field between: the flat ground only."""
    rng = np.random.default_rng(3)
    b = WorldBuilder("open_field_road")
    b.rect([150, 0, 0], [1, 0, 0], [0, 1, 0], 260, 120, 0.2)
    for lo, hi in ((-60.0, field_from), (field_to, 380.0)):
        for x0 in np.arange(lo, hi - 10.0, 18.0):
            for side in (1.0, -1.0):
                y = sorted([side * 12.0, side * (22.0 + rng.uniform(0, 6))])
                b.box(
                    [x0, y[0], 0], [x0 + 14 + rng.uniform(-2, 2), y[1], 8 + rng.uniform(0, 12)], 0.6
                )
                b.box([x0 + 3, side * 9.5 - 0.15, 0], [x0 + 3.3, side * 9.5 + 0.15, 4], 0.9)
    return b.build()


def street_traffic(seed: int = 0, n_cars: int = 6, n_pedestrians: int = 10) -> MoversFn:
    """Cars driving the street loop around the block in both directions in the other lanes (6-11 m/s)
    and pedestrians walking the sidewalks (1-1.8 m/s), as axis-aligned boxes (cars 4.5 x 1.8 x 1.5 m,
    people 0.5 x 0.5 x 1.8 m): a callable t_s -> the world of their rectangles then."""
    rng = np.random.default_rng(seed)
    cars = []
    for j in range(n_cars):
        lane = 3.5 if j % 2 else -3.5  # the lane beside the drive's, or the one across
        direction = -1.0 if j % 2 else 1.0
        loop = CarLoop(half_x=45.0 + lane, half_y=31.0 + lane, speed=rng.uniform(6, 11))
        cars.append((loop, direction, rng.uniform(0, 2 * np.pi / loop.w)))
    walkers = []
    for _ in range(n_pedestrians):
        y = rng.choice([-37.5, 37.5, -23.0, 23.0])
        walkers.append((rng.uniform(-45, 45), y, rng.uniform(1.0, 1.8) * rng.choice([-1, 1])))

    car_half = np.array([2.25, 0.9, 0.75])
    walker_half = np.array([0.25, 0.25, 0.9])
    inten = np.r_[np.full(len(cars), 0.7), np.full(len(walkers), 0.4)]

    def at(t: float) -> World:
        centres = [
            loop.position(np.array([direction * t + phase]))[0][0]
            for loop, direction, phase in cars
        ]
        for x0, y, v in walkers:
            x = (x0 + v * t + 50.0) % 100.0 - 50.0  # up and down the block's sides
            centres.append(np.array([x, y, 0.0]))
        c = np.array(centres)
        h = np.array([car_half] * len(cars) + [walker_half] * len(walkers))
        c[:, 2] = h[:, 2]  # standing on the ground
        return boxes_world(c, h, inten, "traffic")

    return at


def boxes_world(centre: FloatArray, half: FloatArray, intensity: FloatArray, name: str) -> World:
    """Axis-aligned boxes (K centres and half-extents (K, 3), m) as a world of 6 K rectangles, built
    at once (``WorldBuilder.box`` one rectangle at a time is 30 ms for 16 boxes, too slow per slice
    of a turn)."""
    K = len(centre)
    E = np.eye(3)
    cs, us, vs, hs = [], [], [], []
    for a in range(3):  # the two faces normal to axis a: edges along the next two axes
        b, c = (a + 1) % 3, (a + 2) % 3
        for sgn in (-1.0, 1.0):
            cs.append(centre + sgn * half[:, a : a + 1] * E[a])
            us.append(np.broadcast_to(E[b], (K, 3)))
            vs.append(np.broadcast_to(E[c] * sgn, (K, 3)))
            hs.append(np.stack([half[:, b], half[:, c]], axis=1))
    n = 6 * K
    return World(np.ascontiguousarray(np.concatenate(cs)), np.ascontiguousarray(np.concatenate(us)),
                 np.ascontiguousarray(np.concatenate(vs)), np.ascontiguousarray(np.concatenate(hs)),
                 np.arange(n, dtype=np.int64), np.tile(intensity, 6), name)  # fmt: skip


def simulate_fault_drive(scene: str, duration_s: float = 20.0, seed: int = 0,
                         imu_errors: ImuErrorSpec | None = None,
                         lidar: Lidar3dConfig | None = None, progress: bool = False,
                         road_x0: float = 0.0) -> LidarDrive:  # fmt: skip
    """A drive with a scene fault: 'spin' (the street loop with a whole turn of the head about z over
    2 s from t = ``duration_s`` / 2), 'traffic' (the street loop with ``street_traffic``) or 'field'
    (``StraightRoad`` through ``open_field_road``, the LiDAR's range cut at 60 m so the field's middle
    shows only the ground while the LiDAR's x is within 123-171 m: from 15 s to 21 s at 8 m/s from
    ``road_x0`` = 0). Frames as ``sim.drive``: the LiDAR 0.2 m
    above the IMU, the body frame the IMU's; IMU at 200 Hz with seed 000's errors by default."""
    rng = np.random.default_rng(seed)
    cfg = lidar or Lidar3dConfig()
    traj: EulerTrajectory
    movers: MoversFn | None = None
    period: float | None = None
    if scene == "spin":
        base = CarLoop()
        traj, world, period = SpinTurn(base, duration_s / 2, 2.0), urban_block(), None
    elif scene == "traffic":
        base = CarLoop()
        traj, world, movers = base, urban_block(), street_traffic(seed)
        period = car_loop_period_s(base)
    elif scene == "field":
        traj, world = StraightRoad(x0=road_x0), open_field_road()
        cfg = replace(cfg, max_range=min(cfg.max_range, 60.0))
    else:
        raise ValueError(f"unknown scene {scene!r}; expected spin, traffic or field")
    errors = ImuErrorSpec.bwt901cl() if imu_errors is None else imu_errors
    log, truth = simulate_imu(traj, duration_s, rng, errors, 200.0, t0_ns=T0_NS)
    p_b_l = np.array([0.0, 0.0, 0.2])

    def pose_w_l(t: FloatArray) -> tuple[FloatArray, FloatArray]:
        st = traj.state(t)
        return st.R_w_b, st.p_w + st.R_w_b @ p_b_l

    n = int(np.floor(duration_s * cfg.rate_hz + 1e-9))
    scans = []
    for k in tqdm(range(n), desc="3D LiDAR", unit="scan", disable=not progress):
        s = simulate_lidar3d_scan(world, pose_w_l, k / cfg.rate_hz, cfg, rng, movers)
        s.t_ns += T0_NS
        scans.append(s)
    gt_t = np.arange(0.0, duration_s + 1e-9, 0.01)
    st: TrajectoryState = traj.state(gt_t)
    T_i_l = np.eye(4)
    T_i_l[:3, 3] = p_b_l
    gt_ns = T0_NS + np.round(gt_t * 1e9).astype(np.int64)
    return LidarDrive(log, scans, T_i_l, gt_ns, st.p_w, st.R_w_b, truth, 0.0, world, period)


def dynamic_fraction(scans: list[Scan3d]) -> float:
    """The fraction of the scans' points that hit a moving object (surface id >= 1000000)."""
    n = sum(len(s) for s in scans)
    m = sum(int(np.count_nonzero(np.asarray(s.surface_id) >= 1_000_000)) for s in scans)
    return m / max(n, 1)
