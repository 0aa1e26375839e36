"""Stereo camera calibration: EuRoC ``sensor.yaml`` pairs and Kalibr camchain YAML, and rectification.

A camera is a pinhole with radial-tangential (plumb bob) distortion and its pose in the body (IMU) frame
``T_b_c``. Rectification (OpenCV ``stereoRectify``, Bouguet's method) turns both cameras about their
centres so that epipolar lines are image rows; ``R_r_c`` maps the raw left camera frame into the rectified
left frame ``r`` (x right, y down, z forward), in which the VO works.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.io.yamlfile import read_yaml

FloatArray = NDArray[np.float64]


@dataclass
class PinholeCamera:
    """Intrinsics (px), radtan distortion ``[k1, k2, p1, p2]``, image size (px), pose in the body frame."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    dist: FloatArray = field(default_factory=lambda: np.zeros(4))
    T_b_c: FloatArray = field(default_factory=lambda: np.eye(4))

    @property
    def K(self) -> FloatArray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


@dataclass
class Rectification:
    """Rectified stereo geometry: common intrinsics ``K`` (3, 3), baseline (m, right camera at +x),
    remap tables of both cameras, and the rectified left frame's pose in the body: ``R_b_r``, ``p_b_r``."""

    K: FloatArray
    baseline: float
    width: int
    height: int
    R_b_r: FloatArray
    p_b_r: FloatArray
    maps_left: tuple[Any, Any] | None = None
    maps_right: tuple[Any, Any] | None = None

    @property
    def f(self) -> float:
        return float(self.K[0, 0])

    def rectify(self, left: NDArray[np.uint8], right: NDArray[np.uint8]) -> tuple[Any, Any]:
        """Both images remapped into the rectified pair (identity when no maps: already rectified, as
        the simulator renders them)."""
        if self.maps_left is None or self.maps_right is None:
            return left, right
        import cv2

        ml, mr = self.maps_left, self.maps_right
        return (
            cv2.remap(left, ml[0], ml[1], cv2.INTER_LINEAR),
            cv2.remap(right, mr[0], mr[1], cv2.INTER_LINEAR),
        )


@dataclass
class StereoCalibration:
    """Two cameras with their poses in the body frame; ``source`` names the file(s) for messages."""

    left: PinholeCamera
    right: PinholeCamera
    source: str = "<memory>"

    def rectification(self) -> Rectification:
        """Bouguet rectification with zero disparity at infinity and only valid pixels (alpha 0)."""
        import cv2

        L, R = self.left, self.right
        if (L.width, L.height) != (R.width, R.height):
            raise InputError(
                f"{self.source}: the cameras differ in resolution ({L.width}x{L.height} and "
                f"{R.width}x{R.height}); expected one size"
            )
        T_cr_cl = np.linalg.inv(R.T_b_c) @ L.T_b_c  # p_right = R p_left + t
        size = (L.width, L.height)
        R1, R2, P1, P2, _, _, _ = cv2.stereoRectify(
            L.K, L.dist, R.K, R.dist, size, T_cr_cl[:3, :3].copy(), T_cr_cl[:3, 3].reshape(3, 1).copy(),
            flags=cv2.CALIB_ZERO_DISPARITY, alpha=0,
        )  # fmt: skip
        baseline = float(-P2[0, 3] / P2[0, 0])
        if not baseline > 0:
            raise InputError(
                f"{self.source}: the second camera is not to the right of the first "
                f"(rectified baseline {baseline:.4f} m); expected cam1 at +x of cam0"
            )
        ml = cv2.initUndistortRectifyMap(L.K, L.dist, R1, P1[:, :3], size, cv2.CV_16SC2)
        mr = cv2.initUndistortRectifyMap(R.K, R.dist, R2, P2[:, :3], size, cv2.CV_16SC2)
        R_b_r = L.T_b_c[:3, :3] @ R1.T
        return Rectification(
            np.asarray(P1[:, :3], float), baseline, L.width, L.height, R_b_r, L.T_b_c[:3, 3].copy(),
            ml, mr,
        )  # fmt: skip


def _load_yaml(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise InputError(f"{path}: calibration file not found")
    return read_yaml(path, "a camera calibration (Kalibr camchain or EuRoC sensor.yaml)")


def _floats(d: dict[str, Any], key: str, n: int, src: str) -> FloatArray:
    if key not in d:
        raise InputError(f"{src}: field '{key}' is missing")
    v = d[key]
    if isinstance(v, dict) and "data" in v:
        v = v["data"]
    try:
        a = np.asarray(v, dtype=float).ravel()
    except (TypeError, ValueError):
        raise InputError(f"{src}: field '{key}' is not numeric") from None
    if a.size != n:
        raise InputError(f"{src}: field '{key}' has {a.size} numbers; expected {n}")
    return a


def _camera(d: dict[str, Any], src: str, T_b_c: FloatArray, kalibr: bool) -> PinholeCamera:
    model = d.get("camera_model", "pinhole")
    if model != "pinhole":
        raise InputError(f"{src}: camera_model '{model}'; only pinhole is supported")
    dm = d.get("distortion_model", "radtan")
    if dm not in ("radtan", "radial-tangential", "plumb_bob", "none"):
        raise InputError(f"{src}: distortion_model '{dm}'; expected radtan (radial-tangential)")
    fx, fy, cx, cy = _floats(d, "intrinsics", 4, src)
    w, h = (int(x) for x in _floats(d, "resolution", 2, src))
    dist = (
        np.zeros(4)
        if dm == "none"
        else _floats(d, "distortion_coeffs" if kalibr else "distortion_coefficients", 4, src)
    )
    return PinholeCamera(fx, fy, cx, cy, w, h, dist, T_b_c)


def read_euroc_calibration(mav0: str | Path) -> StereoCalibration:
    """``mav0/cam0/sensor.yaml`` and ``mav0/cam1/sensor.yaml`` (``T_BS`` is the camera pose in the body)."""
    root = Path(mav0)
    cams = []
    for name in ("cam0", "cam1"):
        p = root / name / "sensor.yaml"
        if not p.is_file():
            raise InputError(
                f"{p}: not found; a stereo calibration needs both cam0 and cam1 sensor.yaml"
            )
        d = _load_yaml(p)
        T = _floats(d, "T_BS", 16, str(p)).reshape(4, 4)
        cams.append(_camera(d, str(p), T, kalibr=False))
    return StereoCalibration(
        cams[0], cams[1], f"{root / 'cam0/sensor.yaml'}, {root / 'cam1/sensor.yaml'}"
    )


def read_kalibr_camchain(path: str | Path) -> StereoCalibration:
    """A Kalibr ``camchain-imucam.yaml``: ``cam0``/``cam1`` with ``T_cam_imu`` (IMU -> camera), or ``cam1``
    with ``T_cn_cnm1`` (cam0 -> cam1) when the camera-IMU transform of cam1 is absent."""
    p = Path(path)
    d = _load_yaml(p)
    for name in ("cam0", "cam1"):
        if name not in d or not isinstance(d[name], dict):
            raise InputError(
                f"{p}: no '{name}' entry; a stereo camchain needs cam0 and cam1 "
                f"(found: {', '.join(k for k in d if isinstance(k, str)) or 'nothing'})"
            )
    c0, c1 = d["cam0"], d["cam1"]
    if "T_cam_imu" not in c0:
        raise InputError(f"{p}: cam0.T_cam_imu is missing; expected the IMU-camera extrinsic")
    T_c0_i = _floats(c0, "T_cam_imu", 16, f"{p}: cam0").reshape(4, 4)
    if "T_cam_imu" in c1:
        T_c1_i = _floats(c1, "T_cam_imu", 16, f"{p}: cam1").reshape(4, 4)
    elif "T_cn_cnm1" in c1:
        T_c1_i = _floats(c1, "T_cn_cnm1", 16, f"{p}: cam1").reshape(4, 4) @ T_c0_i
    else:
        raise InputError(f"{p}: cam1 has neither T_cam_imu nor T_cn_cnm1")
    left = _camera(c0, f"{p}: cam0", np.asarray(np.linalg.inv(T_c0_i), float), kalibr=True)
    right = _camera(c1, f"{p}: cam1", np.asarray(np.linalg.inv(T_c1_i), float), kalibr=True)
    return StereoCalibration(left, right, str(p))


def read_calibration(path: str | Path) -> StereoCalibration:
    """A Kalibr camchain file, or an EuRoC ``mav0`` folder (or its parent)."""
    p = Path(path)
    if p.is_dir():
        mav0 = p / "mav0" if (p / "mav0").is_dir() else p
        return read_euroc_calibration(mav0)
    return read_kalibr_camchain(p)
