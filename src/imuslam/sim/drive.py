"""In-memory LiDAR + IMU drives with ground truth, for LiDAR-inertial odometry tests and benchmarks.

The street loop (seed 001: a car around an urban block, VLP-16 at 10 Hz, IMU at 200 Hz) and the corridor
(degenerate for LiDAR alone). Frames: body b (the vehicle), IMU i at the body origin, LiDAR l at
``p_b_l`` above it. With ``rotating_platform_hz`` the IMU and the LiDAR head both sit on a platform that
turns about the body z axis through the body origin (seed 001's hardware): ``R_b_i(t) = Rz(w t)`` and the
LiDAR keeps its fixed pose ``T_i_l`` on the platform.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from imuslam.geometry import exp
from imuslam.interfaces.imu import ImuLog
from imuslam.sim.imu import ImuErrorSpec, ImuTruth, simulate_imu
from imuslam.sim.lidar import Lidar3dConfig, Scan3d, simulate_lidar3d_scan
from imuslam.sim.trajectory import CarLoop, CorridorDrive, EulerTrajectory
from imuslam.sim.world import World, corridor, urban_block

FloatArray = NDArray[np.float64]
T0_NS = 1_700_000_000_000_000_000


@dataclass
class LidarDrive:
    """A simulated drive: the IMU log, the LiDAR scans (stamped at their start), the extrinsic ``T_i_l``
    (4, 4), and truth: body poses ``gt_t_ns`` (M,), ``gt_p_w`` (M, 3), ``gt_R_w_b`` (M, 3, 3) at 100 Hz,
    the IMU truth, and the platform angle rate (rad/s, 0 for a fixed mount)."""

    imu: ImuLog
    scans: list[Scan3d]
    T_i_l: FloatArray
    gt_t_ns: NDArray[np.int64]
    gt_p_w: FloatArray
    gt_R_w_b: FloatArray
    imu_truth: ImuTruth
    platform_rate: float
    world: World
    loop_period_s: float | None = None

    def R_b_i(self, t_ns: NDArray[np.int64]) -> FloatArray:
        """(N, 3, 3) platform rotation at ``t_ns`` (the encoder angle), identity for a fixed mount."""
        ang = (np.asarray(t_ns) - self.imu.t_ns[0]).astype(float) * 1e-9 * self.platform_rate
        return exp(np.outer(ang, [0.0, 0.0, 1.0]))

    def true_deskewed(self, j: int) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Scan ``j``'s points moved into the LiDAR frame at the scan end with the true motion (they keep
        their range noise): ``x_l`` (N, 3), the point times ``t_s`` (N,), s, and the true body pose at
        the scan end ``p_w`` (3,), ``R_w_b`` (3, 3). Fixed mount only."""
        from imuslam.geometry.interp import interpolate_poses

        s = self.scans[j]
        R_i_l, p_i_l = self.T_i_l[:3, :3], self.T_i_l[:3, 3]
        gt_t = self.gt_t_ns.astype(float) * 1e-9
        t = s.t_ns * 1e-9 + s.t_offset_s.astype(float)
        P, R = interpolate_poses(gt_t, self.gt_p_w, self.gt_R_w_b, t)
        pe, Re = interpolate_poses(gt_t, self.gt_p_w, self.gt_R_w_b, np.array([t.max()]))
        x_w = np.einsum("nij,nj->ni", R, s.points_l.astype(float) @ R_i_l.T + p_i_l) + P
        x_l = ((x_w - pe[0]) @ Re[0] - p_i_l) @ R_i_l
        return x_l, t, pe[0], Re[0]


def car_loop_period_s(traj: CarLoop) -> float:
    """Time of one lap of the street loop, s."""
    return float(2 * np.pi / traj.w)


def simulate_lidar_drive(
    scene: str = "street",
    duration_s: float = 20.0,
    seed: int = 0,
    imu_errors: ImuErrorSpec | None = None,
    rotating_platform_hz: float = 0.0,
    lidar: Lidar3dConfig | None = None,
    progress: bool = False,
) -> LidarDrive:
    """Simulate ``scene`` ('street' or 'corridor') for ``duration_s`` with the given IMU errors
    (``None``: seed 000's BWT901CL errors)."""
    rng = np.random.default_rng(seed)
    traj: EulerTrajectory
    if scene == "street":
        traj, world, rate, period = CarLoop(), urban_block(), 200.0, None
        period = car_loop_period_s(traj)  # type: ignore[arg-type]
        p_b_l = np.array([0.0, 0.0, 0.2])
    elif scene == "corridor":
        traj, world, rate, period = CorridorDrive(speed=1.0), corridor(), 200.0, None
        p_b_l = np.array([0.0, 0.0, 0.6])
    else:
        raise ValueError(f"unknown scene {scene!r}; expected street or corridor")
    errors = ImuErrorSpec.bwt901cl() if imu_errors is None else imu_errors
    log, truth = simulate_imu(
        traj, duration_s, rng, errors, rate, t0_ns=T0_NS, rotating_platform_hz=rotating_platform_hz
    )
    w_p = 2 * np.pi * rotating_platform_hz

    def pose_w_l(t: FloatArray) -> tuple[FloatArray, FloatArray]:
        st = traj.state(t)
        R_b_i = exp(np.outer(w_p * t, [0.0, 0.0, 1.0]))
        R_w_i = st.R_w_b @ R_b_i
        return R_w_i, st.p_w + R_w_i @ p_b_l

    cfg = lidar or Lidar3dConfig()
    n = int(np.floor(duration_s * cfg.rate_hz + 1e-9))
    scans = []
    for k in tqdm(range(n), desc="3D LiDAR", unit="scan", disable=not progress):
        s = simulate_lidar3d_scan(world, pose_w_l, k / cfg.rate_hz, cfg, rng)
        s.t_ns += T0_NS
        scans.append(s)
    gt_t = np.arange(0.0, duration_s + 1e-9, 0.01)
    st = traj.state(gt_t)
    T_i_l = np.eye(4)
    T_i_l[:3, 3] = p_b_l
    gt_ns = T0_NS + np.round(gt_t * 1e9).astype(np.int64)
    return LidarDrive(log, scans, T_i_l, gt_ns, st.p_w, st.R_w_b, truth, w_p, world, period)


@dataclass
class LidarImuRig(LidarDrive):
    """A :class:`LidarDrive` whose LiDAR has a general pose ``T_i_l`` on the IMU and a clock offset:
    a scan taken at IMU time ``t`` is stamped ``t - time_offset_s`` (``t_imu = t_lidar +
    time_offset_s``, ``lio.config.ExtrinsicConfig``). The body frame is the IMU frame."""

    time_offset_s: float = 0.0


def simulate_lidar_imu_rig(
    motion: str = "excited",
    duration_s: float = 20.0,
    seed: int = 0,
    T_i_l: FloatArray | None = None,
    time_offset_s: float = 0.0,
    imu_errors: ImuErrorSpec | None = None,
    lidar: Lidar3dConfig | None = None,
    progress: bool = False,
) -> LidarImuRig:
    """A LiDAR rigidly mounted at ``T_i_l`` (4, 4; default: 0.2 m above the IMU) on an IMU (200 Hz), with
    a LiDAR clock offset, for LiDAR-IMU calibration. ``motion``: 'excited' (the rig waved by hand in a
    room with a ceiling, :class:`~imuslam.sim.trajectory.ExcitedHandheld`, ``world.calibration_room``) or 'street' (the car loop around
    the urban block: yaw and a centimetre of roll / pitch only) or 'static' (the rig at rest in the room). ``imu_errors`` None: seed 000's
    BWT901CL errors."""
    from imuslam.sim.trajectory import ExcitedHandheld, Static
    from imuslam.sim.world import calibration_room

    rng = np.random.default_rng(seed)
    traj: EulerTrajectory
    if motion == "excited":
        traj, world, period = ExcitedHandheld((0.0, 0.0, 1.2)), calibration_room(), None
    elif motion == "static":
        traj, world, period = Static((0.0, 0.0, 1.2)), calibration_room(), None
    elif motion == "street":
        traj, world = CarLoop(), urban_block()
        period = car_loop_period_s(traj)  # type: ignore[arg-type]
    else:
        raise ValueError(f"unknown motion {motion!r}; expected excited, static or street")
    if T_i_l is None:
        T_i_l = np.eye(4)
        T_i_l[2, 3] = 0.2
    T = np.asarray(T_i_l, float)
    R_i_l, p_i_l = T[:3, :3], T[:3, 3]
    errors = ImuErrorSpec.bwt901cl() if imu_errors is None else imu_errors
    log, truth = simulate_imu(traj, duration_s, rng, errors, 200.0, t0_ns=T0_NS)

    def pose_w_l(t: FloatArray) -> tuple[FloatArray, FloatArray]:
        st = traj.state(t)
        return st.R_w_b @ R_i_l, st.p_w + st.R_w_b @ p_i_l

    cfg = lidar or Lidar3dConfig()
    # scans start after the first IMU sample and end before the last in both clocks
    first = max(0.0, time_offset_s)
    n = int(np.floor((duration_s - first - abs(time_offset_s)) * cfg.rate_hz - 1e-9))
    off_ns = int(round(time_offset_s * 1e9))
    scans = []
    for k in tqdm(range(n), desc="3D LiDAR", unit="scan", disable=not progress):
        s = simulate_lidar3d_scan(world, pose_w_l, first + k / cfg.rate_hz, cfg, rng)
        s.t_ns += T0_NS - off_ns
        scans.append(s)
    gt_t = np.arange(0.0, duration_s + 1e-9, 0.01)
    st = traj.state(gt_t)
    gt_ns = T0_NS + np.round(gt_t * 1e9).astype(np.int64)
    return LidarImuRig(log, scans, T.copy(), gt_ns, st.p_w, st.R_w_b, truth, 0.0, world, period,
                       float(time_offset_s))  # fmt: skip
