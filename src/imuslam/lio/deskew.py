"""Motion compensation: every point of a scan moved into the LiDAR frame at the scan end.

With an IMU (FAST-LIO2, Xu et al. 2022, Sec. IV-C "backward propagation"): the propagated IMU states
between the samples give the pose at each point's time, ``T_w_i(t_j) = (R_k Exp(omega_k dt),
p_k + v_k dt + a_k dt^2 / 2)`` with ``dt = t_j - t_k`` from the last sample at or before ``t_j``; the
point then goes to the scan-end frame ``p_end = T_i_l^-1 T_w_i(t_e)^-1 T_w_i(t_j) T_i_l p_l``.
Without an IMU, the constant-velocity model of KISS-ICP (Vizzo et al. 2023, Sec. III-A) gives the same
per-sample form with one sample at the scan end.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

from imuslam.geometry import exp, log
from imuslam.geometry.so3_nb import exp_into_nb

FloatArray = NDArray[np.float64]


@numba.njit(cache=True)
def _deskew(pts_l: FloatArray, t_pt: FloatArray, t_k: FloatArray, R_k: FloatArray, p_k: FloatArray, v_k: FloatArray, a_k: FloatArray, w_k: FloatArray, R_i_l: FloatArray, p_i_l: FloatArray, R_e: FloatArray, p_e: FloatArray) -> FloatArray:  # pragma: no cover - compiled  # fmt: skip
    n = pts_l.shape[0]
    out = np.empty((n, 3))
    E = np.empty((3, 3))
    R = np.empty((3, 3))
    x = np.empty(3)
    q = np.empty(3)
    y = np.empty(3)
    K = t_k.size
    for j in range(n):
        k = np.searchsorted(t_k, t_pt[j], side="right") - 1
        k = min(max(k, 0), K - 1)
        dt = t_pt[j] - t_k[k]
        exp_into_nb(w_k[k, 0] * dt, w_k[k, 1] * dt, w_k[k, 2] * dt, E)
        for a in range(3):
            for b in range(3):
                R[a, b] = R_k[k, a, 0] * E[0, b] + R_k[k, a, 1] * E[1, b] + R_k[k, a, 2] * E[2, b]
        for a in range(3):  # x_i = R_i_l p_l + p_i_l
            x[a] = (
                R_i_l[a, 0] * pts_l[j, 0]
                + R_i_l[a, 1] * pts_l[j, 1]
                + R_i_l[a, 2] * pts_l[j, 2]
                + p_i_l[a]
            )
        for a in range(3):  # q_w = R x_i + p(t_j) - p_e
            q[a] = (R[a, 0] * x[0] + R[a, 1] * x[1] + R[a, 2] * x[2] + p_k[k, a] + v_k[k, a] * dt
                    + 0.5 * a_k[k, a] * dt * dt - p_e[a])  # fmt: skip
        for a in range(3):  # y = R_e^T q - p_i_l
            y[a] = R_e[0, a] * q[0] + R_e[1, a] * q[1] + R_e[2, a] * q[2] - p_i_l[a]
        for a in range(3):  # p_end = R_i_l^T y
            out[j, a] = R_i_l[0, a] * y[0] + R_i_l[1, a] * y[1] + R_i_l[2, a] * y[2]
    return out


def deskew(
    points_l: FloatArray,
    t_pt: FloatArray,
    t_k: FloatArray,
    R_w_i: FloatArray,
    p_w: FloatArray,
    vel_w: FloatArray,
    acc_w: FloatArray,
    omega_i: FloatArray,
    T_i_l: FloatArray,
    t_end: float,
) -> FloatArray:
    """Points (N, 3) in the LiDAR frame at ``t_end``.

    points_l: (N, 3) LiDAR frame at each point's time t_pt (N,), s; t_k (K,) sample times, s, sorted;
    R_w_i (K, 3, 3), p_w (K, 3), vel_w (K, 3) the propagated IMU states at t_k; acc_w (K, 3) the
    world acceleration and omega_i (K, 3) the body rate held from t_k to t_{k+1}; T_i_l (4, 4).
    """
    t_k = np.ascontiguousarray(t_k, dtype=np.float64)
    R_e, p_e = _pose_at(t_end, t_k, R_w_i, p_w, vel_w, acc_w, omega_i)
    T = np.asarray(T_i_l, dtype=np.float64)
    return _deskew(
        np.ascontiguousarray(points_l, dtype=np.float64), np.ascontiguousarray(t_pt, dtype=np.float64),
        t_k, np.ascontiguousarray(R_w_i, dtype=np.float64), np.ascontiguousarray(p_w, dtype=np.float64),
        np.ascontiguousarray(vel_w, dtype=np.float64), np.ascontiguousarray(acc_w, dtype=np.float64),
        np.ascontiguousarray(omega_i, dtype=np.float64), np.ascontiguousarray(T[:3, :3]),
        np.ascontiguousarray(T[:3, 3]), R_e, p_e,
    )  # fmt: skip


def _pose_at(
    t: float,
    t_k: FloatArray,
    R_w_i: FloatArray,
    p_w: FloatArray,
    vel_w: FloatArray,
    acc_w: FloatArray,
    omega_i: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    k = int(np.clip(np.searchsorted(t_k, t, side="right") - 1, 0, len(t_k) - 1))
    dt = t - t_k[k]
    R = R_w_i[k] @ exp(omega_i[k] * dt)
    p = p_w[k] + vel_w[k] * dt + 0.5 * acc_w[k] * dt * dt
    return np.ascontiguousarray(R, dtype=np.float64), np.ascontiguousarray(p, dtype=np.float64)


def constant_velocity_motion(
    T_prev: FloatArray, T_last: FloatArray, dt_frames: float
) -> tuple[FloatArray, FloatArray]:
    """Body rate (3,) rad/s and velocity in the world (3,) m/s of the constant-velocity model from the
    last two scan-end poses (4, 4) ``dt_frames`` s apart (the twist of ``T_prev^-1 T_last``)."""
    D = np.linalg.inv(T_prev) @ T_last
    omega = log(D[:3, :3]) / dt_frames
    vel_w = (T_last[:3, 3] - T_prev[:3, 3]) / dt_frames
    return omega, vel_w


def deskew_constant_velocity(
    points_l: FloatArray,
    t_pt: FloatArray,
    t_end: float,
    T_w_l_end: FloatArray,
    omega_l: FloatArray,
    vel_w: FloatArray,
) -> FloatArray:
    """Points (N, 3) in the LiDAR frame at ``t_end`` under constant body rate ``omega_l`` (3,) and world
    velocity ``vel_w`` (3,) around the scan-end pose ``T_w_l_end`` (4, 4)."""
    one = np.ones((1, 1))
    z = np.zeros((1, 3))
    return deskew(
        points_l, t_pt, np.array([t_end]), T_w_l_end[None, :3, :3], T_w_l_end[None, :3, 3],
        vel_w[None], z, omega_l[None] * one, np.eye(4), t_end,
    )  # fmt: skip


def deskew_reference(
    points_l: FloatArray,
    t_pt: FloatArray,
    pose_at: object,
    T_i_l: FloatArray,
    t_end: float,
) -> FloatArray:
    """Slow reference: ``pose_at(t) -> (R_w_i, p_w)`` called for every point."""
    f = pose_at  # a callable
    R_e, p_e = f(t_end)  # type: ignore[operator]
    out = np.empty_like(np.asarray(points_l, dtype=float))
    for j in range(len(points_l)):
        R, p = f(float(t_pt[j]))  # type: ignore[operator]
        q = R @ (T_i_l[:3, :3] @ points_l[j] + T_i_l[:3, 3]) + p
        out[j] = T_i_l[:3, :3].T @ (R_e.T @ (q - p_e) - T_i_l[:3, 3])
    return out
