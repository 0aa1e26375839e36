"""A simulated ground robot with a rendered stereo camera and an IMU, with exact ground truth.

The differential-drive robot of seed 000 drives its figure eight in the 8 m x 8 m room; a forward-looking
stereo camera (rectified, 752 x 480, pitched down to see the floor) is rendered by ray casting
(:mod:`imuslam.sim.render`) at every frame time, so visual odometry runs on pixels for as long as wanted;
the IMU (body frame, at the body origin) carries constant biases and white noise of a consumer MEMS.
Frames are rendered lazily, one at a time, as :meth:`SimStereoRun.frames` is iterated.

The figure eight's roll / pitch wobble stands for uneven ground. A wheeled robot on the ground moves
along its own forward axis, so by default (:class:`GroundFollowingFigureEight`) the body rises and sinks
with the pitch, ``v_z = -v_h tan(pitch)``, and the body velocity has no lateral or vertical part: the
non-holonomic constraint the filter applies at the body origin holds exactly. The figure eight of
seed 000 (``ground_following=False``) keeps its velocity horizontal while the body pitches, which gives
a vertical body velocity of 1.2e-3 m/s RMS at 0.3-0.4 m/s: a constraint violated by the simulator.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from imuslam.interfaces.imu import ImuLog
from imuslam.io.camcalib import Rectification
from imuslam.io.trajectory import Trajectory
from imuslam.sim.imu import ImuErrorSpec, simulate_imu
from imuslam.sim.imu_errors import BWT901CL_ACCEL_DENSITY, BWT901CL_GYRO_DENSITY, TriadErrors
from imuslam.sim.render import CameraRig, render_stereo
from imuslam.sim.stereo import R_B_C_FORWARD
from imuslam.sim.trajectory import DiffDriveFigureEight, EulerTrajectory
from imuslam.sim.world import World, room_8x8

FloatArray = NDArray[np.float64]
U8Image = NDArray[np.uint8]

# Gauss-Legendre nodes on [0, 1] for the height integral (10 nodes: exact to rounding over 0.25 s
# of an integrand whose fastest component turns at 3.1 rad/s)
_GL_X, _GL_W = np.polynomial.legendre.leggauss(10)
_GL_X = 0.5 * (_GL_X + 1.0)
_GL_W = 0.5 * _GL_W


class GroundFollowingFigureEight(DiffDriveFigureEight):
    """Seed 000's figure eight with the velocity along the body's forward axis: the horizontal path and
    the attitude are the figure eight's, the height follows the pitch, ``dz/dt = -v_h tan(pitch)``
    (body x axis in the world ``(c_p c_y, c_p s_y, -s_p)`` for ``R_w_b = Rz Ry Rx``), integrated by
    Gauss-Legendre quadrature on a 0.25 s grid from t = 0."""

    _H = 0.25

    def __init__(self) -> None:
        super().__init__()
        self._cum = np.zeros(1)  # integral of dz/dt over [0, k H], k = 0..len-1

    def _pitch(self, t: FloatArray) -> tuple[FloatArray, FloatArray]:
        f2 = self.tilt_freq[1]
        return (
            self.tilt_amp * np.sin(f2 * t + 1.0),
            self.tilt_amp * f2 * np.cos(f2 * t + 1.0),
        )

    def _dz(self, t: FloatArray) -> FloatArray:
        _, v, _ = DiffDriveFigureEight.position(self, t.ravel())
        return (-np.hypot(v[:, 0], v[:, 1]) * np.tan(self._pitch(t.ravel())[0])).reshape(t.shape)

    def _integral(self, a: FloatArray, b: FloatArray) -> FloatArray:
        """Integral of dz/dt over [a, b] (same shapes), each no longer than a few grid steps."""
        nodes = a[:, None] + (b - a)[:, None] * _GL_X[None]
        return (b - a) * (self._dz(nodes) @ _GL_W)

    def _height(self, t: FloatArray) -> FloatArray:
        if np.any(t < 0):
            raise ValueError("GroundFollowingFigureEight is defined for t >= 0")
        k = np.floor(t / self._H).astype(np.int64)
        need = int(k.max(initial=0)) + 1
        if need > len(self._cum):
            g = np.arange(len(self._cum) - 1, need, dtype=np.float64) * self._H
            steps = self._integral(g[:-1], g[1:])
            self._cum = np.concatenate([self._cum, self._cum[-1] + np.cumsum(steps)])
        start = k.astype(np.float64) * self._H
        return np.asarray(self.h + self._cum[k] + self._integral(start, t), dtype=np.float64)

    def position(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        p, v, a = DiffDriveFigureEight.position(self, t)
        pitch, dpitch = self._pitch(t)
        vh = np.hypot(v[:, 0], v[:, 1])
        dvh = (v[:, 0] * a[:, 0] + v[:, 1] * a[:, 1]) / vh
        tp = np.tan(pitch)
        p[:, 2] = self._height(t)
        v[:, 2] = -vh * tp
        a[:, 2] = -(dvh * tp + vh * dpitch / np.cos(pitch) ** 2)
        return p, v, a


@dataclass
class StereoRunConfig:
    """Duration (s), rates (Hz), seed, camera mount (pitch down in degrees, position in the body, m) and
    IMU biases (accelerometer m/s^2, gyro rad/s) and noise densities (per sqrt(Hz)); ``ground_following``:
    the robot moves along its own forward axis (:class:`GroundFollowingFigureEight`), else seed 000's
    figure eight, whose velocity stays horizontal while the body pitches."""

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
    ground_following: bool = True
    rig: CameraRig = field(default_factory=CameraRig)


class SimStereoRun:
    """IMU log, ground truth and lazily rendered stereo frames of one simulated run."""

    def __init__(
        self,
        cfg: StereoRunConfig | None = None,
        traj: EulerTrajectory | None = None,
        world: World | None = None,
    ) -> None:
        self.cfg = c = cfg or StereoRunConfig()
        if traj is None:
            traj = GroundFollowingFigureEight() if c.ground_following else DiffDriveFigureEight()
        self.traj = traj
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
        self._imu, self._imu_truth = simulate_imu(
            self.traj, c.duration_s, rng, errors, rate_hz=c.imu_hz, t0_ns=c.t0_ns
        )
        self._imu.source = self.source
        th = np.deg2rad(c.pitch_down_deg)
        pitch = np.array([[1.0, 0, 0], [0, np.cos(th), np.sin(th)], [0, -np.sin(th), np.cos(th)]])
        self.R_b_c = R_B_C_FORWARD @ pitch
        self.p_b_c = np.asarray(c.p_b_c, float)
        n = int(np.floor(c.duration_s * c.image_hz)) + 1
        self.t_frames_ns = c.t0_ns + np.round(np.arange(n) / c.image_hz * 1e9).astype(np.int64)

    def __len__(self) -> int:
        return len(self.t_frames_ns)

    def imu(self) -> ImuLog:
        """The simulated IMU's raw output (biased, noisy), m/s^2 and rad/s."""
        return self._imu

    def rectification(self) -> Rectification:
        """The rendered pair is rectified by construction: no remap (the identity)."""
        r = self.cfg.rig
        return Rectification(r.K, r.baseline, r.width, r.height, self.R_b_c, self.p_b_c)

    def skipped_frames(self) -> dict[str, int]:
        return {"missing": 0, "unreadable": 0}

    def truth(self, t_ns: NDArray[np.int64] | None = None) -> Trajectory:
        """Body poses at ``t_ns`` (default: the IMU times)."""
        t = self._imu.t_ns if t_ns is None else np.asarray(t_ns, dtype=np.int64)
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
