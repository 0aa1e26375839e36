"""The VIO front end's models against analytic truth: the velocity a frame pair gives under a known
constant twist (turning and moving), and both cameras' rectification maps against the projection of
known points."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

from imuslam.io.camcalib import PinholeCamera, Rectification, StereoCalibration
from imuslam.vio.frontend import StereoVO
from imuslam.vio.measurements import twist_velocity


def _rot(rx: float, ry: float, rz: float) -> np.ndarray:
    """Rotation matrix of the rotation vector (rx, ry, rz), rad (scipy's matrix exponential, not ours)."""
    w = np.array([[0.0, -rz, ry], [rz, 0.0, -rx], [-ry, rx, 0.0]])
    return np.asarray(expm(w))


def _se3(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


# the rectified left camera looks forward from the body (x forward, y left, z up), tilted and offset
R_B_R = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]) @ _rot(0.05, -0.03, 0.02)
P_B_R = np.array([0.30, 0.05, 0.20])


@pytest.mark.parametrize(
    ("omega_b", "vel_b", "dt"),
    [
        ([0.0, 0.0, 1.2], [1.5, 0.0, 0.0], 0.1),  # a ground robot's turn at 1.5 m/s
        ([0.1, -0.2, 1.2], [1.5, 0.1, -0.05], 0.1),  # a turn with roll and pitch rates, side slip
        ([0.3, 0.2, -2.5], [0.4, -0.3, 0.2], 0.05),  # a fast spin of a hand-held rig
    ],
)
def test_vo_velocity_of_a_turning_moving_pair_is_the_body_velocity(
    omega_b: list[float], vel_b: list[float], dt: float
) -> None:
    """A body moving with constant rate ``omega_b`` and constant body velocity ``vel_b`` for ``dt``: its
    motion is the SE(3) exponential of the twist (scipy's matrix exponential of the 4 x 4 twist). The
    rectified camera, mounted off the body's origin, sees that motion through its extrinsic. The front
    end's measurement from the camera pair (:meth:`StereoVO._to_body`: rate and mean velocity seen from
    mid-interval) and the filter's reading of it (:func:`twist_velocity`) give back the rate and the body
    velocity exactly: the only error is rounding. The mid-interval rotation taken the wrong way round
    leaves a lateral error of about |v| |omega| dt (0.18 m/s in the first case)."""
    w, v = np.asarray(omega_b), np.asarray(vel_b)
    xi = np.zeros((4, 4))
    xi[:3, :3] = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    xi[:3, 3] = v
    T_b0_b1 = np.asarray(expm(xi * dt))  # constant body twist for dt
    T_b_r = _se3(R_B_R, P_B_R)
    T_r0_r1 = np.linalg.inv(T_b_r) @ T_b0_b1 @ T_b_r
    rect = Rectification(np.diag([450.0, 450.0, 1.0]), 0.11, 752, 480, R_B_R, P_B_R)
    vo = StereoVO(rect)
    z = vo._to_body(np.linalg.inv(T_r0_r1), dt)  # the front end gets T_{r_k, r_{k-1}}
    np.testing.assert_allclose(z[:3], w, atol=1e-9)
    v_b, _ = twist_velocity(z[:3], z[3:], np.eye(6), dt)
    np.testing.assert_allclose(v_b, v, atol=1e-9)
    # the measurement is the chord (mean velocity), shorter than the speed in a turn: the test sees the
    # difference between the two (for the turns it is far above the 1e-9 tolerance)
    assert np.linalg.norm(z[3:] - v) > 1e-5


def _calibration() -> StereoCalibration:
    """Two unlike cameras (different focal lengths, centres and radial-tangential distortion; the right
    one 11 cm to the right, turned by about a degree), as a real stereo head after calibration."""
    T_b_c0 = _se3(R_B_R @ _rot(0.01, 0.02, -0.01), P_B_R)
    R_c0_c1 = _rot(0.012, -0.015, 0.008)
    T_c0_c1 = _se3(R_c0_c1, np.array([0.110, 0.002, -0.001]))
    left = PinholeCamera(458.7, 457.3, 367.2, 248.4, 752, 480,
                         np.array([-0.283, 0.074, 1.9e-4, 1.8e-5]), T_b_c0)  # fmt: skip
    right = PinholeCamera(457.6, 456.1, 379.9, 255.2, 752, 480,
                          np.array([-0.284, 0.074, -1.0e-4, -3.5e-5]), T_b_c0 @ T_c0_c1)  # fmt: skip
    return StereoCalibration(left, right)


def _lookup(maps: tuple[np.ndarray, np.ndarray], u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The raw pixel (N, 2) a rectification map takes the integer rectified pixels (u, v) from."""
    import cv2

    mx, my = cv2.convertMaps(maps[0], maps[1], cv2.CV_32FC1)
    return np.column_stack([mx[v, u], my[v, u]]).astype(float)


def test_both_rectification_maps_put_a_point_on_the_same_row() -> None:
    """Points placed at integer rectified pixels of the left camera (row v, column u) and an integer
    disparity d, i.e. at depth f b / d in the rectified frame: the right camera sees each at (u - d, v).
    Each camera's rectification map, looked up at those rectified pixels, must point at the pixel where
    that camera's own raw (distorted) projection of the point lies. Map entries are stored in 1/32 px
    (OpenCV's fixed point), so both agree to 0.05 px; the right camera rectified with the left's
    intrinsics is off by pixels (its centre differs by 13 px and 7 px)."""
    import cv2

    cal = _calibration()
    rect = cal.rectification()
    assert rect.maps_left is not None and rect.maps_right is not None
    rng = np.random.default_rng(3)
    n = 200
    u = rng.integers(120, 630, n)
    v = rng.integers(80, 400, n)
    d = rng.integers(8, 60, n)
    f, b = rect.f, rect.baseline
    z = f * b / d
    K = rect.K
    p_r = np.column_stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z])
    # the points in the body, then in each raw camera frame
    p_b = p_r @ rect.R_b_r.T + rect.p_b_r
    for cam, maps, u_rect in ((cal.left, rect.maps_left, u), (cal.right, rect.maps_right, u - d)):
        T_c_b = np.linalg.inv(cam.T_b_c)
        p_c = p_b @ T_c_b[:3, :3].T + T_c_b[:3, 3]
        raw, _ = cv2.projectPoints(p_c, np.zeros(3), np.zeros(3), cam.K, cam.dist)
        looked_up = _lookup(maps, u_rect, v)  # the same row v in both rectified images
        err = np.linalg.norm(looked_up - raw.reshape(-1, 2), axis=1)
        assert np.max(err) < 0.05, f"max {np.max(err):.3f} px"
