"""A simulated ground robot with a rendered stereo camera and an IMU, with exact ground truth.

The differential-drive robot of seed 000 drives its figure eight in the 8 m x 8 m room; a forward-looking
stereo camera (rectified, 752 x 480, pitched down to see the floor) is rendered by ray casting
(:mod:`imuslam.sim.render`) at every frame time, so visual odometry runs on pixels for as long as wanted;
the IMU (body frame, at the body origin) carries constant biases and white noise of a consumer MEMS.
Frames are rendered lazily, one at a time, as :meth:`SimStereoRun.frames` is iterated.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from imuslam.io.trajectory import Trajectory
from imuslam.sim.imu import ImuErrorSpec, simulate_imu
from imuslam.sim.imu_errors import BWT901CL_ACCEL_DENSITY, BWT901CL_GYRO_DENSITY, TriadErrors
from imuslam.sim.render import CameraRig, render_stereo
from imuslam.sim.stereo import R_B_C_FORWARD
from imuslam.sim.trajectory import DiffDriveFigureEight, EulerTrajectory
from imuslam.sim.world import World, room_8x8

FloatArray = NDArray[np.float64]
U8Image = NDArray[np.uint8]


@dataclass
class StereoRunConfig:
    """Duration (s), rates (Hz), seed, camera mount (pitch down in degrees, position in the body, m) and
    IMU biases (accelerometer m/s^2, gyro rad/s) and noise densities (per sqrt(Hz))."""

    duration_s: float = 10.0
    image_hz: float = 20.0
    imu_hz: float = 200.0
    seed: int = 0
    pitch_down_deg: float = 12.0
    p_b_c: tuple[float, float, float] = (0.25, 0.055, 0.35)
    accel_bias: tuple[float, float, float] = (0.04, -0.03, 0.05)
    gyro_bias: tuple[float, float, float] = (0.003, -0.002, 0.004)
    accel_density: float = BWT901CL_ACCEL_DENSITY
    gyro_density: float = BWT901CL_GYRO_DENSITY
    t0_ns: int = 1_000_000_000
    rig: CameraRig = field(default_factory=CameraRig)


@dataclass
class SimRectification:
    """The rendered pair is rectified by construction: rectification is the identity."""

    K: FloatArray
    baseline: float
    width: int
    height: int
    R_b_r: FloatArray
    p_b_r: FloatArray

    @property
    def f(self) -> float:
        return float(self.K[0, 0])

    def rectify(self, left: U8Image, right: U8Image) -> tuple[U8Image, U8Image]:
        return left, right


class SimStereoRun:
    """IMU log, ground truth and lazily rendered stereo frames of one simulated run."""

    def __init__(
        self,
        cfg: StereoRunConfig | None = None,
        traj: EulerTrajectory | None = None,
        world: World | None = None,
    ) -> None:
        self.cfg = c = cfg or StereoRunConfig()
        self.traj = traj or DiffDriveFigureEight()
        self.world = world or room_8x8()
        self.source = f"simulated stereo run (seed {c.seed}, {c.duration_s:g} s)"
        rng = np.random.default_rng(c.seed)
        self._rng_img = np.random.default_rng(c.seed + 1_000_003)
        errors = ImuErrorSpec(
            accel=TriadErrors(np.eye(3), np.ones(3), -np.asarray(c.accel_bias, float)),
            gyro=TriadErrors(np.eye(3), np.ones(3), -np.asarray(c.gyro_bias, float)),
            accel_density=c.accel_density,
            gyro_density=c.gyro_density,
        )
        # TriadErrors' bias is the correction (x_O = x_S + b): the raw output carries +bias
        self.imu, self._imu_truth = simulate_imu(
            self.traj, c.duration_s, rng, errors, rate_hz=c.imu_hz, t0_ns=c.t0_ns
        )
        self.imu.source = self.source
        th = np.deg2rad(c.pitch_down_deg)
        pitch = np.array([[1.0, 0, 0], [0, np.cos(th), np.sin(th)], [0, -np.sin(th), np.cos(th)]])
        self.R_b_c = R_B_C_FORWARD @ pitch
        self.p_b_c = np.asarray(c.p_b_c, float)
        n = int(np.floor(c.duration_s * c.image_hz)) + 1
        self.t_frames_ns = c.t0_ns + np.round(np.arange(n) / c.image_hz * 1e9).astype(np.int64)

    def __len__(self) -> int:
        return len(self.t_frames_ns)

    def rectification(self) -> SimRectification:
        r = self.cfg.rig
        return SimRectification(r.K, r.baseline, r.width, r.height, self.R_b_c, self.p_b_c)

    def skipped_frames(self) -> dict[str, int]:
        return {"missing": 0, "unreadable": 0}

    def truth(self, t_ns: NDArray[np.int64] | None = None) -> Trajectory:
        """Body poses at ``t_ns`` (default: the IMU times)."""
        t = self.imu.t_ns if t_ns is None else np.asarray(t_ns, dtype=np.int64)
        st = self.traj.state((t - self.cfg.t0_ns) * 1e-9)
        return Trajectory(t, st.p_w, st.R_w_b, "simulated truth")

    def velocity_b(self, t_ns: NDArray[np.int64]) -> tuple[FloatArray, FloatArray]:
        """True body velocity (N, 3) and body rate (N, 3) at ``t_ns``."""
        st = self.traj.state((np.asarray(t_ns) - self.cfg.t0_ns) * 1e-9)
        return np.einsum("nji,nj->ni", st.R_w_b, st.vel_w), st.omega_b

    def frames(self) -> Iterator[tuple[int, U8Image | None, U8Image | None]]:
        for t in self.t_frames_ns:
            st = self.traj.state(np.array([(t - self.cfg.t0_ns) * 1e-9]))
            R_w_c = st.R_w_b[0] @ self.R_b_c
            p_w_c = st.p_w[0] + st.R_w_b[0] @ self.p_b_c
            left, right, _ = render_stereo(self.world, self.cfg.rig, R_w_c, p_w_c, self._rng_img)
            yield int(t), left, right
