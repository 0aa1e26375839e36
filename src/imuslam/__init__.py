"""imuslam: IMU calibration without external equipment, INS alignment and IMU-aided SLAM.

Frames (one letter each, used in every name ``R_a_b`` / ``T_a_b`` that maps a point from frame b into
frame a, ``p_a = R_a_b @ p_b``):

    w world      i IMU        b body       l LiDAR
    c camera     n navigation g gimbal     s sensor (raw, non-orthogonal IMU axes)

Units are SI unless a name says otherwise (``_deg``, ``_ns``, ``_dps``). Time is integer ``t_ns`` at
the I/O boundary and float seconds inside the maths. Quaternions are Hamilton, scalar first
(``quat_wxyz``) everywhere inside the package; ``io/`` converts from and to other orders.
Lie tangent vectors are ordered rotation first, then translation (see ``imuslam.geometry``).

Layers, lowest first; a module never imports a higher one (``lint-imports`` checks it):
geometry -> interfaces / errors -> io / config -> sim / imu / ins / hw -> eval -> lio / vio / slam2d ->
study -> demo -> cli (docs/architecture.md).

Threads: importing imuslam changes nothing in the process; the command line sets its thread defaults
(``imuslam.threads.configure_process``) before numpy and numba load.
"""

__version__ = "0.1.0"
